// The perception settings that scale with the part and the camera
// (docs/perception_pipeline.md, "Settings that scale"). The options'
// defaults are the values for the reference: parts of 40-130 mm and a camera
// whose axial noise at the bin floor is at most 0.44 mm and whose views are
// sampled at about 1.3 mm. A setting moves away from its option only where a
// part or the camera demands it, so the shipped cell keeps its values.
// Private to bp_pipeline. Metres.
#pragma once

#include <string>
#include <vector>

#include "core/cell.h"
#include "core/mesh.h"
#include "core/status.h"
#include "pipeline/perception.h"
#include "pipeline/pose_estimator.h"

namespace bp::internal {

// What the camera tells the settings, from the cell: per camera config, the
// axial noise at the bin floor and the grid spacing of the views there
// (PerceptionOptions::grid_spacing rounded to whole pixels of its
// footprint); the largest of each.
struct CameraFigures {
  double sigma_floor = 0.0;   // sigma_z at the floor's depth, metres
  double view_spacing = 0.0;  // distance between a view's grid samples, metres
};
CameraFigures CameraFiguresOf(const Cell& cell, const PerceptionOptions& options);

// A mesh's size, for the checks and the formulas.
struct PartGeometry {
  double diameter = 0.0;  // largest vertex distance, metres
};
PartGeometry MeasureMesh(const TriangleMesh& mesh);

// InvalidArgument naming the likely unit when the mesh cannot be in metres:
// its header declares another unit (unit_hint, core/mesh.h MeshUnitHint),
// or it spans under 2 mm or over 2 m.
Status CheckMeshScale(const PartGeometry& geometry, const std::string& unit_hint, const std::string& path);

// The support distance's floor in units of sigma_floor: a measured point
// within this many sigma_z of a part's surface is that part's (about 1 in
// 1500 of a surface's points falls outside under normal noise).
constexpr double kSupportSigmas = 3.4;

// The estimator's options for one part: `reference` (the defaults) scaled by
//   ppf step            = max(ppf_relative_sampling D, view_spacing), at most 0.2 D
//   icp spacing         = max(icp_model_spacing, D / 300)
//   verify spacing      = max(icp spacing, min(verify_model_spacing, D / 15))
//   support distance    = max(support_distance, kSupportSigmas sigma_floor)
//   free-space distance = max(free_space_distance, 6.8 sigma_floor)
//   ICP final gate      = max(icp_final_distance, 4.5 sigma_floor)
// with D the part's diameter, then the part's overrides (parts[].perception).
PoseEstimatorOptions ScaledEstimatorOptions(const PartGeometry& geometry, const CameraFigures& camera,
                                            const PartPerception& overrides,
                                            const PoseEstimatorOptions& reference = {});

// The pipeline's options for the cell's classes: `options` (the defaults)
// scaled by, over the classes (D_min the smallest diameter; h_min the
// lowest upward face of a part lying on the floor, ClassModel::
// lowest_upward_face, or its flat_height override; n_min the smallest
// min_view_points override):
//   min_segment_points     = clamp(0.15 D_min^2 / view_spacing^2, 30, min_segment_points),
//                            or n_min
//   floor band             = clamp(h_min - max(1 mm, 2 sigma_floor) (to 0.1 mm),
//                                  3 sigma_floor, max(floor_band, 3 sigma_floor))
//   view_waves, second_look_min_points: times min_segment_points' ratio
//   min_segment_spacing    = view_spacing when < 0 (the spacing the count is at)
// Returns a description of what changed (empty: nothing).
struct ClassFigures {
  double diameter = 0.0;
  double flat_height = 0.0;
  int min_view_points = 0;  // 0: derived
};
std::string ScaleToClasses(const std::vector<ClassFigures>& classes, const CameraFigures& camera,
                           PerceptionOptions* options);

// One frame's min_segment_points, its grid `spacing` on the bin floor
// (metres) coarser than min_segment_spacing: the same surface area,
//   max(round(min_segment_points (min_segment_spacing / spacing)^2), min(30, min_segment_points));
// min_segment_points itself when the grid is not coarser or
// min_segment_spacing <= 0 (PerceptionOptions::min_segment_spacing).
int FrameMinSegmentPoints(int min_segment_points, double min_segment_spacing, double spacing);

}  // namespace bp::internal
