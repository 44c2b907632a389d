#include "pipeline/synthetic_variety.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <random>

namespace bp {

namespace {

constexpr double kDeg = M_PI / 180.0;

// Its own stream: the variety of scene `seed` does not shift the pile's draws.
uint64_t VarietySeed(uint64_t seed) {
  uint64_t x = seed ^ 0x5A17E7A1E7A1E7A5ull;
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

const char* Name(DropStyle style) {
  switch (style) {
    case DropStyle::kDefault: return "default";
    case DropStyle::kSettled: return "settled";
    case DropStyle::kJumbled: return "jumbled";
  }
  return "?";
}

// The bin's inner box corners (floor and rim) in base.
std::vector<Vec3> InnerBoxCorners(const BinSpec& bin) {
  std::vector<Vec3> out;
  for (double sx : {-0.5, 0.5}) {
    for (double sy : {-0.5, 0.5}) {
      for (double z : {0.0, bin.inner_size.z()}) {
        out.push_back(bin.X_BW * Vec3(sx * bin.inner_size.x(), sy * bin.inner_size.y(), z));
      }
    }
  }
  return out;
}

bool InView(const Pose& X_BC, const std::vector<Vec3>& corners_B, const CameraConfig& config) {
  const Intrinsics& K = config.intrinsics;
  const double mx = 0.02 * K.width, my = 0.02 * K.height;
  const Pose X_CB = X_BC.inverse();
  for (const Vec3& p_B : corners_B) {
    const Vec3 p = X_CB * p_B;
    if (p.z() <= config.min_depth || p.z() >= config.max_depth) return false;
    const double u = K.fx * p.x() / p.z() + K.cx, v = K.fy * p.y() / p.z() + K.cy;
    if (u < mx || v < my || u > K.width - 1 - mx || v > K.height - 1 - my) return false;
  }
  return true;
}

}  // namespace

std::string SceneVariety::Describe() const {
  char line[320];
  std::snprintf(line, sizeof(line),
                "tilt %.1f deg toward %.0f deg, roll %.0f deg, focal x%.3f, resolution x%.3f, principal point "
                "(%+.3f, %+.3f), axial noise x%.2f, grazing from %.1f deg, mixed pixels %.2f, speckle %.4f, %s drop",
                tilt_deg, tilt_azimuth_deg, roll_deg, focal_scale, resolution_scale, principal_dx, principal_dy,
                axial_noise_scale, grazing_start_deg, mixed_pixels, speckle, Name(drop_style));
  return line;
}

SceneVariety DrawSceneVariety(const VarietySpec& spec, uint64_t seed) {
  std::mt19937_64 rng(VarietySeed(seed));
  std::uniform_real_distribution<double> U(0.0, 1.0);
  const auto in = [&](const std::array<double, 2>& r) { return r[0] + (r[1] - r[0]) * U(rng); };
  SceneVariety v;
  // Tilt uniform in angle (not in solid angle): small tilts are as common as large ones.
  v.tilt_deg = spec.max_tilt_deg * U(rng);
  v.tilt_azimuth_deg = 360.0 * U(rng);
  v.roll_deg = spec.max_roll_deg * (2.0 * U(rng) - 1.0);
  v.focal_scale = in(spec.focal_scale);
  v.resolution_scale = in(spec.resolution_scale);
  v.principal_dx = spec.principal_offset * (2.0 * U(rng) - 1.0);
  v.principal_dy = spec.principal_offset * (2.0 * U(rng) - 1.0);
  v.axial_noise_scale = in(spec.axial_noise_scale);
  v.grazing_start_deg = in(spec.grazing_start_deg);
  v.mixed_pixels = in(spec.mixed_pixels);
  v.speckle = in(spec.speckle);
  const size_t styles = spec.drop_styles.size();
  v.drop_style = styles == 0 ? DropStyle::kDefault
                             : spec.drop_styles[std::min(styles - 1, static_cast<size_t>(U(rng) * styles))];
  return v;
}

CameraConfig VariedConfig(const CameraConfig& base, const SceneVariety& v) {
  CameraConfig c = base;
  Intrinsics& K = c.intrinsics;
  const Intrinsics& B = base.intrinsics;
  K.width = std::max(16, static_cast<int>(std::lround(B.width * v.resolution_scale)));
  K.height = std::max(16, static_cast<int>(std::lround(B.height * v.resolution_scale)));
  const double sx = static_cast<double>(K.width) / B.width, sy = static_cast<double>(K.height) / B.height;
  K.fx = B.fx * sx * v.focal_scale;
  K.fy = B.fy * sy * v.focal_scale;
  // The principal point keeps its place relative to the image centre, then moves.
  K.cx = (B.cx + 0.5) * sx - 0.5 + v.principal_dx * K.width;
  K.cy = (B.cy + 0.5) * sy - 0.5 + v.principal_dy * K.height;
  NoiseModel& n = c.noise;
  n.axial_sigma_base *= v.axial_noise_scale;
  n.axial_sigma_quadratic *= v.axial_noise_scale;
  n.grazing_start_deg = v.grazing_start_deg;
  n.grazing_full_deg = std::min(90.0, v.grazing_start_deg + 12.0);
  n.mixed_pixels = v.mixed_pixels;
  n.speckle = v.speckle;
  return c;
}

Result<Pose> VariedCameraPose(const Pose& X_BC, const BinSpec& bin, const std::vector<CameraConfig>& configs,
                              const SceneVariety& v) {
  // Where the optical axis meets the floor plane (bin frame z = 0).
  const Vec3 o = X_BC.translation(), d = X_BC.linear().col(2);
  const Vec3 n = bin.X_BW.linear().col(2);
  const double along = n.dot(d);
  const double t = std::abs(along) > 1e-9 ? n.dot(bin.X_BW.translation() - o) / along : -1.0;
  if (!(t > 0)) return Status::InvalidArgument("variety: the camera's optical axis does not meet the bin floor");
  const Vec3 pivot = o + t * d;
  // Tilt about a horizontal axis (in the floor plane) at the drawn azimuth.
  const Vec3 x_W = bin.X_BW.linear().col(0), y_W = bin.X_BW.linear().col(1);
  const double az = v.tilt_azimuth_deg * kDeg;
  const Vec3 axis = std::cos(az) * x_W + std::sin(az) * y_W;
  const Mat3 R = Eigen::AngleAxisd(v.tilt_deg * kDeg, axis).toRotationMatrix();
  Pose X = Pose::Identity();
  X.linear() = R * X_BC.linear() * Eigen::AngleAxisd(v.roll_deg * kDeg, Vec3::UnitZ()).toRotationMatrix();
  X.translation() = pivot + R * (o - pivot);
  const std::vector<Vec3> corners = InnerBoxCorners(bin);
  for (int step = 0; step <= 100; ++step) {
    Pose backed = X;
    backed.translation() -= 0.01 * step * X.linear().col(2);
    bool all = true;
    for (const CameraConfig& c : configs) all = all && InView(backed, corners, c);
    if (all) return backed;
  }
  return Status::InvalidArgument("variety: the bin is not in view of the tilted camera even 1 m further back");
}

}  // namespace bp
