// Perception's segmentation stages: the ROI's points -> connected regions and
// segments -> the views the pose search matches (docs/perception_pipeline.md,
// "Stages"). Private to bp_pipeline. Frames: B base, W bin. SI units.
//
// Organized frames run on a grid of every stride-th pixel:
//   LabelGrid          (stage "regions"): normals, connected regions, segments
//   GroupGridSegments  (stage "segment"): the segments' samples, region views
// Unorganized clouds:
//   LabelCloud         (stage "regions"): voxel-connected regions
//   GroupCloudSegments (stage "segment"): the regions as segments
// Each runs on the caller's oneTBB arena; every result equals a serial pass's.
#pragma once

#include <cstdint>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "core/pose.h"
#include "pipeline/frame.h"
#include "pipeline/internal/roi_cloud.h"

namespace bp::internal {

// What segmentation reads of PerceptionOptions (see there for each field).
struct SegmentationOptions {
  double grid_spacing = 0.0012;     // metres on the bin floor between grid samples
  double max_jump = 0.006;          // metres; neighbours farther apart never join
  double normal_angle_deg = 25.0;   // 0 = no normal condition
  double convex_tolerance = -1.0;   // < 0 = off
  int min_segment_points = 150;     // smaller segments are not matched alone
  bool match_regions = true;
  bool match_fragmented_regions = true;
  // Points within this height of the bin floor whose normal is within
  // acos(floor_min_normal_z) of the floor's are floor, not parts (metres).
  float floor_band = 0.004f;
  float floor_min_normal_z = 0.95f;
};

// Indices into Segments::points: one view the pose search matches.
using ViewIndices = std::vector<int32_t>;

// Stage "regions" of an organized frame: labels per grid cell.
struct GridLabels {
  SampleGrid grid;
  float grid_jump = 0.f;                   // neighbour distance on the grid, metres
  float spacing = 0.f;                     // grid spacing on the bin floor, metres
  std::vector<Eigen::Vector3f> normals;    // per cell, towards the camera; NaN: none
  std::vector<int32_t> region_of_cell;     // connected region (depth continuity), -1: empty
  std::vector<int32_t> segment_of_cell;    // grown segment, -1: empty or floor band
  int regions = 0;                         // connected regions
  int segments = 0;                        // grown segments, before the size filter
};

// Segmentation's result, the pose stage's input.
struct Segments {
  // Samples of the kept segments grouped by segment, largest first: segment
  // s is [range[s].first, range[s].second). After them (organized frames,
  // match_regions), the samples of the pieces below min_segment_points (in
  // no range): first those region views hold, then the others (the residual
  // regions' pass groups them).
  std::vector<Eigen::Vector3f> points;
  std::vector<Eigen::Vector3f> normals;  // one per point; empty for unorganized clouds
  std::vector<int32_t> roi_index;        // ROI point index of each sample
  std::vector<std::pair<int32_t, int32_t>> range;
  // Connected regions matched whole (SegmentationOptions::match_regions).
  std::vector<ViewIndices> region_views;
  std::vector<int32_t> segment_of_point;  // per ROI point: kept segment, -1: none
  std::vector<int32_t> region_of_point;   // per ROI point: connected region, -1: none
  // Organized frames: each sample's grid cell (row-major, grid_width cells
  // across) and the grid's neighbour distance (GridLabels::grid_jump):
  // samples of 4-neighbour cells within grid_jump are connected. Empty /
  // 0 for unorganized clouds.
  std::vector<int32_t> cell_of_sample;
  int grid_width = 0;
  float grid_jump = 0.f;
  // The fewest samples a segment holds here (the options' min_segment_points
  // the segments were kept by); the later passes' views need as many.
  int min_points = 0;
};

// Normals, connected regions and grown segments on the grid whose spacing on
// the bin floor is about options.grid_spacing (frame: organized).
GridLabels LabelGrid(const RoiCloud& roi, const Frame& frame, const Pose& X_BW, const SegmentationOptions& options);

// Keeps the segments of at least min_segment_points samples (after merging
// fragmented regions), groups their samples, forms the region views and
// labels every ROI point. Consumes `labels`.
Segments GroupGridSegments(const RoiCloud& roi, GridLabels labels, const SegmentationOptions& options);

// Unorganized clouds: connected components of voxels of `voxel` metres.
// @returns per ROI point its region, and the region count.
std::pair<std::vector<int32_t>, int> LabelCloud(const RoiCloud& roi, float voxel);

// Unorganized clouds: every region of at least min_segment_points points is
// a segment (no normals, no region views).
Segments GroupCloudSegments(const RoiCloud& roi, std::vector<int32_t> region_of_point, int regions,
                            int min_segment_points);

// Points in the largest connected region (the empty-box rule); 0 for none.
int64_t LargestRegionPoints(const std::vector<int32_t>& region_of_point);

// One view per segment: its samples, then (context_radius > 0) the other
// samples within context_radius of its centroid, in sample order.
std::vector<ViewIndices> SegmentViews(const Segments& segments, float context_radius);

}  // namespace bp::internal
