// Private to bp_collision: the FCL side of CollisionGeometry, shared by the
// .cc files that query FCL directly.
#pragma once

#include <fcl/geometry/bvh/BVH_model.h>
#include <fcl/math/bv/OBBRSS.h>

#include <memory>
#include <vector>

#include "collision/mesh_collider.h"

namespace bp {

// OBBRSS, not AABB: FCL copies and re-transforms AABB models on every query,
// which is about 100x slower.
using FclMesh = fcl::BVHModel<fcl::OBBRSSd>;

class CollisionGeometry::Impl {
 public:
  std::shared_ptr<FclMesh> model;
  std::vector<Eigen::Vector3d> vertices;
};

namespace internal {

inline const std::shared_ptr<FclMesh>& FclModel(const CollisionGeometry& g) { return g.impl().model; }

inline fcl::Transform3d ToFcl(const Pose& X) {
  fcl::Transform3d t = fcl::Transform3d::Identity();
  t.linear() = X.linear();
  t.translation() = X.translation();
  return t;
}

}  // namespace internal
}  // namespace bp
