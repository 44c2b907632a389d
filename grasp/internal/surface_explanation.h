// Scene points explained by a detected part's model surface
// (GraspPlanningOptions::surface_explain_distance): a measured point within
// a noise-derived distance of the surface of a detection's model at its
// estimated pose, on a side that faces the camera, is that part's own point
// and no obstacle, whether or not the view perception matched it in
// supported it. Private to bp_grasp. Frames: O part, B base. Metres.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include <Eigen/Core>

#include "core/mesh.h"
#include "core/pose.h"
#include "pipeline/internal/point_hash.h"

namespace bp::internal {

// A part's surface as dense samples (in O) with their outward normals,
// hashed for fixed-radius queries. Immutable after Sample (thread-safe reads).
class PartSurface {
 public:
  // About area / spacing^2 samples (seeded: the same every build). The
  // largest radius a query may ask is `max_radius` (the hash's cell).
  static PartSurface Sample(const TriangleMesh& mesh, double spacing, double max_radius);

  // True when a sample within `radius` of q_O lies on a side of the part
  // that faces eye_O (its outward normal at least min_cos toward the eye);
  // any sample within `radius` when eye_O is null.
  // REQUIRES: radius <= the max_radius it was sampled for.
  bool Explains(const Eigen::Vector3f& q_O, float radius, const Eigen::Vector3f* eye_O, float min_cos) const;

  // A box holding every sample, in O.
  const Eigen::AlignedBox3f& bounds() const { return bounds_; }
  size_t size() const { return normals_.size(); }

 private:
  PointHash hash_;
  std::vector<Eigen::Vector3f> points_, normals_;
  Eigen::AlignedBox3f bounds_;
};

// A detection's part surface at its estimated pose.
struct PlacedSurface {
  const PartSurface* surface = nullptr;
  Pose X_BO = Pose::Identity();
};

// Marks explained[i] for every point of `points` (B) not marked yet that
// lies within `radius` of one of `parts`, on a side facing `eye_B` (the
// camera's centre; nullopt: any side) by at least min_cos. Points are
// looked at in parallel (the caller's arena); each writes its own flag.
// When `owned` is not null it is resized to parts.size() and (*owned)[k]
// lists, ascending, the points part k explains (a point two parts explain,
// where they touch, is listed under both).
// REQUIRES: explained.size() == points.size().
void ExplainBySurfaces(std::span<const Eigen::Vector3f> points, std::span<const PlacedSurface> parts, float radius,
                       const std::optional<Eigen::Vector3f>& eye_B, float min_cos, std::vector<uint8_t>& explained,
                       std::vector<std::vector<uint32_t>>* owned = nullptr);

}  // namespace bp::internal
