#include "pipeline/internal/fit_limit.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "pipeline/internal/class_model.h"

namespace bp::internal {

const NoiseModel* FrameNoise(const CameraSpec& camera, const Frame& frame) {
  if (frame.organized()) {
    const Intrinsics& k = frame.intrinsics;
    for (const CameraConfig& c : camera.configs) {
      const Intrinsics& i = c.intrinsics;
      if (i.width == k.width && i.height == k.height && i.fx == k.fx && i.fy == k.fy && i.cx == k.cx && i.cy == k.cy) {
        return &c.noise;
      }
    }
  }
  if (const CameraConfig* c = camera.FindConfig(camera.default_config)) return &c->noise;
  return camera.configs.empty() ? nullptr : &camera.configs.front().noise;
}

std::pair<double, double> MeasureDepthNoise(const DepthImage& depth) {
  constexpr int kTargetSamples = 20000;
  constexpr float kMaxStep = 0.004f;  // neighbours farther apart in depth: an edge
  const int64_t pixels = static_cast<int64_t>(depth.width) * depth.height;
  const int step = std::max(1, static_cast<int>(std::sqrt(static_cast<double>(pixels) / kTargetSamples)));
  std::vector<float> second, z;
  second.reserve(kTargetSamples * 2);
  z.reserve(kTargetSamples * 2);
  for (int v = 0; v < depth.height; v += step) {
    for (int u = 1; u + 1 < depth.width; u += step) {
      const float a = depth.at(u - 1, v), b = depth.at(u, v), c = depth.at(u + 1, v);
      if (!std::isfinite(a) || !std::isfinite(b) || !std::isfinite(c)) continue;
      if (std::abs(a - b) > kMaxStep || std::abs(c - b) > kMaxStep) continue;
      second.push_back(std::abs(a - 2.f * b + c));
      z.push_back(b);
    }
  }
  if (second.size() < 1000) return {0.0, 0.0};
  const auto median = [](std::vector<float>& x) {
    std::nth_element(x.begin(), x.begin() + static_cast<std::ptrdiff_t>(x.size() / 2), x.end());
    return static_cast<double>(x[x.size() / 2]);
  };
  // sigma = MAD / (0.6745 sqrt(6)) for a Gaussian of variance 6 sigma^2.
  return {median(second) / (0.67449 * std::sqrt(6.0)), median(z)};
}

FitRmsLimit::FitRmsLimit(double max_sigmas, double min_limit, const CameraSpec& camera, const Frame& frame)
    : max_sigmas_(max_sigmas), min_limit_(min_limit), X_CB_(frame.X_BC.inverse()) {
  if (!enabled()) return;
  noise_ = FrameNoise(camera, frame);
  if (frame.organized()) std::tie(measured_sigma_, measured_at_) = MeasureDepthNoise(frame.depth);
  at_median_ = ModelSigma(measured_at_);
  noise_scale_ = at_median_ > 0.0 ? std::max(1.0, measured_sigma_ / at_median_) : 1.0;
}

double FitRmsLimit::ModelSigma(double z) const {
  return noise_ == nullptr ? 0.0 : noise_->axial_sigma_base + noise_->axial_sigma_quadratic * z * z;
}

double FitRmsLimit::At(const ClassModel& model, const Pose& X_BO) const {
  const double z = (X_CB_ * (X_BO * model.centroid_O().cast<double>())).z();
  const double sigma = at_median_ > 0.0 ? noise_scale_ * ModelSigma(z) : measured_sigma_;
  if (!(sigma > 0.0)) return std::numeric_limits<double>::infinity();  // no noise figure: no limit
  return std::max(min_limit_, max_sigmas_ * sigma);
}

}  // namespace bp::internal
