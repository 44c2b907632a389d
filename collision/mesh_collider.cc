#include "collision/mesh_collider.h"

#include <fcl/broadphase/broadphase_dynamic_AABB_tree.h>
#include <fcl/geometry/bvh/BVH_model.h>
#include <fcl/geometry/shape/box.h>
#include <fcl/geometry/shape/sphere.h>
#include <fcl/narrowphase/collision.h>
#include <fcl/narrowphase/collision_object.h>
#include <fcl/narrowphase/distance.h>

#include <algorithm>
#include <cstdint>
#include <string>
#include <utility>

#include "collision/internal/fcl_access.h"

namespace bp {

CollisionGeometry::CollisionGeometry(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {
  for (const auto& v : impl_->vertices) bounds_.extend(v);
}
CollisionGeometry::~CollisionGeometry() = default;

size_t CollisionGeometry::num_triangles() const {
  return static_cast<size_t>(impl_->model->num_tris);
}

Result<std::shared_ptr<const CollisionGeometry>> CollisionGeometry::FromMesh(
    const TriangleMesh& mesh) {
  if (mesh.triangles.empty() || mesh.vertices.empty()) {
    return Status::InvalidArgument("collision geometry: empty mesh");
  }
  auto impl = std::make_unique<Impl>();
  impl->vertices.reserve(mesh.vertices.size());
  for (const auto& v : mesh.vertices) {
    if (!v.allFinite()) return Status::InvalidArgument("collision geometry: non-finite vertex");
    impl->vertices.push_back(v.cast<double>());
  }
  std::vector<fcl::Triangle> tris;
  tris.reserve(mesh.triangles.size());
  const int n = static_cast<int>(mesh.vertices.size());
  for (const auto& t : mesh.triangles) {
    if (t.minCoeff() < 0 || t.maxCoeff() >= n) {
      return Status::InvalidArgument("collision geometry: triangle index out of range");
    }
    tris.emplace_back(t[0], t[1], t[2]);
  }
  impl->model = std::make_shared<FclMesh>();
  impl->model->beginModel(static_cast<int>(tris.size()), n);
  impl->model->addSubModel(impl->vertices, tris);
  impl->model->endModel();
  impl->model->computeLocalAABB();
  return std::shared_ptr<const CollisionGeometry>(new CollisionGeometry(std::move(impl)));
}

Eigen::AlignedBox3d CollisionGeometry::WorldBounds(const Pose& X_WG) const {
  Eigen::AlignedBox3d box;
  for (const auto& v : impl_->vertices) box.extend(X_WG * v);
  return box;
}

Eigen::AlignedBox3d CollisionGeometry::ConservativeWorldBounds(const Pose& X_WG) const {
  Eigen::AlignedBox3d box;
  for (int i = 0; i < 8; ++i) {
    box.extend(X_WG * bounds_.corner(static_cast<Eigen::AlignedBox3d::CornerType>(i)));
  }
  return box;
}

namespace {

using internal::ToFcl;

bool NarrowCollides(const FclMesh& a, const fcl::Transform3d& X_WA, const FclMesh& b,
                    const fcl::Transform3d& X_WB) {
  fcl::CollisionRequestd request;  // one contact is enough for a yes/no answer
  fcl::CollisionResultd result;
  fcl::collide(&a, X_WA, &b, X_WB, request, result);
  return result.isCollision();
}

}  // namespace

bool Collides(const CollisionGeometry& a, const Pose& X_WA, const CollisionGeometry& b,
              const Pose& X_WB) {
  return NarrowCollides(*a.impl().model, ToFcl(X_WA), *b.impl().model, ToFcl(X_WB));
}

double Distance(const CollisionGeometry& a, const Pose& X_WA, const CollisionGeometry& b,
                const Pose& X_WB) {
  fcl::DistanceRequestd request;
  fcl::DistanceResultd result;
  fcl::distance(a.impl().model.get(), ToFcl(X_WA), b.impl().model.get(), ToFcl(X_WB), request,
                result);
  return result.min_distance;
}

SurfacePoint NearestSurfacePoint(const CollisionGeometry& g, const Pose& X_WG, const Eigen::Vector3d& p_W) {
  const FclMesh& model = *g.impl().model;
  // A sphere of radius 0 is a point: FCL measures it to each triangle it
  // reaches through the BVH (sphere-triangle distance, exact).
  const fcl::Sphered point(0.0);
  fcl::Transform3d X_WP = fcl::Transform3d::Identity();
  X_WP.translation() = p_W;
  const fcl::Transform3d X_WG_fcl = ToFcl(X_WG);
  fcl::DistanceRequestd request;
  request.enable_nearest_points = true;
  fcl::DistanceResultd result;
  fcl::distance(&model, X_WG_fcl, &point, X_WP, request, result);
  SurfacePoint out;
  const int triangle = result.b1;
  if (triangle >= 0 && triangle < model.num_tris) {
    const fcl::Triangle& t = model.tri_indices[triangle];
    const Eigen::Vector3d& a = g.impl().vertices[t[0]];
    const Eigen::Vector3d n_G = (g.impl().vertices[t[1]] - a).cross(g.impl().vertices[t[2]] - a);
    if (n_G.norm() > 0) out.normal_W = X_WG.linear() * n_G.normalized();
  }
  // FCL reports a point lying on a triangle as "in contact" (distance < 0,
  // no nearest points): the query point is then the surface point.
  if (result.min_distance > 0) {
    out.distance = result.min_distance;
    out.point_W = X_WG * result.nearest_points[0];  // the triangle's point, in the mesh frame
  } else {
    out.point_W = p_W;
  }
  return out;
}

// --- CollisionScene ---------------------------------------------------------

class CollisionScene::Impl {
 public:
  struct Entry {
    CollisionGeometryPtr geometry;
    Pose X_WO;
    std::unique_ptr<fcl::CollisionObjectd> object;  // registered in `manager`
  };
  std::map<int, Entry> entries;
  fcl::DynamicAABBTreeCollisionManagerd manager;

  // Query state handed to the broadphase callback.
  struct Query {
    const Impl* scene;
    const FclMesh* model;
    fcl::Transform3d X_WO;
    std::span<const int> ignore;
    bool first_only;
    std::vector<int> hits;
  };

  static bool Callback(fcl::CollisionObjectd* o1, fcl::CollisionObjectd* o2, void* data) {
    auto* q = static_cast<Query*>(data);
    // One of the two is the query's bounding box, which has no user data.
    fcl::CollisionObjectd* other = o1->getUserData() != nullptr ? o1 : o2;
    const int id = static_cast<int>(reinterpret_cast<intptr_t>(other->getUserData())) - 1;
    if (std::find(q->ignore.begin(), q->ignore.end(), id) != q->ignore.end()) return false;
    const Entry& e = q->scene->entries.at(id);
    if (NarrowCollides(*q->model, q->X_WO, *e.geometry->impl().model, other->getTransform())) {
      q->hits.push_back(id);
      return q->first_only;  // true stops the broadphase
    }
    return false;
  }

  // Runs the broadphase with a box around the query's world bounds. The box is
  // a local object, so concurrent const queries never share mutable FCL state.
  std::vector<int> Run(const CollisionGeometry& g, const Pose& X_WO, std::span<const int> ignore,
                       bool first_only) const {
    if (entries.empty()) return {};
    const Eigen::AlignedBox3d box = g.ConservativeWorldBounds(X_WO);
    const Eigen::Vector3d size = box.sizes().cwiseMax(1e-9);
    auto shape = std::make_shared<fcl::Boxd>(size);
    fcl::Transform3d X_WBox = fcl::Transform3d::Identity();
    X_WBox.translation() = box.center();
    fcl::CollisionObjectd query_box(shape, X_WBox);
    Query q{this, g.impl().model.get(), ToFcl(X_WO), ignore, first_only, {}};
    manager.collide(&query_box, &q, &Impl::Callback);
    std::sort(q.hits.begin(), q.hits.end());
    return q.hits;
  }
};

CollisionScene::CollisionScene() : impl_(std::make_unique<Impl>()) {}
CollisionScene::~CollisionScene() = default;
CollisionScene::CollisionScene(CollisionScene&&) noexcept = default;
CollisionScene& CollisionScene::operator=(CollisionScene&&) noexcept = default;

Status CollisionScene::Add(int id, CollisionGeometryPtr geometry, const Pose& X_WO) {
  if (!geometry) return Status::InvalidArgument("collision scene: null geometry");
  if (impl_->entries.count(id)) {
    return Status::InvalidArgument("collision scene: id " + std::to_string(id) +
                                   " already present");
  }
  Impl::Entry e;
  e.X_WO = X_WO;
  e.object = std::make_unique<fcl::CollisionObjectd>(geometry->impl().model, ToFcl(X_WO));
  // Ids are stored off by one so that the query box (null user data) is told apart.
  e.object->setUserData(reinterpret_cast<void*>(static_cast<intptr_t>(id) + 1));
  e.geometry = std::move(geometry);
  impl_->manager.registerObject(e.object.get());
  impl_->manager.setup();
  impl_->entries.emplace(id, std::move(e));
  return Status::Ok();
}

Status CollisionScene::Remove(int id) {
  auto it = impl_->entries.find(id);
  if (it == impl_->entries.end())
    return Status::NotFound("collision scene: no object " + std::to_string(id));
  impl_->manager.unregisterObject(it->second.object.get());
  impl_->entries.erase(it);
  return Status::Ok();
}

Status CollisionScene::SetPose(int id, const Pose& X_WO) {
  auto it = impl_->entries.find(id);
  if (it == impl_->entries.end())
    return Status::NotFound("collision scene: no object " + std::to_string(id));
  it->second.X_WO = X_WO;
  it->second.object->setTransform(ToFcl(X_WO));
  it->second.object->computeAABB();
  impl_->manager.update(it->second.object.get());
  return Status::Ok();
}

bool CollisionScene::Contains(int id) const { return impl_->entries.count(id) > 0; }
size_t CollisionScene::size() const { return impl_->entries.size(); }
const Pose& CollisionScene::pose(int id) const { return impl_->entries.at(id).X_WO; }
const CollisionGeometryPtr& CollisionScene::geometry(int id) const {
  return impl_->entries.at(id).geometry;
}

std::vector<int> CollisionScene::ids() const {
  std::vector<int> out;
  out.reserve(impl_->entries.size());
  for (const auto& [id, e] : impl_->entries) out.push_back(id);
  return out;
}

bool CollisionScene::Collides(const CollisionGeometry& geometry, const Pose& X_WO,
                              std::span<const int> ignore) const {
  return !impl_->Run(geometry, X_WO, ignore, /*first_only=*/true).empty();
}

std::vector<int> CollisionScene::CollidingIds(const CollisionGeometry& geometry, const Pose& X_WO,
                                              std::span<const int> ignore) const {
  return impl_->Run(geometry, X_WO, ignore, /*first_only=*/false);
}

bool CollisionScene::ObjectCollides(int id, std::span<const int> ignore) const {
  const auto& e = impl_->entries.at(id);
  std::vector<int> ign(ignore.begin(), ignore.end());
  ign.push_back(id);
  return Collides(*e.geometry, e.X_WO, ign);
}

}  // namespace bp
