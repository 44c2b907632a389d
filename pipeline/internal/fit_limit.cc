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

namespace {

// Neighbours farther apart in depth than this are an edge, not noise
// (metres); the limit grows with the noise (kEdgeSigmas times the sigma of a
// difference of two pixels) so that strong noise is not clipped.
constexpr float kMinEdgeStep = 0.004f;
constexpr double kEdgeSigmas = 5.0;

// One estimate of the median absolute second difference over the lattice,
// neighbour steps above max_step left out. {MAD, median depth}; {0, 0} for
// too few samples.
std::pair<double, double> SecondDifferenceMad(const DepthImage& depth, int step, float max_step,
                                              std::vector<float>& second, std::vector<float>& z) {
  second.clear();
  z.clear();
  for (int v = 0; v < depth.height; v += step) {
    for (int u = 1; u + 1 < depth.width; u += step) {
      const float a = depth.at(u - 1, v), b = depth.at(u, v), c = depth.at(u + 1, v);
      if (!std::isfinite(a) || !std::isfinite(b) || !std::isfinite(c)) continue;
      if (std::abs(a - b) > max_step || std::abs(c - b) > max_step) continue;
      second.push_back(std::abs(a - 2.f * b + c));
      z.push_back(b);
    }
  }
  if (second.size() < 1000) return {0.0, 0.0};
  const auto median = [](std::vector<float>& x) {
    std::nth_element(x.begin(), x.begin() + static_cast<std::ptrdiff_t>(x.size() / 2), x.end());
    return static_cast<double>(x[x.size() / 2]);
  };
  return {median(second), median(z)};
}

}  // namespace

std::pair<double, double> MeasureDepthNoise(const DepthImage& depth) {
  constexpr int kTargetSamples = 20000;
  const int64_t pixels = static_cast<int64_t>(depth.width) * depth.height;
  const int step = std::max(1, static_cast<int>(std::sqrt(static_cast<double>(pixels) / kTargetSamples)));
  std::vector<float> second, z;
  second.reserve(kTargetSamples * 2);
  z.reserve(kTargetSamples * 2);
  // sigma = MAD / (0.6745 sqrt(6)) for a Gaussian of variance 6 sigma^2. The
  // edge limit clips strong noise's own steps (a 2.5 mm sigma lost 40%), so
  // the estimate is repeated with the limit its sigma asks for until the
  // limit stops growing.
  constexpr double kMadToSigma = 1.0 / (0.67449 * 2.449489742783178);
  float max_step = kMinEdgeStep;
  std::pair<double, double> out{0.0, 0.0};
  for (int round = 0; round < 4; ++round) {
    const auto [mad, at] = SecondDifferenceMad(depth, step, max_step, second, z);
    if (!(mad > 0.0) && !(at > 0.0)) return {0.0, 0.0};
    out = {mad * kMadToSigma, at};
    const float wanted = static_cast<float>(kEdgeSigmas * std::sqrt(2.0) * out.first);
    if (!(wanted > 1.05f * max_step)) break;
    max_step = wanted;
  }
  return out;
}

DepthNoise::DepthNoise(const CameraSpec& camera, const Frame& frame) : model_(FrameNoise(camera, frame)) {
  if (frame.organized()) std::tie(measured_sigma_, measured_at_) = MeasureDepthNoise(frame.depth);
  const double at_median = ModelSigma(measured_at_);
  if (model_ != nullptr && at_median > 0.0) scale_ = std::max(1.0, measured_sigma_ / at_median);
}

double DepthNoise::ModelSigma(double z) const {
  return model_ == nullptr ? 0.0 : model_->axial_sigma_base + model_->axial_sigma_quadratic * z * z;
}

double DepthNoise::Sigma(double z) const {
  const double modelled = ModelSigma(z);
  return modelled > 0.0 ? scale_ * modelled : measured_sigma_;
}

FitRmsLimit::FitRmsLimit(double max_sigmas, double min_limit, const DepthNoise& noise, const Frame& frame)
    : max_sigmas_(max_sigmas), min_limit_(min_limit), noise_(noise), X_CB_(frame.X_BC.inverse()) {}

double FitRmsLimit::At(const ClassModel& model, const Pose& X_BO) const {
  const double z = (X_CB_ * (X_BO * model.centroid_O().cast<double>())).z();
  const double sigma = noise_.Sigma(z);
  if (!(sigma > 0.0)) return std::numeric_limits<double>::infinity();  // no noise figure: no limit
  return std::max(min_limit_, max_sigmas_ * sigma);
}

}  // namespace bp::internal
