#include "collision/point_obstacle.h"

#include <gtest/gtest.h>

#include <random>

#include "tests/test_meshes.h"

namespace bp {
namespace {

TEST(PointObstacle, ABoxCollidesWithPointsInsideItAndNotAwayFromThem) {
  std::mt19937 rng{42};
  std::uniform_real_distribution<float> u(-0.05f, 0.05f);
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i < 2000; ++i) points.emplace_back(u(rng), u(rng), 0.0f);  // a 10 cm square at z = 0
  auto obstacle = PointObstacle::FromPoints(points, 0.004);
  ASSERT_TRUE(obstacle.ok());
  EXPECT_EQ((*obstacle)->num_points(), 2000u);
  EXPECT_GT((*obstacle)->num_occupied_voxels(), 100u);
  auto box = CollisionGeometry::FromMesh(testing::BoxMesh({0.02f, 0.02f, 0.02f}));
  ASSERT_TRUE(box.ok());
  EXPECT_TRUE((*obstacle)->Collides(**box, MakePose(Mat3::Identity(), Vec3(0, 0, 0))));
  EXPECT_FALSE((*obstacle)->Collides(**box, MakePose(Mat3::Identity(), Vec3(0, 0, 0.05))));
  EXPECT_FALSE((*obstacle)->Collides(**box, MakePose(Mat3::Identity(), Vec3(0.2, 0, 0))));
}

TEST(PointObstacle, WithoutPointsNothingCollidesAndResolutionMustBePositive) {
  auto empty = PointObstacle::FromPoints({}, 0.004);
  ASSERT_TRUE(empty.ok());
  auto box = CollisionGeometry::FromMesh(testing::BoxMesh({1.f, 1.f, 1.f}));
  ASSERT_TRUE(box.ok());
  EXPECT_FALSE((*empty)->Collides(**box, Pose::Identity()));
  std::vector<Eigen::Vector3f> nan_only{Eigen::Vector3f::Constant(NAN)};
  auto skipped = PointObstacle::FromPoints(nan_only, 0.004);
  ASSERT_TRUE(skipped.ok());
  EXPECT_EQ((*skipped)->num_points(), 0u);
  EXPECT_EQ(PointObstacle::FromPoints({}, 0.0).status().code(), Status::Code::kInvalidArgument);
}

}  // namespace
}  // namespace bp
