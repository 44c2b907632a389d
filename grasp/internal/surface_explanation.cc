#include "grasp/internal/surface_explanation.h"

#include <tbb/blocked_range.h>
#include <tbb/combinable.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <utility>

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
  // The first sample that explains q_O ends the search (any one will do).
  return hash_.AnyWithinWhere(q_O, radius, [&](int i, float) {
    if (eye_O == nullptr) return true;
    const Eigen::Vector3f& p = points_[static_cast<size_t>(i)];
    const Eigen::Vector3f to_eye = *eye_O - p;
    return normals_[static_cast<size_t>(i)].dot(to_eye) >= min_cos * to_eye.norm();
  });
}

void ExplainBySurfaces(std::span<const Eigen::Vector3f> points, std::span<const PlacedSurface> parts, float radius,
                       const std::optional<Eigen::Vector3f>& eye_B, float min_cos, std::vector<uint8_t>& explained,
                       std::vector<std::vector<uint32_t>>* owned) {
  if (owned != nullptr) owned->assign(parts.size(), {});
  // Per part: B -> O, its samples' box grown by the radius (in O), and the eye in O.
  struct Placed {
    uint32_t part;  // index in `parts`
    const PartSurface* surface;
    Eigen::Matrix3f R_OB;
    Eigen::Vector3f t_OB;
    Eigen::AlignedBox3f box_O;
    Eigen::Vector3f eye_O;
    // box_O's corners placed in B, their box grown by kSlack: a point
    // outside it is outside box_O in O too, whatever the float rounding of
    // its transform (well under 1e-5 m in a cell metres across), so the
    // test in B, six comparisons, settles most points without the transform.
    Eigen::AlignedBox3f box_B;
  };
  constexpr double kSlack = 0.001;  // m
  std::vector<Placed> placed;
  for (const PlacedSurface& p : parts) {
    if (p.surface == nullptr || p.surface->size() == 0) continue;
    const Pose X_OB = p.X_BO.inverse();
    Placed q{static_cast<uint32_t>(&p - parts.data()), p.surface, X_OB.linear().cast<float>(), X_OB.translation().cast<float>(), p.surface->bounds(),
             Eigen::Vector3f::Zero(), Eigen::AlignedBox3f()};
    q.box_O.min().array() -= radius;
    q.box_O.max().array() += radius;
    if (eye_B) q.eye_O = q.R_OB * *eye_B + q.t_OB;
    Eigen::AlignedBox3d box_B;
    const Eigen::AlignedBox3d box_O = q.box_O.cast<double>();
    for (int c = 0; c < 8; ++c) box_B.extend(p.X_BO * box_O.corner(static_cast<Eigen::AlignedBox3d::CornerType>(c)));
    box_B.min().array() -= kSlack;
    box_B.max().array() += kSlack;
    q.box_B = box_B.cast<float>();
    placed.push_back(q);
  }
  if (placed.empty()) return;
  // (part, point) pairs each thread found, when the owners are wanted.
  tbb::combinable<std::vector<std::pair<uint32_t, uint32_t>>> found;
  tbb::parallel_for(tbb::blocked_range<size_t>(0, points.size(), 4096), [&](const tbb::blocked_range<size_t>& r) {
    std::vector<std::pair<uint32_t, uint32_t>>* pairs = owned != nullptr ? &found.local() : nullptr;
    for (size_t i = r.begin(); i < r.end(); ++i) {
      if (explained[i] || !points[i].allFinite()) continue;
      bool any = false;
      for (const Placed& p : placed) {
        if (!p.box_B.contains(points[i])) continue;
        const Eigen::Vector3f q = p.R_OB * points[i] + p.t_OB;
        if (!p.box_O.contains(q)) continue;
        if (p.surface->Explains(q, radius, eye_B ? &p.eye_O : nullptr, min_cos)) {
          any = true;
          if (pairs == nullptr) break;
          pairs->emplace_back(p.part, static_cast<uint32_t>(i));
        }
      }
      if (any) explained[i] = 1;
    }
  });
  if (owned == nullptr) return;
  found.combine_each([&](const std::vector<std::pair<uint32_t, uint32_t>>& pairs) {
    for (const auto& [part, i] : pairs) (*owned)[part].push_back(i);
  });
  for (std::vector<uint32_t>& list : *owned) std::sort(list.begin(), list.end());
}

}  // namespace bp::internal
