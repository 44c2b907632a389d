// The points' OcTree built in one pass over sorted keys
// (collision/internal/octree_build.h) is the tree octomap's updateNode
// builds from the same voxels in any order: the same nodes, log-odds and
// size, node by node (OcTreeBaseImpl::operator==).
#include "collision/internal/octree_build.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <random>
#include <vector>

namespace bp {
namespace {

// The distinct keys of `points` in `tree`'s grid, sorted by TreeOrder.
std::vector<octomap::OcTreeKey> SortedKeys(const octomap::OcTree& tree, const std::vector<octomap::point3d>& points) {
  std::vector<octomap::OcTreeKey> keys;
  for (const octomap::point3d& p : points) {
    octomap::OcTreeKey key;
    if (tree.coordToKeyChecked(p, key)) keys.push_back(key);
  }
  std::sort(keys.begin(), keys.end(), [](const auto& a, const auto& b) {
    return internal::TreeOrder(a) < internal::TreeOrder(b);
  });
  keys.erase(std::unique(keys.begin(), keys.end()), keys.end());
  return keys;
}

TEST(OctreeBuild, SortedKeysInOnePassBuildTheTreeUpdateNodeBuildsInAnyOrder) {
  std::mt19937 rng(44);
  for (double res : {0.004, 0.0005}) {
    SCOPED_TRACE("resolution " + std::to_string(res));
    // A cloud round the origin (keys on both sides of octomap's centre
    // key), a dense patch and a few far points.
    std::uniform_real_distribution<float> near(-0.05f, 0.05f), far(-3.f, 3.f);
    std::vector<octomap::point3d> points;
    for (int i = 0; i < 4000; ++i) points.emplace_back(near(rng), near(rng), near(rng));
    for (float x = 0.f; x < 0.02f; x += 0.0003f) {
      for (float y = 0.f; y < 0.02f; y += 0.0003f) points.emplace_back(x, y, 0.01f + 0.1f * x);
    }
    for (int i = 0; i < 50; ++i) points.emplace_back(far(rng), far(rng), far(rng));
    octomap::OcTree reference(res), built(res);
    std::vector<octomap::point3d> shuffled = points;
    std::shuffle(shuffled.begin(), shuffled.end(), rng);
    octomap::KeySet seen;
    for (const octomap::point3d& p : shuffled) {
      octomap::OcTreeKey key;
      ASSERT_TRUE(reference.coordToKeyChecked(p, key));
      // One hit per voxel, as PointObstacle::FromPoints inserts them.
      if (!seen.insert(key).second) continue;
      reference.updateNode(key, true, /*lazy_eval=*/true);
    }
    reference.updateInnerOccupancy();
    const std::vector<octomap::OcTreeKey> keys = SortedKeys(built, points);
    ASSERT_EQ(keys.size(), seen.size());
    internal::InsertSortedKeys(built, keys);
    built.updateInnerOccupancy();
    EXPECT_GT(reference.getNumLeafNodes(), 3000u);
    EXPECT_EQ(built.getNumLeafNodes(), reference.getNumLeafNodes());
    EXPECT_EQ(built.size(), reference.size());
    EXPECT_TRUE(built == reference);
    // The comparison is not blind: one voxel more differs.
    octomap::OcTree extra(res);
    std::vector<octomap::OcTreeKey> more = keys;
    more.push_back(extra.coordToKey(octomap::point3d(5.f, 5.f, 5.f)));
    internal::InsertSortedKeys(extra, more);
    extra.updateInnerOccupancy();
    EXPECT_FALSE(extra == reference);
  }
}

TEST(OctreeBuild, NoKeysLeaveTheTreeEmpty) {
  octomap::OcTree tree(0.004);
  internal::InsertSortedKeys(tree, {});
  EXPECT_EQ(tree.size(), 0u);
  EXPECT_EQ(tree.getRoot(), nullptr);
}

}  // namespace
}  // namespace bp
