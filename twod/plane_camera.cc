#include "twod/plane_camera.h"

#include <algorithm>
#include <cmath>
#include <random>

#include <opencv2/imgproc.hpp>

#include "twod/internal/cv_util.h"

namespace bp {

Eigen::Vector2d Pose2D::Apply(const Eigen::Vector2d& p) const {
  const double c = std::cos(theta), s = std::sin(theta);
  return {x + c * p.x() - s * p.y(), y + s * p.x() + c * p.y()};
}

Pose2D Pose2D::Compose(const Pose2D& b) const {
  const Eigen::Vector2d t = Apply(b.xy());
  return {t.x(), t.y(), WrapAngle(theta + b.theta)};
}

double WrapAngle(double a) {
  a = std::fmod(a, 2 * M_PI);
  if (a <= -M_PI) a += 2 * M_PI;
  if (a > M_PI) a -= 2 * M_PI;
  return a;
}

namespace {

// The outline with no edge longer than `step` (distortion bends long edges).
std::vector<Eigen::Vector2d> Densify(const std::vector<Eigen::Vector2d>& poly, double step) {
  std::vector<Eigen::Vector2d> out;
  for (size_t i = 0; i < poly.size(); ++i) {
    const Eigen::Vector2d& a = poly[i];
    const Eigen::Vector2d& b = poly[(i + 1) % poly.size()];
    const int n = std::max(1, static_cast<int>(std::ceil((b - a).norm() / step)));
    for (int k = 0; k < n; ++k) out.push_back(a + (b - a) * (static_cast<double>(k) / n));
  }
  return out;
}

constexpr int kShift = 4;  // fillPoly fractional bits

std::vector<cv::Point> ToCanvas(const std::vector<cv::Point2d>& px, int S) {
  std::vector<cv::Point> out;
  out.reserve(px.size());
  for (const cv::Point2d& p : px) {
    // Native pixel centre u maps to supersampled coordinate (u + 0.5) S - 0.5.
    out.emplace_back(static_cast<int>(std::lround(((p.x + 0.5) * S - 0.5) * (1 << kShift))),
                     static_cast<int>(std::lround(((p.y + 0.5) * S - 0.5) * (1 << kShift))));
  }
  return out;
}

// The outline's vertex centroid and the radius about it.
std::pair<Eigen::Vector2d, double> BoundingCircle(const Flat2DSpec& f) {
  Eigen::Vector2d c = Eigen::Vector2d::Zero();
  for (const Eigen::Vector2d& p : f.outline) c += p;
  c /= static_cast<double>(f.outline.size());
  double r = 0;
  for (const Eigen::Vector2d& p : f.outline) r = std::max(r, (p - c).norm());
  return {c, r};
}

}  // namespace

Result<std::unique_ptr<SyntheticPlaneCamera>> SyntheticPlaneCamera::Create(const Cell& cell,
                                                                            SyntheticPlaneOptions options) {
  const CameraConfig* config = cell.camera.FindConfig(cell.camera.default_config);
  if (!config || !config->intrinsics.valid()) return Status::InvalidArgument("2D camera: no valid default config");
  if (cell.camera.eye_in_hand) return Status::Unavailable("2D camera: eye-in-hand 2D tasks are not simulated");
  const Pose X_CP = cell.camera.X_BC.inverse() * cell.bin.X_BW;
  return std::unique_ptr<SyntheticPlaneCamera>(
      new SyntheticPlaneCamera(cell, config->intrinsics, X_CP, options));
}

Status SyntheticPlaneCamera::Scatter(int count, uint64_t seed, const std::vector<int>& classes) {
  std::vector<const PartSpec*> pool;
  for (const PartSpec& p : cell_.parts) {
    if (!p.flat_2d) continue;
    if (!classes.empty() && std::find(classes.begin(), classes.end(), p.class_id) == classes.end()) continue;
    pool.push_back(&p);
  }
  if (pool.empty()) return Status::InvalidArgument("2D scatter: no part with flat_2d among the classes");
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  const Eigen::Vector2d half = cell_.bin.inner_size.head<2>() / 2;
  std::vector<FlatPartTruth> parts;
  std::vector<double> radii;
  std::vector<Eigen::Vector2d> centres;
  for (int i = 0; i < count; ++i) {
    bool placed = false;
    for (int attempt = 0; attempt < 500 && !placed; ++attempt) {
      const PartSpec* part = pool[static_cast<size_t>(unit(rng) * pool.size()) % pool.size()];
      const auto [centre, r] = BoundingCircle(*part->flat_2d);
      if (r >= half.minCoeff()) break;
      // Draw the circle's centre in the area, then the part pose around it.
      const Eigen::Vector2d at((2 * unit(rng) - 1) * (half.x() - r), (2 * unit(rng) - 1) * (half.y() - r));
      bool free = true;
      for (size_t j = 0; j < parts.size() && free; ++j) {
        free = (centres[j] - at).norm() > r + radii[j] + options_.min_gap;
      }
      if (!free) continue;
      FlatPartTruth t;
      t.class_id = part->class_id;
      t.X_PO.theta = WrapAngle(2 * M_PI * unit(rng));
      const Eigen::Vector2d rotated = Pose2D{0, 0, t.X_PO.theta}.Apply(centre);
      t.X_PO.x = at.x() - rotated.x();
      t.X_PO.y = at.y() - rotated.y();
      t.instance_id = static_cast<int>(parts.size()) + 1;
      parts.push_back(t);
      radii.push_back(r);
      centres.push_back(at);
      placed = true;
    }
  }
  std::lock_guard<std::mutex> lock(mutex_);
  parts_ = std::move(parts);
  return Status::Ok();
}

void SyntheticPlaneCamera::SetParts(std::vector<FlatPartTruth> parts) {
  std::lock_guard<std::mutex> lock(mutex_);
  parts_ = std::move(parts);
}

std::vector<FlatPartTruth> SyntheticPlaneCamera::parts() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return parts_;
}

void SyntheticPlaneCamera::RemovePart(int instance_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  parts_.erase(std::remove_if(parts_.begin(), parts_.end(),
                              [&](const FlatPartTruth& p) { return p.instance_id == instance_id; }),
               parts_.end());
}

Result<PlaneImage> SyntheticPlaneCamera::Capture(const PlaneCaptureRequest& request) {
  std::vector<FlatPartTruth> parts;
  uint64_t capture = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    parts = parts_;
    capture = ++captures_;
  }
  const int S = options_.supersample;
  cv::Mat canvas(K_.height * S, K_.width * S, CV_8UC1, cv::Scalar(options_.background));
  auto fill = [&](const std::vector<Vec3>& p_P, uint8_t value) {
    const std::vector<cv::Point> poly = ToCanvas(internal::Project(K_, X_CP_, p_P), S);
    const cv::Point* pts = poly.data();
    const int n = static_cast<int>(poly.size());
    cv::fillPoly(canvas, &pts, &n, 1, cv::Scalar(value), cv::LINE_8, kShift);
  };
  if (request.marker_X_PT) {
    // The calibration runs on a cleared plane: only the marker disc.
    std::mt19937_64 robot_rng(cell_.source.seed * 7919ULL + capture);
    std::normal_distribution<double> error(0.0, options_.robot_sigma);
    const Vec3 c = request.marker_X_PT->translation() + Vec3(error(robot_rng), error(robot_rng), 0.0);
    std::vector<Vec3> disc;
    for (int k = 0; k < 96; ++k) {
      const double a = 2 * M_PI * k / 96;
      disc.emplace_back(c.x() + options_.marker_radius * std::cos(a), c.y() + options_.marker_radius * std::sin(a),
                        c.z());
    }
    fill(disc, options_.marker);
  } else {
    for (const FlatPartTruth& t : parts) {
      const PartSpec* spec = cell_.FindPart(t.class_id);
      if (!spec || !spec->flat_2d) continue;
      const std::vector<Eigen::Vector2d> outline = Densify(spec->flat_2d->outline, 0.002);
      std::vector<Vec3> bottom, top;
      for (const Eigen::Vector2d& p : outline) {
        const Eigen::Vector2d q = t.X_PO.Apply(p);
        bottom.emplace_back(q.x(), q.y(), 0.0);
        top.emplace_back(q.x(), q.y(), spec->flat_2d->thickness);
      }
      fill(bottom, options_.side);
      for (size_t i = 0; i < outline.size(); ++i) {
        const size_t j = (i + 1) % outline.size();
        fill({bottom[i], bottom[j], top[j], top[i]}, options_.side);
      }
      fill(top, options_.top);
    }
  }
  cv::Mat native;
  cv::resize(canvas, native, cv::Size(K_.width, K_.height), 0, 0, cv::INTER_AREA);
  cv::Mat noisy;
  native.convertTo(noisy, CV_32F);
  cv::Mat noise(noisy.size(), CV_32F);
  cv::RNG rng(cell_.source.seed * 1000003ULL + capture);
  rng.fill(noise, cv::RNG::NORMAL, 0.0, options_.noise_sigma);
  noisy += noise;
  PlaneImage out;
  out.intrinsics = K_;
  out.image = IntensityImage(K_.width, K_.height);
  noisy.convertTo(internal::AsMat(out.image), CV_8U);  // saturating
  out.truth = std::move(parts);
  return out;
}

}  // namespace bp
