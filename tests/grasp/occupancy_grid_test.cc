// The point check's pre-filter (grasp/internal/occupancy_grid.h): a box in
// its own frame, placed anywhere, is "near" the grid's points whenever the
// FCL OcTree of their voxels (collision/point_obstacle.h) meets a mesh
// inside that box; and AnyNear's answer is the per-point box test.
#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "collision/mesh_collider.h"
#include "collision/point_obstacle.h"
#include "core/mesh_gen.h"
#include "grasp/internal/occupancy_grid.h"

namespace bp {
namespace {

// The centre of the voxel (edge `res`) holding each point, as octomap keys
// it (floor(c / res)): the planner's voxelised obstacle.
std::vector<Eigen::Vector3f> VoxelCentresOf(const std::vector<Eigen::Vector3f>& points, double res) {
  std::vector<Eigen::Vector3f> out;
  for (const Eigen::Vector3f& p : points) {
    Eigen::Vector3f c;
    for (int k = 0; k < 3; ++k) {
      c[k] = static_cast<float>((std::floor(static_cast<double>(p[k]) / res) + 0.5) * res);
    }
    out.push_back(c);
  }
  return out;
}

Eigen::AlignedBox3d BoundsOf(const TriangleMesh& mesh) {
  Eigen::AlignedBox3d box;
  for (const auto& v : mesh.vertices) box.extend(v.cast<double>());
  return box;
}

// Places the shipped cup's shape (shortened, so that it is among the points
// rather than above them) and a thin plate (whose box is tight) at `poses`
// random poses each, turned any way and offset up to `reach` (m) from the
// origin, and expects grid.AnyNear(mesh bounds, pose, grow) wherever the
// obstacle meets the mesh. Each answer must occur at least `min_each` times,
// so that the poses test the pre-filter, not one side of it.
void ExpectAnyNearWhereverTheObstacleIsHit(const PointObstacle& obstacle, const internal::OccupancyGrid& grid,
                                           double grow, int poses, double reach, int min_each, std::mt19937& rng) {
  SuctionGripperParams cup;
  cup.flange_offset = 0.08;
  const std::vector<TriangleMesh> meshes = {MakeSuctionGripper(cup), MakeLBracket()};
  int collides = 0, far = 0;
  for (const TriangleMesh& mesh : meshes) {
    auto geometry = CollisionGeometry::FromMesh(mesh);
    ASSERT_TRUE(geometry.ok());
    const Eigen::AlignedBox3d box = BoundsOf(mesh);
    std::uniform_real_distribution<double> angle(-M_PI, M_PI), offset(-reach, reach);
    for (int i = 0; i < poses; ++i) {
      const Vec3 axis = Vec3(angle(rng), angle(rng), angle(rng)).normalized();
      const Pose X = MakePose(Mat3(Eigen::AngleAxisd(angle(rng), axis)), Vec3(offset(rng), offset(rng), offset(rng)));
      const bool hit = obstacle.Collides(**geometry, X);
      const bool near = grid.AnyNear(box, X, grow);
      if (hit) {
        ++collides;
        EXPECT_TRUE(near) << "pose " << i;
      }
      if (!near) ++far;
    }
  }
  EXPECT_GT(collides, min_each);
  EXPECT_GT(far, min_each);
}

TEST(OccupancyGrid, AnyNearIsTrueForEveryPoseWhoseMeshMeetsAVoxel) {
  constexpr double kRes = 0.004;
  std::mt19937 rng(40);
  std::uniform_real_distribution<float> in_cube(-0.05f, 0.05f);
  // A sparse cloud (about a tenth of the cube's voxels) and a plate of
  // voxels under it, as the occluded columns leave on a bin floor.
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i < 1500; ++i) points.emplace_back(in_cube(rng), in_cube(rng), in_cube(rng));
  for (float x = -0.05f; x <= 0.05f; x += 0.003f) {
    for (float y = -0.05f; y <= 0.05f; y += 0.003f) points.emplace_back(x, y, -0.06f);
  }
  const std::vector<Eigen::Vector3f> centres = VoxelCentresOf(points, kRes);
  auto obstacle = PointObstacle::FromPoints(centres, kRes);
  ASSERT_TRUE(obstacle.ok());
  const internal::OccupancyGrid grid(centres, 0.01);
  ExpectAnyNearWhereverTheObstacleIsHit(**obstacle, grid, kRes, 1500, 0.07, 300, rng);
}

// A detection's own points (grasp_planning.cc, HitsItsOwnPoints): the raw
// points, not their voxels' centres, in 0.5 mm voxels and 5 mm cells; a
// voxel lies within sqrt(3) edges of its point, so two edges of grow.
TEST(OccupancyGrid, AnyNearWithTwoEdgesIsTrueForEveryPoseWhoseMeshMeetsARawPointsVoxel) {
  constexpr double kRes = 0.0005;
  std::mt19937 rng(41);
  std::uniform_real_distribution<float> in_cube(-0.03f, 0.03f);
  // A sparse cloud and a dense patch, as a part's points beside its fit.
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i < 3000; ++i) points.emplace_back(in_cube(rng), in_cube(rng), in_cube(rng));
  for (float x = -0.02f; x <= 0.02f; x += 0.0007f) {
    for (float y = -0.02f; y <= 0.02f; y += 0.0007f) points.emplace_back(x, y, -0.035f + 0.2f * x);
  }
  auto obstacle = PointObstacle::FromPoints(points, kRes);
  ASSERT_TRUE(obstacle.ok());
  const internal::OccupancyGrid grid(points, 0.005);
  ExpectAnyNearWhereverTheObstacleIsHit(**obstacle, grid, 2 * kRes, 1000, 0.06, 200, rng);
}

TEST(OccupancyGrid, AnyNearTestsEachPointAgainstTheBoxGrownAlongItsOwnAxes) {
  // One point; a box 2 x 1 x 1 cm turned 45 deg about z, centred on the origin.
  const std::vector<Eigen::Vector3f> point = {Eigen::Vector3f(0.0f, 0.0125f, 0.0f)};
  const internal::OccupancyGrid grid(point, 0.01);
  const Eigen::AlignedBox3d box_L(Vec3(-0.01, -0.005, -0.005), Vec3(0.01, 0.005, 0.005));
  const Pose turned = MakePose(Mat3(Eigen::AngleAxisd(M_PI / 4, Vec3::UnitZ())), Vec3::Zero());
  // In the box's frame the point is at (0.0088, 0.0088, 0): 3.8 mm beyond
  // its y face, inside its x extent. The world box of the grown box holds
  // it at any grow; the grown box itself only from 3.8 mm on.
  EXPECT_FALSE(grid.AnyNear(box_L, turned, 0.0035));
  EXPECT_TRUE(grid.AnyNear(box_L, turned, 0.0040));
  // Unturned it is 7.5 mm beyond the y face.
  EXPECT_FALSE(grid.AnyNear(box_L, Pose::Identity(), 0.007));
  EXPECT_TRUE(grid.AnyNear(box_L, Pose::Identity(), 0.0076));
  // An empty grid has nothing near.
  EXPECT_FALSE(internal::OccupancyGrid({}, 0.01).AnyNear(box_L, Pose::Identity(), 1.0));
}

}  // namespace
}  // namespace bp
