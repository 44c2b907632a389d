// Rigid triangle-mesh collision queries (FCL behind a pimpl).
//
// A CollisionGeometry is built once from a TriangleMesh (an OBBRSS bounding
// volume hierarchy) and is immutable afterwards; share it between poses,
// scenes and threads through std::shared_ptr<const CollisionGeometry>.
//
// Thread-safety: CollisionGeometry is immutable. The free functions and every
// const member of CollisionScene may be called concurrently from any number of
// threads as long as nobody mutates the scene (Add / Remove / SetPose) at the
// same time. CollisionScene::Add refreshes FCL's cached bounds inside the
// shared geometry (same values every time): do not Add one geometry to two
// scenes from two threads at once.
#pragma once

#include <Eigen/Geometry>
#include <cstdint>
#include <map>
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "core/mesh.h"
#include "core/pose.h"
#include "core/status.h"

namespace bp {

class CollisionGeometry {
 public:
  // @returns InvalidArgument for an empty mesh or out-of-range indices.
  static Result<std::shared_ptr<const CollisionGeometry>> FromMesh(const TriangleMesh& mesh);

  ~CollisionGeometry();
  CollisionGeometry(const CollisionGeometry&) = delete;
  CollisionGeometry& operator=(const CollisionGeometry&) = delete;

  // Axis-aligned bounds of the vertices in the geometry's own frame.
  const Eigen::AlignedBox3d& local_bounds() const { return bounds_; }
  // Axis-aligned bounds of the geometry placed at X_WG (exact: from the vertices).
  Eigen::AlignedBox3d WorldBounds(const Pose& X_WG) const;
  // Cheap superset of WorldBounds: the bounds of the 8 transformed corners of local_bounds().
  Eigen::AlignedBox3d ConservativeWorldBounds(const Pose& X_WG) const;
  size_t num_triangles() const;

  class Impl;
  const Impl& impl() const { return *impl_; }

 private:
  explicit CollisionGeometry(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
  Eigen::AlignedBox3d bounds_;
};

using CollisionGeometryPtr = std::shared_ptr<const CollisionGeometry>;

// True when geometry a at X_WA and b at X_WB intersect (touching counts).
bool Collides(const CollisionGeometry& a, const Pose& X_WA, const CollisionGeometry& b,
              const Pose& X_WB);

// Minimum distance between the two placed geometries, metres; 0 or a
// negative value (not a penetration depth) when they intersect.
double Distance(const CollisionGeometry& a, const Pose& X_WA, const CollisionGeometry& b,
                const Pose& X_WB);

// The point of a placed geometry's surface (its triangles) nearest to a query
// point, and the surface's orientation there.
struct SurfacePoint {
  double distance = 0.0;                        // metres from the query point; 0 on the surface
  Eigen::Vector3d point_W = Eigen::Vector3d::Zero();   // the nearest surface point
  // Unit outward normal of the triangle that point lies on (counter-clockwise
  // winding seen from outside, as every binpick mesh is built).
  Eigen::Vector3d normal_W = Eigen::Vector3d::UnitZ();
};

// The surface of `g` placed at X_WG nearest to p_W (an FCL distance query
// between g's BVH and a point). A point inside a closed mesh is measured to
// the surface too: the distance is never negative.
SurfacePoint NearestSurfacePoint(const CollisionGeometry& g, const Pose& X_WG, const Eigen::Vector3d& p_W);

// Several placed objects with a broadphase (dynamic AABB tree). Objects are
// named by caller-chosen integer ids.
class CollisionScene {
 public:
  CollisionScene();
  ~CollisionScene();
  CollisionScene(CollisionScene&&) noexcept;
  CollisionScene& operator=(CollisionScene&&) noexcept;

  // @returns InvalidArgument if the id is taken or geometry is null.
  Status Add(int id, CollisionGeometryPtr geometry, const Pose& X_WO);
  // @returns NotFound for an unknown id.
  Status Remove(int id);
  Status SetPose(int id, const Pose& X_WO);

  bool Contains(int id) const;
  size_t size() const;
  // REQUIRES: Contains(id).
  const Pose& pose(int id) const;
  const CollisionGeometryPtr& geometry(int id) const;
  // Ids in increasing order.
  std::vector<int> ids() const;

  // True if `geometry` placed at X_WO intersects any object of the scene
  // other than those in `ignore`.
  bool Collides(const CollisionGeometry& geometry, const Pose& X_WO,
                std::span<const int> ignore = {}) const;
  // Ids (sorted) of the scene objects that `geometry` at X_WO intersects.
  std::vector<int> CollidingIds(const CollisionGeometry& geometry, const Pose& X_WO,
                                std::span<const int> ignore = {}) const;
  // Object `id` against the rest of the scene at its current pose.
  bool ObjectCollides(int id, std::span<const int> ignore = {}) const;

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace bp
