#include "collision/internal/octree_build.h"

#include <array>

namespace bp::internal {

uint64_t TreeOrder(const octomap::OcTreeKey& key) {
  const auto spread = [](uint64_t v) {  // bit i -> bit 3i, for the 16 bits of a key
    v &= 0xffff;
    v = (v | (v << 16)) & 0x0000ff0000ffull;
    v = (v | (v << 8)) & 0x00f00f00f00full;
    v = (v | (v << 4)) & 0x0c30c30c30c3ull;
    v = (v | (v << 2)) & 0x249249249249ull;
    return v;
  };
  return spread(key[0]) | (spread(key[1]) << 1) | (spread(key[2]) << 2);
}

void InsertSortedKeys(octomap::OcTree& tree, std::span<const octomap::OcTreeKey> keys) {
  if (keys.empty()) return;
  // The first key as updateNode inserts it: that creates the root.
  tree.updateNode(keys[0], true, /*lazy_eval=*/true);
  const int depth = static_cast<int>(tree.getTreeDepth());
  // The child of level d (0: the root's) on a key's path, as updateNodeRecurs picks it.
  const auto child = [depth](const octomap::OcTreeKey& key, int d) {
    return static_cast<unsigned>(octomap::computeChildIdx(key, depth - 1 - d));
  };
  // path[d]: the node at depth d on the previous key's path (path[depth]: its leaf).
  std::array<octomap::OcTreeNode*, 32> path{};
  path[0] = tree.getRoot();
  for (int d = 0; d < depth; ++d) path[d + 1] = tree.getNodeChild(path[d], child(keys[0], d));
  const float hit = tree.getProbHitLog();
  for (size_t k = 1; k < keys.size(); ++k) {
    // Where the key leaves the previous key's path; in depth-first order no
    // node below that was made for an earlier key, so the rest are new
    // (createNodeChild counts them into the tree's size, as updateNode does).
    int d = 0;
    while (d < depth && child(keys[k], d) == child(keys[k - 1], d)) ++d;
    for (; d < depth; ++d) path[d + 1] = tree.createNodeChild(path[d], child(keys[k], d));
    // A new leaf updated once, as updateNodeRecurs's last level does.
    tree.updateNodeLogOdds(path[depth], hit);
  }
}

}  // namespace bp::internal
