#include "collision/point_obstacle.h"

#include <fcl/geometry/octree/octree.h>
#include <fcl/narrowphase/collision.h>
#include <octomap/OcTree.h>

#include <cmath>
#include <utility>

#include "collision/internal/fcl_access.h"

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
  // Distinct voxels first: many points share a voxel, and updateNode walks
  // the tree from the root each time.
  octomap::KeySet keys;
  for (const Eigen::Vector3f& p : points_W) {
    if (!p.allFinite()) continue;
    octomap::OcTreeKey key;
    if (octree->coordToKeyChecked(octomap::point3d(p.x(), p.y(), p.z()), key)) keys.insert(key);
    ++n;
  }
  for (const octomap::OcTreeKey& key : keys) octree->updateNode(key, true, /*lazy_eval=*/true);
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
