// Private to bp_collision: an octomap OcTree of occupied voxels built in one
// pass over their keys sorted in the tree's own order, instead of a walk
// from the root per voxel (OccupancyOcTreeBase::updateNode): the points'
// obstacle (collision/point_obstacle.h) is built once per frame, and the
// walks were most of its cost.
#pragma once

#include <octomap/OcTree.h>

#include <cstdint>
#include <span>

namespace bp::internal {

// A voxel key's place in a depth-first walk of the octree: its 16-bit x, y
// and z interleaved (z highest in each triple, as octomap numbers a node's
// children, octomap::computeChildIdx), most significant level first.
// One-to-one on keys.
uint64_t TreeOrder(const octomap::OcTreeKey& key);

// Marks each of `keys` occupied in `tree` as tree.updateNode(key, true,
// lazy_eval = true) would for each in turn: the same nodes, log-odds and
// tree size (each leaf is new; the nodes on the path shared with the
// previous key are reused rather than searched for from the root). Then
// call tree.updateInnerOccupancy(), as after lazy updates.
// REQUIRES: `tree` empty; keys distinct and sorted by TreeOrder.
void InsertSortedKeys(octomap::OcTree& tree, std::span<const octomap::OcTreeKey> keys);

}  // namespace bp::internal
