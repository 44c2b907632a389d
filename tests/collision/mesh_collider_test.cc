#include "collision/mesh_collider.h"

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <thread>

#include "tests/test_meshes.h"

namespace bp {
namespace {

CollisionGeometryPtr Box(float sx, float sy, float sz) {
  auto g = CollisionGeometry::FromMesh(testing::BoxMesh({sx, sy, sz}));
  EXPECT_TRUE(g.ok());
  return *g;
}

Pose At(double x, double y, double z) { return MakePose(Mat3::Identity(), Vec3(x, y, z)); }

TEST(MeshCollider, RejectsEmptyMesh) {
  EXPECT_FALSE(CollisionGeometry::FromMesh(TriangleMesh{}).ok());
}

TEST(MeshCollider, OverlappingBoxesCollideSeparatedBoxesDoNot) {
  auto a = Box(0.1f, 0.1f, 0.1f);
  EXPECT_TRUE(Collides(*a, At(0, 0, 0), *a, At(0.09, 0, 0)));
  EXPECT_FALSE(Collides(*a, At(0, 0, 0), *a, At(0.11, 0, 0)));
  EXPECT_NEAR(Distance(*a, At(0, 0, 0), *a, At(0.13, 0, 0)), 0.03, 1e-6);
}

TEST(MeshCollider, RotationIsTakenIntoAccount) {
  auto a = Box(0.2f, 0.02f, 0.02f);
  // A long thin bar at x = 0.15 misses a unit box unless turned towards it.
  auto b = Box(0.1f, 0.1f, 0.1f);
  const Pose X_WBar = At(0, 0.15, 0);
  EXPECT_FALSE(Collides(*a, X_WBar, *b, At(0, 0, 0)));
  Pose turned = X_WBar;
  turned.linear() = Eigen::AngleAxisd(M_PI / 2, Vec3::UnitZ()).toRotationMatrix();
  EXPECT_TRUE(Collides(*a, turned, *b, At(0, 0, 0)));
}

TEST(MeshCollider, WorldBoundsFollowThePose) {
  auto a = Box(0.2f, 0.1f, 0.05f);
  Pose X = At(1, 2, 3);
  X.linear() = Eigen::AngleAxisd(M_PI / 2, Vec3::UnitZ()).toRotationMatrix();
  const auto box = a->WorldBounds(X);
  EXPECT_NEAR(box.sizes().x(), 0.1, 1e-6);
  EXPECT_NEAR(box.sizes().y(), 0.2, 1e-6);
  EXPECT_NEAR(box.center().z(), 3.0, 1e-6);
  X.linear() = Eigen::AngleAxisd(0.3, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  const auto exact = a->WorldBounds(X), loose = a->ConservativeWorldBounds(X);
  EXPECT_TRUE(loose.contains(exact));
}

TEST(MeshCollider, NearestSurfacePointFindsTheFaceItsNormalAndTheDistanceFromOutsideOnAndInside) {
  // Vertices are floats: positions hold to about 1e-9 m.
  auto near = [](const Vec3& a, const Vec3& b) { return (a - b).norm() < 1e-8; };
  auto box = Box(0.1f, 0.1f, 0.1f);
  // Turned 90 deg about x and moved: the box's -y face looks up (+z).
  Pose X_WG = At(0.2, 0.1, 0.3);
  X_WG.linear() = Eigen::AngleAxisd(M_PI / 2, Vec3::UnitX()).toRotationMatrix();
  const SurfacePoint above = NearestSurfacePoint(*box, X_WG, Vec3(0.21, 0.12, 0.37));
  EXPECT_NEAR(above.distance, 0.02, 1e-8);
  EXPECT_TRUE(near(above.point_W, Vec3(0.21, 0.12, 0.35))) << above.point_W.transpose();
  EXPECT_TRUE(above.normal_W.isApprox(Vec3::UnitZ(), 1e-9)) << above.normal_W.transpose();
  // Beside the box's edge: the nearest point is on the edge.
  const SurfacePoint beside = NearestSurfacePoint(*box, X_WG, Vec3(0.28, 0.1, 0.38));
  EXPECT_NEAR(beside.distance, std::hypot(0.03, 0.03), 1e-8);
  EXPECT_TRUE(near(beside.point_W, Vec3(0.25, 0.1, 0.35))) << beside.point_W.transpose();
  // On the face, and 10 mm inside the box under it: the face is the surface.
  const SurfacePoint on = NearestSurfacePoint(*box, X_WG, Vec3(0.19, 0.08, 0.35));
  EXPECT_NEAR(on.distance, 0.0, 1e-8);
  EXPECT_TRUE(on.normal_W.isApprox(Vec3::UnitZ(), 1e-9)) << on.normal_W.transpose();
  const SurfacePoint inside = NearestSurfacePoint(*box, X_WG, Vec3(0.19, 0.08, 0.34));
  EXPECT_NEAR(inside.distance, 0.01, 1e-8);
  EXPECT_TRUE(near(inside.point_W, Vec3(0.19, 0.08, 0.35))) << inside.point_W.transpose();
  EXPECT_TRUE(inside.normal_W.isApprox(Vec3::UnitZ(), 1e-9)) << inside.normal_W.transpose();
}

TEST(CollisionScene, MeshAgainstSceneReportsTheObjectsItHits) {
  CollisionScene scene;
  auto box = Box(0.1f, 0.1f, 0.1f);
  ASSERT_TRUE(scene.Add(1, box, At(0, 0, 0)).ok());
  ASSERT_TRUE(scene.Add(2, box, At(0.3, 0, 0)).ok());
  ASSERT_TRUE(scene.Add(3, box, At(0.6, 0, 0)).ok());
  EXPECT_FALSE(scene.Add(2, box, At(0, 0, 0)).ok());

  auto probe = Box(0.25f, 0.05f, 0.05f);
  EXPECT_EQ(scene.CollidingIds(*probe, At(0.15, 0, 0)), (std::vector<int>{1, 2}));
  EXPECT_TRUE(scene.Collides(*probe, At(0.15, 0, 0)));
  EXPECT_FALSE(scene.Collides(*probe, At(0.15, 0.2, 0)));
  const int ignore[] = {1, 2};
  EXPECT_FALSE(scene.Collides(*probe, At(0.15, 0, 0), ignore));
}

TEST(CollisionScene, MovedNeighbourIsAccepted) {
  CollisionScene scene;
  auto box = Box(0.1f, 0.1f, 0.1f);
  ASSERT_TRUE(scene.Add(1, box, At(0, 0, 0)).ok());
  ASSERT_TRUE(scene.Add(2, box, At(0.05, 0, 0)).ok());
  EXPECT_TRUE(scene.ObjectCollides(1));
  ASSERT_TRUE(scene.SetPose(2, At(0.5, 0, 0)).ok());
  EXPECT_FALSE(scene.ObjectCollides(1));
  EXPECT_FALSE(scene.Collides(*box, At(0.0, 0.12, 0)));
  EXPECT_TRUE(scene.Collides(*box, At(0.45, 0.0, 0)));
  ASSERT_TRUE(scene.Remove(2).ok());
  EXPECT_FALSE(scene.Collides(*box, At(0.45, 0.0, 0)));
  EXPECT_FALSE(scene.Remove(2).ok());
  EXPECT_EQ(scene.ids(), std::vector<int>{1});
}

TEST(CollisionScene, ConstQueriesAreSafeFromSeveralThreads) {
  CollisionScene scene;
  auto box = Box(0.1f, 0.1f, 0.1f);
  for (int i = 0; i < 10; ++i) ASSERT_TRUE(scene.Add(i, box, At(0.2 * i, 0, 0)).ok());
  std::vector<std::thread> threads;
  std::atomic<int> wrong{0};
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&] {
      for (int k = 0; k < 200; ++k) {
        const double x = 0.2 * (k % 10);
        if (!scene.Collides(*box, At(x + 0.05, 0, 0))) ++wrong;
        if (scene.Collides(*box, At(x + 0.1, 0.3, 0))) ++wrong;
      }
    });
  }
  for (auto& t : threads) t.join();
  EXPECT_EQ(wrong.load(), 0);
}

}  // namespace
}  // namespace bp
