#include "grasp/internal/surface_explanation.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>

#include "pipeline/internal/model_sampling.h"

namespace bp::internal {

PartSurface PartSurface::Sample(const TriangleMesh& mesh, double spacing, double max_radius) {
  constexpr uint64_t kSampleSeed = 0x5EF5u;  // the same samples every build
  OrientedPoints s = SampleSurface(mesh, spacing, kSampleSeed);
  PartSurface out;
  out.points_ = std::move(s.points);
  out.normals_ = std::move(s.normals);
  for (const Eigen::Vector3f& p : out.points_) out.bounds_.extend(p);
  out.hash_.Build(out.points_, static_cast<float>(max_radius));
  return out;
}

bool PartSurface::Explains(const Eigen::Vector3f& q_O, float radius, const Eigen::Vector3f* eye_O,
                           float min_cos) const {
  bool found = false;
  hash_.ForEachWithin(q_O, radius, [&](int i, float) {
    if (found) return;
    if (eye_O == nullptr) {
      found = true;
      return;
    }
    const Eigen::Vector3f& p = points_[static_cast<size_t>(i)];
    const Eigen::Vector3f to_eye = *eye_O - p;
    found = normals_[static_cast<size_t>(i)].dot(to_eye) >= min_cos * to_eye.norm();
  });
  return found;
}

void ExplainBySurfaces(std::span<const Eigen::Vector3f> points, std::span<const PlacedSurface> parts, float radius,
                       const std::optional<Eigen::Vector3f>& eye_B, float min_cos, std::vector<uint8_t>& explained) {
  // Per part: B -> O, its samples' box grown by the radius (in O), and the eye in O.
  struct Placed {
    const PartSurface* surface;
    Eigen::Matrix3f R_OB;
    Eigen::Vector3f t_OB;
    Eigen::AlignedBox3f box_O;
    Eigen::Vector3f eye_O;
  };
  std::vector<Placed> placed;
  for (const PlacedSurface& p : parts) {
    if (p.surface == nullptr || p.surface->size() == 0) continue;
    const Pose X_OB = p.X_BO.inverse();
    Placed q{p.surface, X_OB.linear().cast<float>(), X_OB.translation().cast<float>(), p.surface->bounds(),
             Eigen::Vector3f::Zero()};
    q.box_O.min().array() -= radius;
    q.box_O.max().array() += radius;
    if (eye_B) q.eye_O = q.R_OB * *eye_B + q.t_OB;
    placed.push_back(q);
  }
  if (placed.empty()) return;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, points.size(), 4096), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t i = r.begin(); i < r.end(); ++i) {
      if (explained[i] || !points[i].allFinite()) continue;
      for (const Placed& p : placed) {
        const Eigen::Vector3f q = p.R_OB * points[i] + p.t_OB;
        if (!p.box_O.contains(q)) continue;
        if (p.surface->Explains(q, radius, eye_B ? &p.eye_O : nullptr, min_cos)) {
          explained[i] = 1;
          break;
        }
      }
    }
  });
}

}  // namespace bp::internal
