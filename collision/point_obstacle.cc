#include "collision/point_obstacle.h"

#include <fcl/geometry/octree/octree.h>
#include <fcl/narrowphase/collision.h>
#include <octomap/OcTree.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <vector>
#include <utility>

#include "collision/internal/fcl_access.h"
#include "collision/internal/octree_build.h"

namespace bp {

class PointObstacle::Impl {
 public:
  std::shared_ptr<fcl::OcTreed> tree;  // null when there are no points
  size_t occupied = 0;
};

PointObstacle::PointObstacle(std::unique_ptr<Impl> impl, size_t num_points, double resolution)
    : impl_(std::move(impl)), num_points_(num_points), resolution_(resolution) {}
PointObstacle::~PointObstacle() = default;

size_t PointObstacle::num_occupied_voxels() const { return impl_->occupied; }

Result<std::shared_ptr<const PointObstacle>> PointObstacle::FromPoints(
    std::span<const Eigen::Vector3f> points_W, double resolution) {
  if (!(resolution > 0)) return Status::InvalidArgument("point obstacle: resolution must be > 0");
  auto impl = std::make_unique<Impl>();
  size_t n = 0;
  auto octree = std::make_shared<octomap::OcTree>(resolution);
  // Distinct voxels first: many points share a voxel. Sorted in the tree's
  // own order (the keys' bits interleaved, the root's child first) and
  // inserted in one pass down the shared paths (internal::InsertSortedKeys:
  // the tree updateNode builds, which is the same in any order: one hit per
  // voxel, inner nodes updated once after).
  std::vector<std::pair<uint64_t, octomap::OcTreeKey>> keys;
  keys.reserve(points_W.size());
  for (const Eigen::Vector3f& p : points_W) {
    if (!p.allFinite()) continue;
    octomap::OcTreeKey key;
    if (octree->coordToKeyChecked(octomap::point3d(p.x(), p.y(), p.z()), key)) keys.emplace_back(internal::TreeOrder(key), key);
    ++n;
  }
  std::sort(keys.begin(), keys.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  keys.erase(std::unique(keys.begin(), keys.end(), [](const auto& a, const auto& b) { return a.second == b.second; }),
             keys.end());
  std::vector<octomap::OcTreeKey> sorted;
  sorted.reserve(keys.size());
  for (const auto& [order, key] : keys) sorted.push_back(key);
  internal::InsertSortedKeys(*octree, sorted);
  if (n > 0) {
    octree->updateInnerOccupancy();
    impl->occupied = octree->getNumLeafNodes();
    impl->tree = std::make_shared<fcl::OcTreed>(octree);
    impl->tree->computeLocalAABB();
  }
  return std::shared_ptr<const PointObstacle>(new PointObstacle(std::move(impl), n, resolution));
}

bool PointObstacle::Collides(const CollisionGeometry& geometry, const Pose& X_WG) const {
  if (!impl_->tree) return false;
  fcl::CollisionRequestd request;
  fcl::CollisionResultd result;
  fcl::collide(impl_->tree.get(), fcl::Transform3d::Identity(), internal::FclModel(geometry).get(),
               internal::ToFcl(X_WG), request, result);
  return result.isCollision();
}

}  // namespace bp
