// Render-free verification of one pose against a view (docs/perception.md,
// "Verification"): the model's camera-facing, not self-occluded samples are
// supported by a view point, in free space before the measured surface
// (evidence against) or occluded behind it (no evidence). Also the filled-hole
// test. Private to bp_pipeline. Frames: B base, C camera, O part. Metres.
#pragma once

#include <cstdint>
#include <span>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "core/pose.h"
#include "pipeline/internal/point_hash.h"
#include "pipeline/pose_estimator.h"

namespace bp::internal {

struct PoseModel;

// Without a depth image: the view's points splatted into an angular grid
// seen from the camera centre, keeping the nearest depth per cell. Cells
// without points are unknown.
struct SegmentDepth {
  Eigen::Vector3f c = Eigen::Vector3f::Zero(), x = Eigen::Vector3f::UnitX(), y = Eigen::Vector3f::UnitY(),
                  z = Eigen::Vector3f::UnitZ();
  float cell_ang = 1;
  int nu = 0, nv = 0;
  float u0 = 0, v0 = 0;
  std::vector<float> zmin;
  bool empty() const { return zmin.empty(); }
  // Nearest measured depth along the ray through p, NaN if unknown; *d gets p's depth.
  float At(const Eigen::Vector3f& p, float* d) const;
};
// Cells of cell_m metres at the points' mean range; empty for an extent of
// more than 4M cells.
SegmentDepth BuildSegmentDepth(std::span<const Eigen::Vector3f> pts, const Eigen::Vector3f& camera, float cell_m);

// The view's points for the support test: a hash of them and, when each of
// them lies on its pixel of the view's depth image (projects onto its
// centre, at the depth it holds: the grid samples of a frame), that fact.
// Then a model point with no pixel near it in the depth image at a depth
// within the support distance of its own has no view point within that
// distance either, and the hash is not asked: the same answers, for a few
// pixel reads instead of eight hash probes.
struct SceneSupport {
  PointHash hash;
  bool on_depth = false;

  // Builds the hash of pts (finite) with cells of `cell` and checks them
  // against the view's depth image.
  void Build(std::span<const Eigen::Vector3f> pts, float cell, const SceneView& view);
  // True when a view point lies within r of p (p_C: p in C, (u, v) its pixel).
  bool AnyWithin(const Eigen::Vector3f& p, float r, const Eigen::Vector3f& p_C, int u, int v,
                 const SceneView& view) const;
};

struct VerifyStats {
  int visible = 0, occluded = 0, supported = 0, free_space = 0;
  // Of the visible points, those on a grazing face (more than 60 deg off the
  // line of sight, where depth sensors drop pixels) whose pixel has no
  // measurement and that no scene point supports.
  int unmeasured = 0;
  bool below_support = false;  // the pose sinks the part into the support plane
  // (supported - free_space_weight * free_space) / (visible - occluded
  // [- unmeasured]); -1 when nothing is visible or below the support plane.
  double score = -1;
  // Verify with a bar stopped once the score could no longer reach it: the
  // counts are partial and score is the highest the rest could have made
  // it (below the bar).
  bool cut_short = false;
};

// Visibility, support and free-space test of the part at X_BO. stride > 1
// checks every stride-th verification sample (a quick pass).
// unmeasured_is_no_evidence: PoseSearch::unmeasured_is_no_evidence.
// bar: a pose whose score is below it is of no use to the caller; the test
// stops once the samples left, were each supported, could not lift the
// score to it (VerifyStats::cut_short). A score that reaches the bar, and
// every count with it, is the same as without one.
VerifyStats Verify(const PoseModel& model, const Pose& X_BO, const SceneView& view, const SceneSupport& scene,
                   const SegmentDepth& segment_depth, int stride = 1, bool unmeasured_is_no_evidence = false,
                   double bar = -1.0);

// Hole points in view and, of those, filled: where the measured surface goes
// on through the part's hole (depth image only; {0, 0} without one).
std::pair<int, int> HoleStats(const PoseModel& model, const Pose& X_BO, const SceneView& view);

}  // namespace bp::internal
