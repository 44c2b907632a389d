#include "pipeline/internal/verification.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "pipeline/frame.h"
#include "pipeline/internal/depth_window.h"
#include "pipeline/internal/int_math.h"
#include "pipeline/internal/pose_model.h"

namespace bp::internal {

namespace {

// Model points facing the camera by less than this cosine (more than 60 deg
// off the line of sight) lie on grazing faces, where depth sensors (and the
// synthetic noise model) drop pixels.
constexpr float kGrazingCos = 0.5f;
// A view point deprojected from a depth image projects back onto its pixel's
// centre, at its depth, but for float rounding through B and back.
constexpr OnPixelTolerance kOnPixel{};
// The largest depth-image window (half width, pixels) the support test
// scans before it asks the hash.
constexpr int kMaxSupportWindow = 3;
// A hole point in view faces the camera by at least this cosine (its face does).
constexpr float kHoleMinCos = 0.3f;
// A model point counts as in free space only when the measured surface lies
// beyond it at the pixel and at the pixels about kFreeSpaceReach (metres)
// around it: one pixel off the part's silhouette, where the depth jumps to
// what is behind, is an alignment error of a pixel, not evidence against the
// pose.
constexpr double kFreeSpaceReach = 0.0013;
// Verify with a bar: the samples are taken in this many interleaved rounds,
// and the bound checked after each.
constexpr size_t kBoundRounds = 8;

// True if every finite depth at (u, v) and at the 8 pixels `reach` away is
// beyond `limit`.
bool FreeAround(const DepthImage& depth, int u, int v, float limit, double reach_px) {
  const int r = std::max(1, static_cast<int>(std::lround(reach_px)));
  for (int dv = -r; dv <= r; dv += r) {
    const int vv = v + dv;
    if (vv < 0 || vv >= depth.height) continue;
    for (int du = -r; du <= r; du += r) {
      const int uu = u + du;
      if (uu < 0 || uu >= depth.width) continue;
      const float z = depth.at(uu, vv);
      if (std::isfinite(z) && z > 0 && z <= limit) return false;
    }
  }
  return true;
}

// A model sample facing the camera, in B, with the cosine of its normal to
// the line of sight.
struct FacingSample {
  Eigen::Vector3f p;
  float cos;
};

// Step 1: the verification samples (every stride-th) facing the camera c
// by at least visible_min_cos at X_BO = (R, t).
std::vector<FacingSample> FacingSamples(const PoseModel& m, const Eigen::Matrix3f& R, const Eigen::Vector3f& t,
                                        const Eigen::Vector3f& c, int stride) {
  const float min_cos = static_cast<float>(m.options.visible_min_cos);
  std::vector<FacingSample> cands;
  cands.reserve(m.verify.size() / 2 + 1);
  // Most samples that face away are rejected in O first, without the
  // transform, the root or the division; the margin leaves every sample near
  // the limit to the exact test in B below, so the result is the same.
  const Eigen::Vector3f c_O = R.transpose() * (c - t);
  const bool prefilter = min_cos > 0.01f;
  const float lo = min_cos - 1e-3f, lo2 = lo * lo;
  for (size_t i = 0; i < m.verify.size(); i += static_cast<size_t>(std::max(1, stride))) {
    if (prefilter) {
      const Eigen::Vector3f v = c_O - m.verify.points[i];
      const float dot = m.verify.normals[i].dot(v);
      if (dot <= 0.f || dot * dot < lo2 * v.squaredNorm()) continue;
    }
    const Eigen::Vector3f p = R * m.verify.points[i] + t;
    const Eigen::Vector3f n = R * m.verify.normals[i];
    const Eigen::Vector3f to_cam = c - p;
    const float dist = to_cam.norm();
    const float cs = n.dot(to_cam) / std::max(dist, 1e-9f);
    if (cs >= min_cos) cands.push_back({p, cs});
  }
  return cands;
}

// Step 2: a small angular depth buffer of the facing samples seen from the
// camera, for self-occlusion.
struct SelfOcclusion {
  Eigen::Vector3f z;                 // viewing direction through the part's centroid
  float cell_m = 0.f;                // cell size at the part, metres
  std::vector<float> zbuf;           // nearest depth per cell
  std::vector<int> cell_of;          // per facing sample, -1: off the buffer

  // True when sample i lies behind the part's own nearer surface.
  bool Hidden(const std::vector<FacingSample>& cands, size_t i, const Eigen::Vector3f& c, float tan_theta) const {
    const float d = (cands[i].p - c).dot(z);
    return d > zbuf[static_cast<size_t>(cell_of[i])] + cell_m * (0.5f + tan_theta);
  }
};

SelfOcclusion SplatSelfOcclusion(const PoseModel& m, const std::vector<FacingSample>& cands,
                                 const Eigen::Vector3f& o, const Eigen::Vector3f& c, int stride) {
  SelfOcclusion s;
  s.z = (o - c).normalized();
  const Eigen::Vector3f x = s.z.unitOrthogonal();
  const Eigen::Vector3f y = s.z.cross(x);
  const float range = std::max((o - c).norm(), 1e-3f);
  s.cell_m = 1.5f * static_cast<float>(m.options.verify_model_spacing) * std::sqrt(static_cast<float>(std::max(1, stride)));
  const float cell_ang = s.cell_m / range;
  const int half = static_cast<int>(std::ceil(1.2 * m.diameter / s.cell_m)) + 2;
  const int N = 2 * half + 1;
  s.zbuf.assign(static_cast<size_t>(N) * N, std::numeric_limits<float>::infinity());
  s.cell_of.assign(cands.size(), -1);
  for (size_t i = 0; i < cands.size(); ++i) {
    const Eigen::Vector3f v = cands[i].p - c;
    const float d = v.dot(s.z);
    if (d <= 0) continue;
    const int u = FloorToInt(v.dot(x) / d / cell_ang) + half;
    const int w = FloorToInt(v.dot(y) / d / cell_ang) + half;
    if (u < 0 || w < 0 || u >= N || w >= N) continue;
    s.cell_of[i] = w * N + u;
    s.zbuf[s.cell_of[i]] = std::min(s.zbuf[s.cell_of[i]], d);
  }
  return s;
}

}  // namespace

float SegmentDepth::At(const Eigen::Vector3f& p, float* d) const {
  const Eigen::Vector3f v = p - c;
  *d = v.dot(z);
  if (*d <= 0) return std::numeric_limits<float>::quiet_NaN();
  const int u = static_cast<int>(std::floor(v.dot(x) / *d / cell_ang - u0));
  const int w = static_cast<int>(std::floor(v.dot(y) / *d / cell_ang - v0));
  if (u < 0 || w < 0 || u >= nu || w >= nv) return std::numeric_limits<float>::quiet_NaN();
  const float zm = zmin[static_cast<size_t>(w) * nu + u];
  return std::isfinite(zm) ? zm : std::numeric_limits<float>::quiet_NaN();
}

SegmentDepth BuildSegmentDepth(std::span<const Eigen::Vector3f> pts, const Eigen::Vector3f& camera, float cell_m) {
  SegmentDepth b;
  Eigen::Vector3f mean = Eigen::Vector3f::Zero();
  for (const auto& p : pts) mean += p;
  mean /= static_cast<float>(pts.size());
  b.c = camera;
  const float range = (mean - camera).norm();
  if (!(range > 1e-3f)) return b;
  b.z = (mean - camera) / range;
  b.x = b.z.unitOrthogonal();
  b.y = b.z.cross(b.x);
  b.cell_ang = cell_m / range;
  float umin = 1e30f, umax = -1e30f, vmin = 1e30f, vmax = -1e30f;
  std::vector<Eigen::Vector3f> uvd(pts.size());
  for (size_t i = 0; i < pts.size(); ++i) {
    const Eigen::Vector3f v = pts[i] - camera;
    const float d = v.dot(b.z);
    if (d <= 0) {
      uvd[i] = Eigen::Vector3f(0, 0, -1);
      continue;
    }
    uvd[i] = Eigen::Vector3f(v.dot(b.x) / d / b.cell_ang, v.dot(b.y) / d / b.cell_ang, d);
    umin = std::min(umin, uvd[i].x()), umax = std::max(umax, uvd[i].x());
    vmin = std::min(vmin, uvd[i].y()), vmax = std::max(vmax, uvd[i].y());
  }
  if (umin > umax) return b;
  b.u0 = std::floor(umin) - 1, b.v0 = std::floor(vmin) - 1;
  b.nu = static_cast<int>(umax - b.u0) + 2, b.nv = static_cast<int>(vmax - b.v0) + 2;
  if (static_cast<int64_t>(b.nu) * b.nv > 4'000'000) return SegmentDepth{};  // absurd extent: skip the test
  b.zmin.assign(static_cast<size_t>(b.nu) * b.nv, std::numeric_limits<float>::infinity());
  for (const auto& e : uvd) {
    if (e.z() <= 0) continue;
    const size_t k = static_cast<size_t>(static_cast<int>(e.y() - b.v0)) * b.nu + static_cast<int>(e.x() - b.u0);
    b.zmin[k] = std::min(b.zmin[k], e.z());
  }
  return b;
}

void SceneSupport::Build(std::span<const Eigen::Vector3f> pts, float cell, const SceneView& view) {
  hash.Build(pts, cell);
  on_depth = false;
  if (view.depth == nullptr || view.depth->empty() || !view.intrinsics.valid() || pts.empty()) return;
  const Pose X_CB = view.X_BC.inverse();
  const Eigen::Matrix3f R = X_CB.linear().cast<float>();
  const Eigen::Vector3f t = X_CB.translation().cast<float>();
  for (const Eigen::Vector3f& p : pts) {
    if (!OnItsPixel(view.intrinsics, *view.depth, R * p + t, kOnPixel)) return;
  }
  on_depth = true;
}

bool SceneSupport::AnyWithin(const Eigen::Vector3f& p, float r, const Eigen::Vector3f& p_C, int u, int v,
                             const SceneView& view) const {
  if (on_depth &&
      !DepthWindowMayHoldPointNear(*view.depth, view.intrinsics, p_C, u, v, r, kOnPixel, kMaxSupportWindow)) {
    return false;
  }
  return hash.AnyWithin(p, r);
}

VerifyStats Verify(const PoseModel& m, const Pose& X_BO, const SceneView& view, const SceneSupport& scene,
                   const SegmentDepth& segment_depth, int stride, bool unmeasured_is_no_evidence, double bar) {
  VerifyStats s;
  const Eigen::Matrix3f R = X_BO.linear().cast<float>();
  const Eigen::Vector3f t = X_BO.translation().cast<float>();
  if (view.support_plane_B) {
    const Eigen::Vector3f n = view.support_plane_B->head<3>().cast<float>();
    const float d = static_cast<float>((*view.support_plane_B)[3]);
    const float limit = -static_cast<float>(m.options.max_support_penetration);
    for (const auto& p : m.verify_extreme) {
      if (n.dot(R * p + t) + d < limit) {
        s.below_support = true;
        return s;
      }
    }
  }
  const Eigen::Vector3f c = view.X_BC.translation().cast<float>();
  const std::vector<FacingSample> cands = FacingSamples(m, R, t, c, stride);
  if (cands.empty()) return s;
  const SelfOcclusion self = SplatSelfOcclusion(m, cands, R * m.centroid_O + t, c, stride);

  // Step 3: each visible sample's evidence.
  const bool have_depth = view.depth != nullptr && !view.depth->empty() && view.intrinsics.valid();
  const Pose X_CB = view.X_BC.inverse();
  const Eigen::Matrix3f R_CB = X_CB.linear().cast<float>();
  const Eigen::Vector3f t_CB = X_CB.translation().cast<float>();
  const float support = static_cast<float>(m.options.support_distance);
  const float free_thr = static_cast<float>(m.options.free_space_distance);
  // One sample's evidence into s.
  const auto take = [&](size_t i) {
    if (self.cell_of[i] < 0) return;
    const float cs = cands[i].cos;
    const float tan_theta = std::sqrt(std::max(0.f, 1 - cs * cs)) / cs;
    if (self.Hidden(cands, i, c, tan_theta)) return;  // hidden by the part itself
    ++s.visible;
    bool supported = false;
    if (have_depth) {
      // O(1) through the depth image first; the segment's points only when
      // the pixel disagrees.
      const Eigen::Vector3f pc = R_CB * cands[i].p + t_CB;
      const Intrinsics& K = view.intrinsics;
      int u = 0, v = 0;
      if (!PixelOf(K, *view.depth, pc, &u, &v)) {
        // Outside the image: no depth there, as at a dropped pixel (a cloud's
        // image is the crop's window of the camera's).
        supported = scene.hash.AnyWithin(cands[i].p, support);
        if (!supported && cs < kGrazingCos) ++s.unmeasured;
      } else {
        const float zm = view.depth->at(u, v);
        if (std::isfinite(zm) && zm > 0) {
          // Slanted surfaces change depth by about a pixel footprint * tan(theta).
          const float slack = static_cast<float>(pc.z() / K.fx) * tan_theta;
          supported = std::abs(zm - pc.z()) < support + slack;
          if (!supported) supported = scene.AnyWithin(cands[i].p, support, pc, u, v, view);
          if (!supported) {
            if (zm < pc.z() - free_thr - slack) {
              ++s.occluded;
            } else if (zm > pc.z() + free_thr + slack && FreeAround(*view.depth, u, v, pc.z() + free_thr + slack,
                                                                     kFreeSpaceReach * K.fx / pc.z())) {
              ++s.free_space;
            }
          }
        } else {
          supported = scene.AnyWithin(cands[i].p, support, pc, u, v, view);
          if (!supported && cs < kGrazingCos) ++s.unmeasured;
        }
      }
    } else {
      supported = scene.hash.AnyWithin(cands[i].p, support);
    }
    if (!have_depth && !supported && !segment_depth.empty()) {
      // The segment's nearest surface along the ray: in front of it by more
      // than the threshold is free space; behind it, occluded by the segment.
      float dp = 0;
      const float zm = segment_depth.At(cands[i].p, &dp);
      if (std::isfinite(zm)) {
        const float slack = segment_depth.cell_ang * dp * tan_theta;
        if (dp < zm - free_thr) ++s.free_space;
        else if (dp > zm + free_thr + slack) ++s.occluded;
      }
    }
    if (supported) ++s.supported;
  };
  const auto denominator = [&] { return s.visible - s.occluded - (unmeasured_is_no_evidence ? s.unmeasured : 0); };
  const auto numerator = [&] { return s.supported - m.options.free_space_weight * s.free_space; };
  if (!(bar > -1.0)) {
    for (size_t i = 0; i < cands.size(); ++i) take(i);
  } else {
    // kBoundRounds interleaved rounds (every kBoundRounds-th sample from a
    // rising offset: the counts are the same in any order), so that the
    // samples seen after each round are spread over the part. After each,
    // the samples left are assumed supported, each adding one to the
    // numerator and to the denominator, the most one can add; below the
    // bar even so, the pose cannot reach it.
    const size_t rounds = std::min(kBoundRounds, cands.size());
    size_t seen = 0;
    for (size_t round = 0; round < rounds; ++round) {
      if (round > 0) {
        const double left = static_cast<double>(cands.size() - seen);
        const double d = denominator() + left;
        if (d > 0 && (numerator() + left) / d < bar) {
          s.score = (numerator() + left) / d;
          s.cut_short = true;
          return s;
        }
      }
      for (size_t i = round; i < cands.size(); i += rounds, ++seen) take(i);
    }
  }
  const int denom = denominator();
  if (denom > 0) s.score = numerator() / static_cast<double>(denom);
  return s;
}

std::pair<int, int> HoleStats(const PoseModel& m, const Pose& X_BO, const SceneView& view) {
  int in_view = 0, filled = 0;
  if (m.holes.empty() || view.depth == nullptr || view.depth->empty() || !view.intrinsics.valid()) return {0, 0};
  const Eigen::Matrix3f R = X_BO.linear().cast<float>();
  const Eigen::Vector3f t = X_BO.translation().cast<float>();
  const Eigen::Vector3f c = view.X_BC.translation().cast<float>();
  const Pose X_CB = view.X_BC.inverse();
  const Eigen::Matrix3f R_CB = X_CB.linear().cast<float>();
  const Eigen::Vector3f t_CB = X_CB.translation().cast<float>();
  // Measured points back to O: p_O = R^T (X_BC p_C - t).
  const Eigen::Matrix3f R_OC = R.transpose() * view.X_BC.linear().cast<float>();
  const Eigen::Vector3f t_OC = R.transpose() * (view.X_BC.translation().cast<float>() - t);
  const Intrinsics& K = view.intrinsics;
  const float support = static_cast<float>(m.options.support_distance);
  const float free_thr = static_cast<float>(m.options.free_space_distance);
  const float margin = static_cast<float>(m.options.hole_margin);
  for (const HolePoint& h : m.holes) {
    const Eigen::Vector3f p = R * h.p + t;
    const Eigen::Vector3f to_cam = c - p;
    const float dist = to_cam.norm();
    const float cs = (R * h.n).dot(to_cam) / std::max(dist, 1e-9f);
    if (cs < kHoleMinCos) continue;
    const Eigen::Vector3f pc = R_CB * p + t_CB;
    int u = 0, v = 0;
    if (!PixelOf(K, *view.depth, pc, &u, &v)) continue;
    const float zm = view.depth->at(u, v);
    if (!std::isfinite(zm) || !(zm > 0)) continue;
    const float slack = static_cast<float>(pc.z() / K.fx) * std::sqrt(std::max(0.f, 1 - cs * cs)) / cs;
    if (zm < pc.z() - free_thr - slack) continue;  // something in front: no evidence
    ++in_view;
    if (std::abs(zm - pc.z()) >= support + slack) continue;
    const Eigen::Vector3f m_C = Deproject(K, static_cast<float>(u), static_cast<float>(v), zm);
    if (!m.OnSurface(R_OC * m_C + t_OC, margin)) ++filled;
  }
  return {in_view, filled};
}


}  // namespace bp::internal
