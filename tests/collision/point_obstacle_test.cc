#include "collision/point_obstacle.h"

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <random>
#include <set>

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

// Every voxel holding a point is occupied and no other, whatever the order
// and repetition of the points (FromPoints sorts and deduplicates the
// voxels before building the tree): against the voxels counted by hand, on
// both sides of every axis's origin.
TEST(PointObstacle, OccupiesExactlyTheVoxelsOfItsPoints) {
  constexpr double kRes = 0.004;
  std::mt19937 rng{7};
  std::uniform_real_distribution<float> u(-0.15f, 0.15f);
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i < 3000; ++i) points.emplace_back(u(rng), u(rng), u(rng));
  for (int i = 0; i < 1000; ++i) points.push_back(points[static_cast<size_t>(i) * 3]);  // repeats
  std::set<std::array<int64_t, 3>> voxels;
  const auto voxel = [](const Eigen::Vector3f& p) {
    return std::array<int64_t, 3>{static_cast<int64_t>(std::floor(p.x() / kRes)),
                                  static_cast<int64_t>(std::floor(p.y() / kRes)),
                                  static_cast<int64_t>(std::floor(p.z() / kRes))};
  };
  for (const Eigen::Vector3f& p : points) voxels.insert(voxel(p));
  auto obstacle = PointObstacle::FromPoints(points, kRes);
  ASSERT_TRUE(obstacle.ok());
  EXPECT_EQ((*obstacle)->num_points(), points.size());
  EXPECT_EQ((*obstacle)->num_occupied_voxels(), voxels.size());
  // A 1 mm cube at a voxel's centre meets that voxel alone.
  auto cube = CollisionGeometry::FromMesh(testing::BoxMesh({0.001f, 0.001f, 0.001f}));
  ASSERT_TRUE(cube.ok());
  const auto centre = [](const std::array<int64_t, 3>& v) {
    return Vec3((v[0] + 0.5) * kRes, (v[1] + 0.5) * kRes, (v[2] + 0.5) * kRes);
  };
  int checked = 0;
  for (size_t i = 0; i < points.size(); i += 37) {
    std::array<int64_t, 3> v = voxel(points[i]);
    EXPECT_TRUE((*obstacle)->Collides(**cube, MakePose(Mat3::Identity(), centre(v)))) << i;
    v[2] += 1;  // the voxel above, occupied only when one of the points is there
    EXPECT_EQ((*obstacle)->Collides(**cube, MakePose(Mat3::Identity(), centre(v))), voxels.count(v) > 0) << i;
    ++checked;
  }
  EXPECT_GT(checked, 100);
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
