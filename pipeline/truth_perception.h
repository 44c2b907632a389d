// TEST ORACLE, NOT PERCEPTION: a Perception that reads a synthetic frame's
// ground truth instead of detecting anything. Detections are the true parts
// at their true poses; support points are the ROI points whose pixel label is
// the part. It exists to test grasp planning and the bin-clearing loop apart
// from perception (`binpick clear --oracle`); its numbers say nothing about
// perception. Frames without truth give no detections.
//
// The ROI crop and the largest-connected-region count are real (the same rule
// perception follows): points in B, ROI in the bin frame W (inner box shrunk
// by roi.wall_margin, z from roi.floor_margin to roi.height), regions are
// 26-connected cells of a `region_cell` voxel grid.
//
// Thread-safety: Run is const and may be called concurrently.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "core/cell.h"
#include "pipeline/perception.h"

namespace bp {

struct TruthPerceptionOptions {
  double min_visible_fraction = 0.35;  // a part less visible is "not detected"
  int min_support_points = 150;        // nor one with fewer ROI points
  double region_cell = 0.005;          // m, voxel edge for the connected regions
};

class TruthPerception final : public Perception {
 public:
  explicit TruthPerception(Cell cell, TruthPerceptionOptions options = {});
  // `effort` changes nothing: the truth is exact. With a region, its box is
  // the ROI.
  Result<PerceptionResult> Run(const Frame& frame, const std::vector<int>& classes = {},
                               PerceptionEffort effort = PerceptionEffort::kNormal,
                               const std::optional<PerceptionRegion>& region = std::nullopt) const override;

 private:
  Cell cell_;
  TruthPerceptionOptions options_;
};

// Points of the largest 26-connected region of `points` on a voxel grid of
// edge `cell` (a region is the points of face-, edge- or corner-adjacent
// occupied voxels). 0 for no points.
int64_t LargestRegionPoints(std::span<const Eigen::Vector3f> points, double cell);

// True when p (in B) lies in the cell's ROI.
bool InRoi(const Cell& cell, const Eigen::Vector3f& p_B);

}  // namespace bp
