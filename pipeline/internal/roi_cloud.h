// Frame -> base-frame points inside the ROI, plus the organized-grid
// structures the later stages use (normals, connected regions, segments).
// Private to bp_pipeline. Frames: B base, C camera, W bin. SI units.
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "core/cell.h"
#include "core/pose.h"
#include "pipeline/frame.h"

namespace bp::internal {

// ROI points of one frame. For organized frames `pixel_of_point` holds the
// pixel index (v * width + u) of each point and `point_of_pixel` the inverse
// (-1 off the ROI); for unorganized frames both are empty.
struct RoiCloud {
  std::vector<Eigen::Vector3f> points_B;
  std::vector<int32_t> pixel_of_point;
  std::vector<int32_t> point_of_pixel;
  int width = 0;
  int height = 0;
  int64_t valid_points = 0;  // finite points in the frame, before the crop
  bool organized() const { return width > 0; }
};

// The ROI box in W: the bin's inner box less wall_margin on every side, from
// floor_margin above the floor up to height.
struct RoiBox {
  Eigen::Vector3f min_W;
  Eigen::Vector3f max_W;
};
RoiBox MakeRoiBox(const Cell& cell);

// One pass over the frame: deprojects (organized) or takes points_C, maps to
// B with frame.X_BC, keeps finite points inside the ROI box. Organized
// frames are cropped in bands of rows in parallel (on the caller's oneTBB
// arena), each band into buffers of its own, joined in row order: the result
// is that of one pass. `out`'s buffers are reused.
void CropToRoi(const Frame& frame, const Pose& X_BW, const RoiBox& box, RoiCloud* out);

// Drops the points within `margin` (> 0) of any of `near_B` (finite), keeping
// the others in their order (organized clouds stay in row-major pixel order,
// point_of_pixel updated). @returns how many were dropped.
int64_t DropPointsNear(const std::vector<Eigen::Vector3f>& near_B, float margin, RoiCloud* roi);

// Grid used by normals and segmentation: every `stride`-th pixel of an
// organized ROI cloud (stride 1 = all). Indices are ROI point indices.
struct SampleGrid {
  int stride = 1;
  int width = 0;   // grid cells across (ceil(image width / stride))
  int height = 0;
  std::vector<int32_t> point_of_cell;  // ROI point index or -1
  std::vector<int32_t> cell_points;    // ROI indices of the occupied cells, row-major order
};
SampleGrid MakeSampleGrid(const RoiCloud& roi, int stride);

// Normals of the occupied grid cells by cross products of neighbours `radius`
// cells away (central differences, one-sided where a neighbour is missing or
// beyond max_jump), oriented towards `viewpoint_B`. Cells without a normal get
// NaN. Output is indexed like grid.point_of_cell.
void GridNormals(const RoiCloud& roi, const SampleGrid& grid, int radius, float max_jump,
                 const Eigen::Vector3f& viewpoint_B, std::vector<Eigen::Vector3f>* normals);

// Region growing on the grid (4-neighbours): two cells join when their points
// are within max_jump and, if max_normal_angle_rad > 0, their normals differ by
// less than that angle, or (convex_tolerance >= 0) when the crease between
// them is convex: (n_a - n_b) . (p_a - p_b) >= convex_tolerance * |p_a - p_b|.
// Cells in `excluded` (may be empty) never join.
// @returns per cell a region id (-1 = empty / excluded) and the region count.
int GrowRegions(const RoiCloud& roi, const SampleGrid& grid, const std::vector<Eigen::Vector3f>& normals,
                float max_jump, float max_normal_angle_rad, const std::vector<uint8_t>& excluded,
                std::vector<int32_t>* region_of_cell, float convex_tolerance = -1.f);

// Voxel-hash connected components for unorganized ROI clouds (26-neighbours).
// @returns per point a region id and the region count.
int VoxelRegions(const std::vector<Eigen::Vector3f>& points, float voxel, std::vector<int32_t>* region_of_point);

// Spreads grid-cell labels to every ROI point: a point takes the label of the
// cell covering its pixel when within max_jump of that cell's point, else -1.
// Two label sets at once (one pass over the points).
void SpreadLabels(const RoiCloud& roi, const SampleGrid& grid, const std::vector<int32_t>& label_of_cell,
                  float max_jump, std::vector<int32_t>* label_of_point);
void SpreadLabels(const RoiCloud& roi, const SampleGrid& grid, const std::vector<int32_t>& a_of_cell,
                  const std::vector<int32_t>& b_of_cell, float max_jump, std::vector<int32_t>* a_of_point,
                  std::vector<int32_t>* b_of_point);

// Per connected region, what its cells hold: samples of kept segments and of
// pieces too small to be segments, the first kept segment met and whether a
// second one was. Counted over ranges of cells in parallel, then merged in
// range order: the merge of the ranges' counts equals the count of their
// concatenation.
struct RegionSegmentCounts {
  std::vector<int32_t> first_segment, kept_samples, fragment_samples;
  std::vector<uint8_t> multi;  // two or more kept segments

  explicit RegionSegmentCounts(size_t regions = 0)
      : first_segment(regions, -1), kept_samples(regions, 0), fragment_samples(regions, 0), multi(regions, 0) {}
  // A cell of region r (>= 0) with kept segment s (-1: none), a fragment's or not.
  void Add(int32_t r, int32_t s, bool fragment) {
    const auto i = static_cast<size_t>(r);
    fragment_samples[i] += fragment ? 1 : 0;
    if (s < 0) return;
    ++kept_samples[i];
    if (first_segment[i] < 0) first_segment[i] = s;
    else if (first_segment[i] != s) multi[i] = 1;
  }
  // Appends the counts of the cells after this one's (same region count).
  void Merge(const RegionSegmentCounts& later) {
    for (size_t i = 0; i < first_segment.size(); ++i) {
      kept_samples[i] += later.kept_samples[i];
      fragment_samples[i] += later.fragment_samples[i];
      multi[i] |= later.multi[i];
      if (later.first_segment[i] < 0) continue;
      if (first_segment[i] < 0) first_segment[i] = later.first_segment[i];
      else if (first_segment[i] != later.first_segment[i]) multi[i] = 1;
    }
  }
};

}  // namespace bp::internal
