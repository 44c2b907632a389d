// The perception pipeline: frame -> base-frame points -> ROI crop ->
// segmentation -> pose estimation -> verified detections (issue 3).
//
// Frames (STYLE.md): B robot base, C camera, W bin, O part. SI units.
// Thread-safety: Perception is built once at start-up (model tables are
// cached); Run() is const and may be called concurrently. Run uses the oneTBB
// arena of the calling thread (the caller owns the arena and its size).
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/cell.h"
#include "core/pose.h"
#include "core/status.h"
#include "pipeline/frame.h"
#include "pipeline/pose_estimator.h"

namespace bp {

struct Detection {
  int class_id = 0;
  Pose X_BO = Pose::Identity();   // part in robot base
  double score = 0.0;             // fraction of the visible model surface supported by scene points
  double visible_fraction = 0.0;  // estimated fraction of the part's surface that is visible
  double rms_residual = 0.0;      // point-to-plane RMS of the fit over its support, metres
  std::vector<int32_t> support;   // indices into PerceptionResult::roi_points_B
};

struct StageTiming {
  std::string stage;  // "deproject", "roi", "segment", "pose", "verify", ...
  double ms = 0.0;
};

struct PerceptionResult {
  std::vector<Detection> detections;
  // Valid points inside the ROI, in B (after the crop). Detections' support
  // and segments index into this.
  std::vector<Eigen::Vector3f> roi_points_B;
  // Segment id per ROI point (-1 = floor / noise / unassigned).
  std::vector<int32_t> segment_of_point;
  int64_t roi_point_count = 0;          // == roi_points_B.size()
  int64_t largest_region_points = 0;    // largest connected region of ROI points (empty-box rule)
  std::vector<StageTiming> timings;
  int views = 0;              // segment, region and residual views formed
  int views_explained = 0;    // of those, skipped as pieces of parts already found (view_waves)
  int estimator_calls = 0;    // (view, class) pose estimates run
  int second_looks = 0;       // views matched again (PerceptionOptions::second_look_below)
  int coarse_refined = 0;     // coarse poses and seeds refined (first ICP pass) over all estimates
  int coarse_skipped = 0;     // second look: coarse poses not refined again (second_look_skip_tried)
  // Axial depth noise measured in the frame (organized frames; 0 otherwise):
  // sigma (metres) from second differences along the rows, at the median
  // depth depth_noise_at (metres). Above the camera config's NoiseModel, it
  // scales the fit residual limit (PerceptionOptions::max_fit_rms_sigmas).
  double depth_noise_sigma = 0.0;
  double depth_noise_at = 0.0;
  std::string reason;                   // why there are no detections, when there are none
  double TotalMs() const;
};

struct PerceptionOptions {
  int threads = 2;  // size of the oneTBB arena the pipeline creates when the caller has none
  // Segmentation (docs/perception_pipeline.md): organized-grid region growing.
  // Neighbouring points join when closer than segment_max_jump (metres) and
  // their normals differ by less than segment_normal_angle_deg (0 = no normal
  // condition: depth-continuous connected components).
  double segment_max_jump = 0.006;
  double segment_normal_angle_deg = 25.0;
  // With >= 0, neighbours across a convex crease join whatever their normals
  // ((n_a - n_b) . (p_a - p_b) >= this * |p_a - p_b|); < 0 = off.
  double segment_convex_tolerance = -1.0;
  // Segments with fewer grid points are not sent to the pose estimator.
  int min_segment_points = 150;
  // Detections need at least this verification score (the estimator's own
  // threshold is lower; measured: wrong-class / wrong-pose hypotheses that
  // survive it mostly score 0.35-0.7, true ones 0.9+).
  double min_detection_score = 0.7;
  // A hypothesis whose fit residual (point-to-plane RMS over its support)
  // exceeds max_fit_rms_sigmas times the axial depth noise sigma_z at its
  // depth, and at least min_fit_rms_limit, is the wrong shape: a bushing's
  // 36 mm hub fitted onto a tee's 40 mm pipe supports most of its samples
  // within support_distance but leaves residuals above the noise. sigma_z is
  // the capturing camera config's NoiseModel, scaled up when the frame
  // measures noisier (PerceptionResult::depth_noise_sigma: a camera noisier
  // than its cell says loses no true detection). 0 = off. Measured (`binpick
  // eval`, 130 scenes, docs/perception_pipeline.md): true detections leave at
  // most 1.07 sigma_z (median 0.7), 7 of the 35 false positives more.
  double max_fit_rms_sigmas = 1.15;
  double min_fit_rms_limit = 0.0002;
  // Also match each connected region (depth continuity only) that holds two
  // or more segments, or one segment and pieces below min_segment_points
  // (a quarter of its points or more), as one more view of all its non-floor
  // points (parts cut by the normal condition).
  bool match_regions = true;
  // A connected region whose segments are all below min_segment_points but
  // that holds at least that many grid points as a whole is matched as one
  // segment (thin parts whose faces the normal condition cuts apart).
  bool match_fragmented_regions = true;
  // The pose estimator sees each segment plus the other segments' points
  // within this fraction of the largest part diameter of its centroid (0 = the
  // segment alone).
  double context_relative_radius = 0.0;
  // A class is "too small" for a view whose extent along its first principal
  // axis exceeds the class's diameter (plus noise tolerance): the view is not
  // one instance of it. Such classes are tried last, only when no class that
  // fits found a detection (a merged segment may hold one), and need
  // too_small_class_min_score. Region views no class fits are skipped.
  bool class_prefilter = true;
  // Classes are tried per view in order of extent match; the others are
  // skipped when the first one's best hypothesis scores at least this and its
  // support holds at least early_exit_support of the view's points. 0 = run
  // every class on every view. Measured (`binpick eval`, all 130 scenes of
  // docs/perception_pipeline.md): 0.8 instead of 0.85 gives the same
  // detections with 51.5 instead of 52.5 estimator calls per frame; 0.75
  // loses a part (recall 0.9510, precision 0.9871 against 0.9515 / 0.9875).
  // The second look exits early too (it ran every class that fits until
  // 2026-12-03): the same detections on all 130 scenes and the held-out 30,
  // estimator calls -3% and coarse poses refined -6.4% on seeds 11-40.
  double early_exit_score = 0.8;
  double early_exit_support = 0.6;
  // The ranking adds this times how far the view's planar share (the share
  // of its normals within 15 deg of its two main directions: an L-bracket's
  // plates near 1, a pipe lower) lies outside the class's range seen from
  // 64 directions (internal::ModelPlanarShareRange), less 0.1 of slack. 0 =
  // extents alone. Measured (`binpick eval`, seeds 11-40): estimator calls
  // 1451 -> 1402, coarse poses refined 5941 -> 5714, the same detections on
  // all 130 scenes and the held-out 30 (docs/perception_pipeline.md).
  double rank_planar_share_weight = 4.0;
  // Detections of a class too small for the view (tried last, when no class
  // that fits found anything: merged segments) need at least this score.
  double too_small_class_min_score = 0.85;
  // Views (segments and region views) are matched in waves by size: first
  // those with at least view_waves[0] grid points, then those with at least
  // view_waves[1], ..., then the rest. Before each wave after the first, the
  // detections so far are accepted, and a view whose points lie mostly (60%)
  // on an accepted detection's surface is not matched: it is a piece of a
  // part already found. Empty = one wave (every view matched).
  std::vector<int> view_waves = {2000, 800, 300};
  // Grid spacing targeted on the bin floor (metres): high-resolution frames are
  // segmented and matched on every k-th pixel so that the spacing is about this.
  double grid_spacing = 0.0012;
  // A second look: after the waves, a view whose best hypothesis over the
  // classes tried scored below this (none at all included), that holds at
  // least second_look_min_points grid points and that no detection scoring
  // at least this explains (as for view_waves) is matched again by the
  // classes that fit it (in order, with the early exit above), with
  // second_look_search; what it finds competes with
  // the detections so far by score. 0 = off. Measured (`binpick eval`, seeds
  // 1-10 / 11-40 / 41-70, docs/perception_pipeline.md): recall 0.951 / 0.950
  // / 0.955 against 0.933 / 0.942 / 0.936 with it off, precision 0.988 /
  // 0.979 / 0.987 against 0.988 / 0.981 / 0.986, about 20 ms more per
  // frame (median). The recall comes from the coarse poses ranked 5-12 by
  // PPF votes.
  double second_look_below = 0.9;
  int second_look_min_points = 450;
  PoseSearch second_look_search{.max_reference_points = 20, .max_coarse_poses = 12, .peaks_per_reference = 2,
                                .peaks_examined = 16, .stop_score = 0.9};
  // The second look does not refine again the coarse poses the view's
  // estimate in its wave refined (per class; PoseSearch::skip_coarse).
  // Measured (all 130 scenes of docs/perception_pipeline.md): 11.8% fewer
  // first-pass ICPs (coarse_refined), recall 0.9515 -> 0.9524, precision
  // 0.9875 -> 0.9871, the same true positives.
  bool second_look_skip_tried = true;
  // The second look (with second_look_skip_tried) tries the classes of a
  // view in the order of their best hypothesis in the view's wave, then as
  // ranked there: the class that came closest first. Measured (`binpick
  // eval`, seeds 11-40): estimator calls 1404 -> 1395, coarse poses refined
  // 5722 -> 5651, the same detections on all 130 scenes and the held-out 30.
  bool second_look_rank_by_wave = true;
  // A thorough run (PerceptionEffort::kThorough) tries every class on every
  // view (no early exit) with this wider coarse search. The grasp planner
  // retries with it when a normal run leaves nothing to pick in a bin that is
  // not empty (docs/perception.md, "Thorough retry").
  PoseSearch thorough_search{.max_reference_points = 20, .max_coarse_poses = 24, .peaks_per_reference = 2,
                             .peaks_examined = 30, .resting_seeds = true, .keep_better_than_fine = true,
                             .unmeasured_is_no_evidence = true};
};

enum class PerceptionEffort {
  kNormal,
  kThorough,  // see PerceptionOptions::thorough_search; slower
};

class Perception {
 public:
  virtual ~Perception() = default;
  // Builds model tables for every part class of the cell (slow, once).
  static Result<std::unique_ptr<Perception>> Build(const Cell& cell, const PerceptionOptions& options = {});
  // Detects parts of `classes` (empty = all cell parts) in `frame`. Empty ROI,
  // an all-NaN frame or degenerate segments give an OK result with no
  // detections and a reason; never a pose built from NaNs.
  virtual Result<PerceptionResult> Run(const Frame& frame, const std::vector<int>& classes = {},
                                       PerceptionEffort effort = PerceptionEffort::kNormal) const = 0;
};

}  // namespace bp
