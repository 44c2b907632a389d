#include "pipeline/internal/face_seeds.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "pipeline/internal/model_geometry.h"
#include "pipeline/internal/planar_faces.h"
#include "pipeline/internal/pose_model.h"

namespace bp::internal {

namespace {

constexpr double kDeg = M_PI / 180.0;
// Face seeds align a face's axes with the view's principal axis and with up
// to this many more directions, those of the view's longest convex-hull edges
// (merged within kFaceEdgeMergeDeg, modulo 90 deg).
constexpr int kFaceEdgeDirections = 2;
constexpr double kFaceEdgeMergeDeg = 5.0;
// Face seeds are ranked by a verification of every kFaceSeedStride-th
// sample, after a screen of every kFaceSeedScreenStride-th sample has kept
// the best kFaceSeedsScreened (docs/tuning.md, face_seeds).
constexpr int kFaceSeedStride = 6;
constexpr int kFaceSeedScreenStride = 24;
constexpr size_t kFaceSeedsScreened = 6;
}  // namespace

void AppendFaceSeeds(const PoseModel& m, std::span<const Eigen::Vector3f> scene, const Eigen::Vector3f& n,
                     const SceneView& view, const SceneSupport& support, const SegmentDepth& segment_depth, int keep,
                     std::vector<CoarsePose>& coarse) {
  Eigen::Vector3f c, a, b;
  Eigen::Vector2f lo, hi;
  PlaneFrame(scene, n, &c, &a, &b, &lo, &hi);
  // The view in its plane, (a, b) coordinates about c.
  std::vector<Eigen::Vector2f> q;
  q.reserve(scene.size());
  for (const auto& p : scene) q.emplace_back(a.dot(p - c), b.dot(p - c));
  // In-plane directions to align a face's axes with: the view's principal
  // axis, and its convex hull's long edges (a partly hidden face keeps some
  // of its straight edges; its principal axes turn with what is hidden).
  // Directions modulo 90 deg: each is tried in its four quarter turns.
  std::vector<float> angles = {0.f};
  {
    const std::vector<Eigen::Vector2f> hull = ConvexHull2(q);
    std::vector<std::pair<float, float>> edges;  // (length, angle mod 90 deg)
    for (size_t i = 0; i < hull.size(); ++i) {
      const Eigen::Vector2f e = hull[(i + 1) % hull.size()] - hull[i];
      float ang = std::atan2(e.y(), e.x());
      ang = std::fmod(ang + static_cast<float>(4 * M_PI), static_cast<float>(M_PI / 2));
      edges.emplace_back(e.norm(), ang);
    }
    std::stable_sort(edges.begin(), edges.end(), [](const auto& x, const auto& y) { return x.first > y.first; });
    const float same = static_cast<float>(kFaceEdgeMergeDeg * kDeg), quarter = static_cast<float>(M_PI / 2);
    for (const auto& [len, edge_ang] : edges) {
      if (len < kMinFaceExtent || static_cast<int>(angles.size()) > kFaceEdgeDirections) break;
      const float ang = edge_ang;  // a copy: clang 14 cannot capture a structured binding
      const bool known = std::any_of(angles.begin(), angles.end(), [&](float x) {
        const float d = std::abs(x - ang);
        return std::min(d, quarter - d) < same;
      });
      if (!known) angles.push_back(ang);
    }
  }
  const float tol = 0.004f;  // box slack: depth noise and normal outliers along the view's border
  const Eigen::Vector3f axis = m.symmetry.axis.cast<float>().normalized();
  std::vector<std::pair<double, CoarsePose>> seeds;
  for (const PlanarFace& f : m.faces) {
    const Eigen::Vector2f fext = f.hi - f.lo;
    // A face a revolute part's axis is normal to looks the same at every turn.
    const bool round = m.symmetry.kind == Symmetry::Kind::kRevolute && std::abs(f.n.dot(axis)) > 0.999f;
    for (size_t di = 0; di < (round ? 1 : angles.size()); ++di) {
      for (int k = 0; k < (round ? 1 : 4); ++k) {
        const float th = angles[di] + static_cast<float>(k * M_PI / 2);
        const Eigen::Vector2f dx(std::cos(th), std::sin(th)), dy(-dx.y(), dx.x());
        const Eigen::Vector3f x = dx.x() * a + dx.y() * b;
        const Eigen::Vector3f y = n.cross(x);  // = dy.x() a + dy.y() b
        // The view's box in (x, y) about c; the face's box must hold it.
        Eigen::Vector2f vlo = Eigen::Vector2f::Constant(std::numeric_limits<float>::infinity()), vhi = -vlo;
        for (const Eigen::Vector2f& p : q) {
          const Eigen::Vector2f r(p.dot(dx), p.dot(dy));
          vlo = vlo.cwiseMin(r);
          vhi = vhi.cwiseMax(r);
        }
        if ((vhi - vlo).x() > fext.x() + tol || (vhi - vlo).y() > fext.y() + tol) continue;
        Eigen::Matrix3f S, F;
        S << x, y, n;
        F << f.u, f.v, f.n;
        const Eigen::Matrix3f R = S * F.transpose();
        // Per axis: centre on centre when the face is no larger than the view
        // (within tol); else two placements, the boxes' low or high edges together.
        std::vector<float> off[2];
        for (int e = 0; e < 2; ++e) {
          if (fext[e] - (vhi[e] - vlo[e]) < tol) {
            off[e].push_back(0.5f * (vlo[e] + vhi[e]) - 0.5f * (f.lo[e] + f.hi[e]));
          } else {
            off[e].push_back(vlo[e] - f.lo[e]);
            off[e].push_back(vhi[e] - f.hi[e]);
          }
        }
        for (float ox : off[0]) {
          for (float oy : off[1]) {
            // The face centroid goes to c + ox x + oy y.
            CoarsePose cp;
            cp.X_BO = Pose::Identity();
            cp.X_BO.linear() = R.cast<double>();
            cp.X_BO.translation() = (c + ox * x + oy * y - R * f.c).cast<double>();
            const VerifyStats st = Verify(m, cp.X_BO, view, support, segment_depth, kFaceSeedScreenStride);
            if (st.below_support || !(st.score > 0)) continue;
            seeds.emplace_back(st.score, cp);
          }
        }
      }
    }
  }
  const auto by_score = [](const auto& p, const auto& q) { return p.first > q.first; };
  std::stable_sort(seeds.begin(), seeds.end(), by_score);
  if (seeds.size() > kFaceSeedsScreened) seeds.resize(kFaceSeedsScreened);
  for (auto& [score, cp] : seeds) score = Verify(m, cp.X_BO, view, support, segment_depth, kFaceSeedStride).score;
  std::stable_sort(seeds.begin(), seeds.end(), by_score);
  for (size_t i = 0; i < seeds.size() && static_cast<int>(i) < keep; ++i) coarse.push_back(seeds[i].second);
}

}  // namespace bp::internal
