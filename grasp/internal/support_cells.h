// The ROI points a detection's support sample stands for
// (GraspPlanningOptions::support_grid_spacing): every point within a
// distance of an explained (support) point is explained too. Private to
// bp_grasp. Frames: B (the points'). Metres.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include <Eigen/Core>

namespace bp::internal {

// Marks explained[i] for every finite point of `points` not marked yet whose
// squared distance to a marked (support) point is at most
// float(reach * reach). Support bounds wider than 2^24 cubes of edge
// `reach` (a far outlier among the supports) mark nothing more. The points
// are looked at in parallel (the caller's arena): each writes its own flag
// and reads the support points only.
// REQUIRES: explained.size() == points.size(), reach > 0.
void ExplainSupportCells(std::span<const Eigen::Vector3f> points, double reach, std::vector<uint8_t>& explained);

}  // namespace bp::internal
