// The bin's fill level (issue 41 item 2): a height map of the ROI's points
// over the bin floor, per perception run into the bin.
//
// The floor inside the ROI (the bin's inner floor less the ROI's wall
// margin) is cut into square cells; each cell's height is that of its
// highest ROI point above the floor (z in the bin frame W), 0 for a cell
// with none (the floor itself lies below the ROI's floor margin; a cell the
// camera does not see also counts 0, so a pile's shadowed flanks are
// under-counted). Frames: B robot base, W bin. SI units. Thread-safety: a
// free function over const inputs.
#pragma once

#include <span>

#include <Eigen/Core>

#include "core/pose.h"

namespace bp {

struct FillLevel {
  double mean_height = 0.0;        // m, mean of the cells' heights
  double max_height = 0.0;         // m, the highest ROI point above the floor
  double occupied_fraction = 0.0;  // [0, 1], cells higher than FillLevelOptions::occupied_height
  int cells = 0;                   // cells over the ROI's floor
};

struct FillLevelOptions {
  double cell_size = 0.01;         // m, > 0
  // A cell is occupied above this height (m): the floor's depth noise and
  // the ROI's floor margin stay below it, the thinnest shipped part (5 mm)
  // lying flat reaches it.
  double occupied_height = 0.004;
};

// The fill level of the floor rectangle |x| <= half_extent.x(), |y| <=
// half_extent.y() of the bin frame at X_BW, from points in B (points
// outside the rectangle are ignored).
FillLevel MeasureFillLevel(std::span<const Eigen::Vector3f> points_B, const Pose& X_BW,
                           const Eigen::Vector2d& half_extent, const FillLevelOptions& options = {});

}  // namespace bp
