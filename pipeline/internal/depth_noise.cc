#include "pipeline/internal/depth_noise.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>
#include <vector>

namespace bp::internal {

Intrinsics ProjectorIntrinsics(const Intrinsics& K, const Vec3& offset, double min_depth) {
  Intrinsics P = K;
  P.distortion = {};
  const double z = std::max(min_depth, 0.05);
  const int pad_x = static_cast<int>(std::ceil(K.fx * std::abs(offset.x()) / z)) + 2;
  const int pad_y = static_cast<int>(std::ceil(K.fy * std::abs(offset.y()) / z)) + 2;
  P.width = K.width + 2 * std::min(pad_x, K.width);
  P.height = K.height + 2 * std::min(pad_y, K.height);
  P.cx = K.cx + std::min(pad_x, K.width);
  P.cy = K.cy + std::min(pad_y, K.height);
  return P;
}

namespace {

uint64_t SplitMix(uint64_t x) {
  x += 0x9E3779B97F4A7C15ull;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ull;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBull;
  return x ^ (x >> 31);
}

// Deprojection with the divisions done once.
struct Pinhole {
  explicit Pinhole(const Intrinsics& K) : cx(K.cx), cy(K.cy), ifx(1.0 / K.fx), ify(1.0 / K.fy) {}
  double cx, cy, ifx, ify;
};

Eigen::Vector3d Point(const Pinhole& K, int u, int v, double z) {
  return {(u - K.cx) * K.ifx * z, (v - K.cy) * K.ify * z, z};
}

// Cosine between the surface normal (from the clean depth) and the viewing
// ray at (u, v); NaN if no neighbour is valid in one direction. Uses the
// neighbour with the smaller depth step so that edges do not bend the normal.
// Returns 1 instead when the cosine is certainly above the cosine whose
// square (times 1 + 1e-9) is `above_sq` (no square root or division: the
// margin is far wider than the few ulps between the two ways of computing
// it, so callers that only compare with that cosine decide the same).
double ViewCosine(const DepthImage& d, const Pinhole& K, int u, int v, double above_sq) {
  const double z = d.at(u, v);
  const Eigen::Vector3d P = Point(K, u, v, z);
  auto tangent = [&](int du, int dv, Eigen::Vector3d& t) {
    double best = std::numeric_limits<double>::infinity();
    for (int s : {1, -1}) {
      const int uu = u + s * du, vv = v + s * dv;
      if (uu < 0 || vv < 0 || uu >= d.width || vv >= d.height) continue;
      const double zz = d.at(uu, vv);
      if (!std::isfinite(zz) || std::abs(zz - z) >= best) continue;
      best = std::abs(zz - z);
      t = (Point(K, uu, vv, zz) - P) * s;
    }
    return std::isfinite(best);
  };
  Eigen::Vector3d tx = Eigen::Vector3d::Zero(), ty = Eigen::Vector3d::Zero();  // set when tangent() is true
  if (!tangent(1, 0, tx) || !tangent(0, 1, ty)) return std::numeric_limits<double>::quiet_NaN();
  const Eigen::Vector3d n = tx.cross(ty);
  const double dot = n.dot(P);
  if (dot * dot > n.squaredNorm() * P.squaredNorm() * above_sq) return 1.0;
  const double nn = n.norm() * P.norm();
  if (nn <= 0) return std::numeric_limits<double>::quiet_NaN();
  return std::abs(dot) / nn;
}

// The clean depth of the 4-neighbour of (u, v) farthest in depth from z when
// that is more than `jump` away (a depth edge), else NaN.
double EdgeNeighbourDepth(const DepthImage& d, int u, int v, double z, double jump) {
  double best = jump, far = std::numeric_limits<double>::quiet_NaN();
  const int du[] = {1, -1, 0, 0}, dv[] = {0, 0, 1, -1};
  for (int k = 0; k < 4; ++k) {
    const int uu = u + du[k], vv = v + dv[k];
    if (uu < 0 || vv < 0 || uu >= d.width || vv >= d.height) continue;
    const double zz = d.at(uu, vv);
    if (std::isfinite(zz) && std::abs(zz - z) > best) {
      best = std::abs(zz - z);
      far = zz;
    }
  }
  return far;
}

// std::floor for |x| < 2^30, as an int: without SSE4.1 (the baseline x86-64
// build) std::floor is a slow sequence, and this is the noise's hot loop.
int FloorInt(double x) {
  const int t = static_cast<int>(x);  // rounds towards zero
  return t - (x < t ? 1 : 0);
}

// True if the projector sees the camera point P_C (depth test against the
// projector's depth map; the 2x2 neighbourhood tolerates steep slopes).
// `*u_read`, `*v_read`: the top-left pixel of the 2x2 block read, u = -1
// when none was.
bool Illuminated(const NoiseInputs& in, const Eigen::Vector3d& P_C, int* u_read, int* v_read) {
  *u_read = -1;
  *v_read = -1;
  const Eigen::Vector3d P = P_C - in.projector_offset;
  if (P.z() <= 0) return false;
  const Intrinsics& K = *in.K_projector;
  const double iz = 1.0 / P.z();
  const double x = K.fx * P.x() * iz + K.cx, y = K.fy * P.y() * iz + K.cy;
  if (!(std::abs(x) < 0x1p30 && std::abs(y) < 0x1p30)) return true;  // far outside the map: lit
  const int u0 = FloorInt(x), v0 = FloorInt(y);
  if (u0 < 0 || v0 < 0 || u0 + 1 >= K.width || v0 + 1 >= K.height)
    return true;  // outside the map: lit
  *u_read = u0;
  *v_read = v0;
  double far_z = -1;
  for (int dv = 0; dv <= 1; ++dv) {
    for (int du = 0; du <= 1; ++du) {
      const float z = in.projector_depth->at(u0 + du, v0 + dv);
      far_z = std::max(far_z, std::isfinite(z) ? static_cast<double>(z) : 1e9);
    }
  }
  const double tolerance = 0.001 + 0.002 * P.z();
  return P.z() <= far_z + tolerance;
}

bool SameIntrinsics(const Intrinsics& a, const Intrinsics& b) {
  return a.width == b.width && a.height == b.height && a.fx == b.fx && a.fy == b.fy && a.cx == b.cx &&
         a.cy == b.cy;
}

// True when `g` was computed for these inputs (the images aside).
bool GeometryFits(const NoiseGeometry& g, const NoiseModel& model, const NoiseInputs& in, bool shadow, int w,
                  int h) {
  if (g.width != w || g.height != h || g.grazing_start_deg != model.grazing_start_deg ||
      g.grazing_full_deg != model.grazing_full_deg || g.shadow != shadow || !SameIntrinsics(g.K, *in.K)) {
    return false;
  }
  return !shadow || (SameIntrinsics(g.K_projector, *in.K_projector) && g.projector_offset == in.projector_offset);
}

}  // namespace

void ApplyDepthNoise(const NoiseModel& model, const NoiseInputs& in, uint64_t seed, const DepthImage& depth,
                     DepthImage& noisy) {
  NoiseGeometry geometry;
  ApplyDepthNoise(model, in, seed, depth, noisy, geometry, NoiseChanges{});
}

void ApplyDepthNoise(const NoiseModel& model, const NoiseInputs& in, uint64_t seed, const DepthImage& depth,
                     DepthImage& noisy, NoiseGeometry& geometry, const NoiseChanges& changes) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const int w = depth.width, h = depth.height;
  if (noisy.width != w || noisy.height != h) noisy = DepthImage(w, h);
  // The depth range, applied last to what the noise left.
  const auto in_range = [&](float z) { return std::isfinite(z) && (z < in.min_depth || z > in.max_depth) ? nan : z; };
  if (!model.enabled) {
    geometry.width = 0;  // its inputs' changes are not followed meanwhile
    for (size_t i = 0; i < depth.data.size(); ++i) noisy.data[i] = in_range(depth.data[i]);
    return;
  }
  const Pinhole K(*in.K);
  const double cos_start = std::cos(model.grazing_start_deg * M_PI / 180.0);
  const double cos_full = std::cos(model.grazing_full_deg * M_PI / 180.0);
  const bool shadow = model.projector_shadow && in.projector_depth && in.K_projector;
  const double above_sq =
      cos_start > 0 ? cos_start * cos_start * (1 + 1e-9) : std::numeric_limits<double>::infinity();

  // The cached geometry: where to compute it again.
  const bool all = changes.all || !GeometryFits(geometry, model, in, shadow, w, h) ||
                   (shadow && (in.K_projector->width > 32767 || in.K_projector->height > 32767));
  if (all) {
    geometry.code.assign(static_cast<size_t>(w) * h, NoiseGeometry::kNoDepth);
    geometry.projector_u.assign(static_cast<size_t>(w) * h, -1);
    geometry.projector_v.assign(static_cast<size_t>(w) * h, -1);
    geometry.ramp_drop.resize(static_cast<size_t>(w) * h);  // read only where classify wrote it
    geometry.width = w;
    geometry.height = h;
    geometry.grazing_start_deg = model.grazing_start_deg;
    geometry.grazing_full_deg = model.grazing_full_deg;
    geometry.shadow = shadow;
    geometry.K = *in.K;
    if (shadow) {
      geometry.K_projector = *in.K_projector;
      geometry.projector_offset = in.projector_offset;
    }
  }
  // A pixel's grazing class reads its 4-neighbours' depth; its shadow, its
  // own depth and the 2 x 2 projector block it falls on.
  const PixelRect& dd = changes.depth;
  const PixelRect depth_rect = dd.empty() ? dd : PixelRect{dd.u0 - 1, dd.v0 - 1, dd.u1 + 1, dd.v1 + 1};
  const PixelRect& pr = changes.projector;
  const bool projector_changed = shadow && !pr.empty();
  const double span = model.grazing_full_deg - model.grazing_start_deg;
  // The seed-independent verdicts of pixel (u, v), clean depth z (finite).
  const auto classify = [&](int u, int v, double z, size_t i) {
    const double c = ViewCosine(depth, K, u, v, above_sq);
    uint8_t code = !(std::isfinite(c) && c < cos_start) ? NoiseGeometry::kFacing
                   : c <= cos_full                      ? NoiseGeometry::kDropped
                                                        : NoiseGeometry::kRamp;
    if (code == NoiseGeometry::kRamp) {
      // Grazing dropout: probability ramps linearly in angle from start to full.
      const double angle = std::acos(std::clamp(c, 0.0, 1.0)) * 180.0 / M_PI;
      geometry.ramp_drop[i] = (angle - model.grazing_start_deg) / span;
    }
    int pu = -1, pv = -1;
    if (shadow && !Illuminated(in, Point(K, u, v, z), &pu, &pv)) code |= NoiseGeometry::kShadowed;
    geometry.code[i] = code;
    geometry.projector_u[i] = static_cast<int16_t>(pu);
    geometry.projector_v[i] = static_cast<int16_t>(pv);
  };

  // Rows in parallel; each row has its own RNG stream (seed, row), so the
  // result does not depend on the schedule.
  tbb::parallel_for(tbb::blocked_range<int>(0, h), [&](const tbb::blocked_range<int>& rows) {
    for (int v = rows.begin(); v < rows.end(); ++v) {
      NoiseDraws draw(SplitMix(seed ^ SplitMix(static_cast<uint64_t>(v))));
      float* row = &noisy.at(0, v);
      const size_t row_start = static_cast<size_t>(v) * w;
      const bool row_in_depth_rect = v >= depth_rect.v0 && v <= depth_rect.v1;
      for (int u = 0; u < w; ++u) {
        row[u] = nan;
        const double z = depth.at(u, v);
        const size_t i = row_start + u;
        if (all || (row_in_depth_rect && u >= depth_rect.u0 && u <= depth_rect.u1)) {
          if (std::isfinite(z)) {
            classify(u, v, z, i);
          } else {
            geometry.code[i] = NoiseGeometry::kNoDepth;
            geometry.projector_u[i] = -1;
          }
        } else if (projector_changed && geometry.projector_u[i] >= 0) {
          const int pu = geometry.projector_u[i], pv = geometry.projector_v[i];
          if (pu + 1 >= pr.u0 && pu <= pr.u1 && pv + 1 >= pr.v0 && pv <= pr.v1) classify(u, v, z, i);
        }
        if (!std::isfinite(z)) continue;
        const uint8_t code = geometry.code[i];
        if ((code & NoiseGeometry::kClassMask) == NoiseGeometry::kDropped) continue;
        if ((code & NoiseGeometry::kClassMask) == NoiseGeometry::kRamp &&
            (span <= 0 || draw.Uniform() < geometry.ramp_drop[i])) {
          continue;
        }
        if (shadow && (code & NoiseGeometry::kShadowed)) continue;
        if (model.random_dropout > 0 && draw.Uniform() < model.random_dropout) continue;
        const double sigma = model.axial_sigma_base + model.axial_sigma_quadratic * z * z;
        double value = z + sigma * draw.Normal();
        // Draws only when a model is on: frames without them stay bit for bit.
        if (model.mixed_pixels > 0) {
          const double far = EdgeNeighbourDepth(depth, u, v, z, model.mixed_pixel_jump);
          if (std::isfinite(far) && draw.Uniform() < model.mixed_pixels) value = z + draw.Uniform() * (far - z);
        }
        if (model.speckle > 0 && draw.Uniform() < model.speckle) value += model.speckle_sigma * draw.Normal();
        row[u] = in_range(static_cast<float>(value));
      }
    }
  });
}

void ApplyDepthNoise(const NoiseModel& model, const NoiseInputs& in, uint64_t seed, DepthImage& depth) {
  DepthImage noisy;
  ApplyDepthNoise(model, in, seed, depth, noisy);
  depth = std::move(noisy);
}

}  // namespace bp::internal
