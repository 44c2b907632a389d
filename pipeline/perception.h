// The perception pipeline: frame -> base-frame points -> ROI crop ->
// segmentation -> pose estimation -> verified detections (issue 3).
//
// Frames (STYLE.md): B robot base, C camera, W bin, O part. SI units.
// Thread-safety: Perception is built once at start-up (model tables are
// cached); Run() is const and may be called concurrently. Run uses the oneTBB
// arena of the calling thread (the caller owns the arena and its size).
#pragma once

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/cell.h"
#include "core/mesh.h"
#include "core/pose.h"
#include "core/status.h"
#include "pipeline/bin_detection.h"
#include "pipeline/fill_level.h"
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
  // Hypotheses that differ by more than the pose tolerance explain the view
  // about equally well (issue 37 item 3; PoseHypothesis::alternatives): the
  // other poses the part may have, besides X_BO. Free space has ruled out
  // those it could. A grasp is valid on such a detection only when it is
  // valid at every one of them as well (kAmbiguous, grasp/grasp_planning.h),
  // and its contact region must be seen even under a gripper's
  // `if_ambiguous` seen-contact rule (SeenContactRule).
  std::vector<Pose> alternatives_X_BO = {};
  bool pose_ambiguous() const { return !alternatives_X_BO.empty(); }
};

struct StageTiming {
  std::string stage;  // "smooth", "roi", "regions", "segment", "pose", "verify", ...
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
  // Axial depth noise measured in the frame (organized frames with a fit
  // limit; 0 otherwise), metres, at the median depth depth_noise_at: above
  // the camera config's NoiseModel it scales the fit residual limit.
  double depth_noise_sigma = 0.0;
  double depth_noise_at = 0.0;
  // A run within a PerceptionBudget: (view, class) estimates not started
  // because the budget would have been exceeded (not in estimator_calls).
  int estimates_skipped = 0;
  // Detections withheld as ambiguous and mostly hidden
  // (PerceptionOptions::ambiguous_min_visible).
  int withheld_ambiguous = 0;
  // Detections withheld as seen on one plane and mostly hidden
  // (PerceptionOptions::one_plane_min_visible).
  int withheld_one_plane = 0;
  bool budget_exhausted() const { return estimates_skipped > 0; }
  std::string reason;                   // why there are no detections, when there are none
  // The bin detection stage of a run into the bin (bin.detect on or
  // required); nullopt when it did not run (off, a task's own region). When
  // found, its X_BW is the bin pose the run cropped and took the floor from.
  std::optional<BinDetection> bin;
  // The bin's fill level (pipeline/fill_level.h) from the ROI's points over
  // the floor of the bin pose used; runs into the bin only.
  std::optional<FillLevel> fill;
  double TotalMs() const;
};

// The bin pose a result stands on: the measured one when its run found the
// bin, else the cell's nominal bin.pose. The grasp stage tests the gripper
// against the walls at this pose; the empty-box rule counts the points of
// the ROI cropped at it.
inline const Pose& BinPoseOf(const PerceptionResult& result, const BinSpec& bin) {
  return result.bin && result.bin->found ? result.bin->X_BW : bin.X_BW;
}

// Defaults were chosen on the shipped cell (docs/tuning.md has the figure
// behind each and its command) and are the values for its parts and camera:
// Build scales min_segment_points, floor_band, view_waves and
// second_look_min_points to the cell's smallest and flattest parts and its
// camera (docs/perception_pipeline.md, "Settings that scale"). Distances in
// metres.
struct PerceptionOptions {
  int threads = 2;  // arena size when the caller has none (Build's model tables); >= 1
  // Depth smoothing (organized frames): a frame whose axial noise at its
  // median depth exceeds smoothing_target_sigma (metres; 0 = never smooth)
  // is averaged over the smallest window, of half width at most
  // smoothing_max_radius pixels, that brings it there; neighbours farther
  // than smoothing_gate_sigmas noise sigmas in depth stay out (edges).
  double smoothing_target_sigma = 0.0005;
  int smoothing_max_radius = 2;
  double smoothing_gate_sigmas = 2.0;
  // Segmentation: neighbouring grid points join when closer than
  // segment_max_jump (> 0) and their normals differ by less than
  // segment_normal_angle_deg (0 = no normal condition). Fewest merges.
  double segment_max_jump = 0.006;
  double segment_normal_angle_deg = 25.0;
  // >= 0: neighbours across a convex crease join whatever their normals
  // ((n_a - n_b) . (p_a - p_b) >= this * |p_a - p_b|); < 0 = off (merged more).
  double segment_convex_tolerance = -1.0;
  // Segments with fewer grid points are not matched alone (>= 1).
  int min_segment_points = 150;
  // The grid spacing on the bin floor (metres) at which min_segment_points
  // is counted. A frame whose grid is coarser (a lower resolution, a shorter
  // focal length, a farther camera) needs min_segment_points x
  // (min_segment_spacing / its spacing)^2 grid points: the same surface
  // area, at least min(30, min_segment_points). < 0: Build sets it to the
  // cell camera's view spacing (the one min_segment_points is scaled to);
  // 0: the same count on every frame.
  double min_segment_spacing = -1.0;
  // Grid points within this height of the bin floor whose normal is within
  // 18 deg of up are floor, not parts (> 0); below the shipped parts' 5 mm.
  double floor_band = 0.004;
  // Detections need this verification score, in [0, 1]. The estimator's own
  // bar (PoseEstimatorOptions::min_score) is 0.6; frames whose grazing faces
  // drop depth leave true poses at 0.6-0.7, about as often right as the
  // detections above (strict rule, docs/tuning.md).
  double min_detection_score = 0.6;
  // A hypothesis whose fit residual exceeds max_fit_rms_sigmas x the depth
  // noise sigma_z at its depth (and min_fit_rms_limit, metres) is the wrong
  // shape. 0 = off. True detections leave at most 1.07 sigma_z.
  double max_fit_rms_sigmas = 1.15;
  double min_fit_rms_limit = 0.0002;
  // Also match each connected region holding two or more segments, or one
  // and pieces below min_segment_points (a quarter of it or more), whole.
  bool match_regions = true;
  // A connected region of small pieces only but >= min_segment_points grid
  // points in all is one segment (thin parts whose faces the normals cut).
  bool match_fragmented_regions = true;
  // Each segment view also holds the samples within this fraction of the
  // largest diameter of its centroid; 0 = the segment alone (better).
  double context_relative_radius = 0.0;
  // Classes whose diameter a view exceeds are tried last, only when no
  // class that fits found a detection (a merged segment may hold one).
  bool class_prefilter = true;
  // Classes run per view best-ranked first; the others are skipped when its
  // best hypothesis scores >= early_exit_score and holds >= early_exit_support
  // of the view's points. 0 = every class on every view.
  double early_exit_score = 0.8;
  double early_exit_support = 0.6;
  // Weight, >= 0, of the view's planar share outside the class's range in
  // the class ranking (besides the extents); 0 = extents alone.
  double rank_planar_share_weight = 4.0;
  // A hypothesis with more than this fraction of its seen samples in free
  // space (in front of the measured surface, beyond free_space_distance at
  // the pixel and around it: where the camera saw through the part) is not
  // a detection, whatever its score. In [0, 1]; 1 = off. The free-space test
  // is set beyond the noise (6.8 sigma_z), so true poses leave none but at
  // their outline; a part fitted into a larger one (a bushing in a tee's
  // run) sticks out of its surface.
  double max_free_space_fraction = 0.01;
  // A pose that sinks the part more than this below the bin floor is not a
  // detection (metres, >= 0; PoseEstimatorOptions::max_support_penetration,
  // whose own default, 3 mm, direct estimator users keep). True poses of
  // parts resting on the floor sink at most about 1.1 mm (tuning seeds with
  // variety); a pipe tee standing on its branch and turned about its run
  // pushes the branch's rim 1-3 mm into it (docs/tuning.md).
  double max_support_penetration = 0.0015;
  // PoseEstimatorOptions::ambiguity_net_gain, handed to every class's
  // estimator (>= 0; 0 = off; docs/tuning.md).
  double ambiguity_net_gain = PoseEstimatorOptions{}.ambiguity_net_gain;
  // PoseEstimatorOptions::arm_swaps, handed to every class's estimator
  // (docs/tuning.md).
  bool arm_swaps = PoseEstimatorOptions{}.arm_swaps;
  // PoseEstimatorOptions::planar_view_min_share, handed to every class's
  // estimator: a view this share of which lies on one plane gets face
  // seeds (an L-bracket seen edge-on, its side face 2-4 pixels wide at
  // 640x480). In [0, 1]; 0 = the RMS test alone; 0.75 chosen on the tuning
  // seeds (docs/tuning.md, `planar_view_min_share`).
  double planar_view_min_share = 0.75;
  // PoseEstimatorOptions::unmeasured_is_no_evidence, handed to every class's
  // estimator (the waves', residual and enclosing searches); the second
  // look's and thorough searches set their own (true). A grazing face over
  // pixels the camera dropped is no evidence against a pose: without it
  // true L-brackets seen edge-on scored 0.43-0.6 (docs/tuning.md).
  bool unmeasured_is_no_evidence = true;
  // After every pass, a detection of a class nearly round about an axis (a
  // pipe tee about its run) is turned again on its own points, those its
  // accepted neighbours explain left out (internal::RedecideTurns): a turn
  // that explains more than (1 + own_turn_gain) times what its pose does
  // replaces it (stage "own_turns"). < 0 = off (docs/tuning.md).
  double own_turn_gain = 0.01;
  // own_turns judges again only the parts whose accepted neighbours hold at
  // least this fraction of the points within the part's reach, or whose pose
  // is ambiguous (in [0, 1]; below it the own points are about the view the
  // fine pass judged the turns on; 0.1 before issue 40, docs/tuning.md).
  double own_turn_min_foreign = 0.3;
  // Last, a detection whose pose is ambiguous (Detection::pose_ambiguous:
  // poses beyond the tolerance explain the view about as well) and of which
  // less than this fraction of the camera-facing surface is seen
  // (Detection::visible_fraction) is withheld: a part mostly hidden whose
  // distinguishing feature is among the hidden (a pipe tee's branch) is
  // left for a later capture, not answered in a guessed pose
  // (PerceptionResult::withheld_ambiguous). In [0, 1]; 0 = off
  // (docs/tuning.md).
  double ambiguous_min_visible = 0.5;
  // Then a detection of which less than this fraction of the camera-facing
  // surface is seen and whose support lies on one plane (95% of it within
  // 1.5 mm) is withheld: one flat face seen alone fixes the plane, but
  // which flat face of the part it is and where on it the part lies come
  // from an outline the occluders cut (an L-bracket's seen base fitted by
  // its upright, 30 mm along). PerceptionResult::withheld_one_plane. In
  // [0, 1]; 0 = off. 0.4: above it the rule took parts the recall counts
  // (docs/tuning.md, `one_plane_min_visible`).
  double one_plane_min_visible = 0.4;
  // Acceptance: a candidate whose surface centre lies within 0.3 of the
  // larger diameter of an accepted detection's conflicts with it only when
  // at least this fraction of the candidate's support lies on that
  // detection's surface (within 2.5 mm; or they interpenetrate, which
  // conflicts anyway). The same part found again from another of its
  // segments lies on it; two true neighbours may have close surface
  // centres (a bushing in an L-bracket's corner, two brackets side by
  // side) but each one's points lie on its own surface. In [0, 1]; 0 =
  // centre closeness alone conflicts (docs/tuning.md).
  double near_centre_min_shared = 0.3;
  // Score a class too small for the view needs, in [0, 1].
  double too_small_class_min_score = 0.85;
  // Views are matched in waves of at least view_waves[i] grid points
  // (strictly decreasing); a later wave skips views lying (60%) on accepted
  // detections. Empty = one wave.
  std::vector<int> view_waves = {2000, 800, 300};
  // Grid spacing on the bin floor: high-resolution frames are segmented on
  // every k-th pixel so that the spacing is about this (> 0).
  double grid_spacing = 0.0012;
  // Second look: views of >= second_look_min_points grid points whose best
  // score was below second_look_below and that no detection scoring that
  // much explains are matched again with second_look_search. 0 = off.
  double second_look_below = 0.9;
  int second_look_min_points = 450;
  PoseSearch second_look_search{.max_reference_points = 20, .max_coarse_poses = 12, .peaks_per_reference = 2,
                                .peaks_examined = 16, .unmeasured_is_no_evidence = true, .stop_score = 0.9};
  // The second look does not refine again the coarse poses its wave refined
  // for the same view and class.
  bool second_look_skip_tried = true;
  // The second look tries a view's classes in the order of their best score
  // in its wave.
  bool second_look_rank_by_wave = true;
  // After the residual pass, the samples no detection explains (of segments
  // and of pieces too small to be one) are grouped by grid connectivity and
  // each group of >= min_segment_points is matched as a view: a part split
  // over segments, or left in pieces, once its neighbours are found
  // (internal::ResidualRegionViews; stage "residual_regions").
  bool residual_regions = true;
  // The residual regions' groups whose grid cells touch across a depth jump
  // are also matched joined, one more view per union (a part whose nearer
  // arm hides part of its own farther surface: a pipe tee's branch in front
  // of its run; internal::ResidualRegionViews).
  bool residual_across_jumps = true;
  // The residual regions' views no class found a detection in are matched
  // once more without the grid's normals: the estimator estimates its own
  // (PCA over each subsampled voxel's neighbours within a PPF step). The
  // grid's normals come from central differences about 2.5 mm away and, on
  // noisy or grazing surfaces, are too rough for point-pair voting; the
  // part's points alone, with the estimator's normals, often find it
  // (internal::NothingFound; stage "residual_regions").
  bool residual_own_normals = true;
  // After the residual regions, a detection of a class that a larger class
  // may enclose (a flanged bushing's hub in a pipe tee's arm) is matched
  // again by the larger class on its samples and the unexplained ones
  // around it; the larger part replaces it when it explains its samples
  // and more (internal::ReplaceEnclosed; stage "enclosing").
  bool enclosing_parts = true;
  // A thorough run (PerceptionEffort::kThorough) tries every class on every
  // view with this wider search; the planner retries with it when a normal
  // run leaves nothing to pick.
  PoseSearch thorough_search{.max_reference_points = 20, .max_coarse_poses = 24, .peaks_per_reference = 2,
                             .peaks_examined = 30, .resting_seeds = true, .keep_better_than_fine = true,
                             .unmeasured_is_no_evidence = true};
  // PoseSearch::turns_below_bar on the classes' default search (the waves,
  // the residual passes, enclosing); second_look_search and thorough_search
  // carry their own. Off: it finds tees standing on their branch but turns
  // about a third of them 5-17 deg off (more gross errors; docs/tuning.md,
  // `turns_below_bar`).
  bool turns_below_bar = false;
};

// Where perception looks, when not into the bin: a box in a frame R (X_BR in
// the base) whose z = 0 plane is the surface the objects rest on (what
// segmentation leaves out as floor, pose seeds rest on and no pose may sink
// into; see `support`). In-hand tasks
// look into a box in the tool frame, fixture tasks into one in the fixture's
// taught frame (TaskSpec::roi). The bin's is the cell's roi in W.
struct PerceptionRegion {
  Pose X_BR = Pose::Identity();
  Eigen::AlignedBox3d box_R;
  // false: nothing rests on z = 0 (a part held by a gripper, free to sit
  // tilted across the cup's lip): no floor band, no support plane.
  bool support = true;
  // Geometry in view that is no part, in R (the gripper at an in_hand
  // capture: its mesh, in the tool frame). ROI points within clear_margin
  // (metres, > 0) of its surface (of surface samples about a third of the
  // margin apart) are dropped before segmentation, so the box may reach
  // past the tool centre point and keep a held part's points beside the cup.
  // Null: nothing dropped.
  std::shared_ptr<const TriangleMesh> clear_mesh_R;
  double clear_margin = 0.003;
};

enum class PerceptionEffort {
  kNormal,
  kThorough,  // see PerceptionOptions::thorough_search; slower
};

// A deadline for the pose stage of a run (the planner's thorough retry,
// Perception::RunThorough). A (view, class) estimate starts only when the
// clock plus the mean duration of the run's estimates so far is at or
// before deadline_ms; the others are skipped and counted
// (PerceptionResult::estimates_skipped). Estimates already running finish,
// so a run overshoots by less than its longest estimate at worst. The
// stages before the pose search (crop, segmentation) always run.
//
// max_estimates > 0 is a budget in work units as well: the run's (view,
// class) estimates are numbered in the order they start (waves, and within
// a wave the views and each view's classes in ranking order) and only the
// first max_estimates are started, whatever the clock; a view's fallback
// classes too small for it (run when its ranked classes find nothing) start
// only when all its ranked ones were within the count. Which estimates run
// is then the same on every machine and at any load; the deadline stays a
// safety cap on top.
struct PerceptionBudget {
  double deadline_ms = 0.0;  // on now_ms's scale
  // Milliseconds since any fixed origin, thread-safe; called twice per
  // estimate. Empty: SteadyClockMs. Tests inject a deterministic clock.
  std::function<double()> now_ms;
  int max_estimates = 0;  // > 0: at most that many estimates start; 0: no count
};
// The steady clock in milliseconds (PerceptionBudget's default clock).
double SteadyClockMs();

// The pose estimator options perception builds every class's estimator
// from (before Perception::Build scales them to the part and camera): the
// PerceptionOptions fields that are the estimator's rules. Diagnostics that
// verify or search a pose by the pipeline's rules (binpick eval --causes)
// start from these too, so the two never drift apart.
PoseEstimatorOptions ReferenceEstimatorOptions(const PerceptionOptions& options);

class Perception {
 public:
  virtual ~Perception() = default;
  // Builds model tables for every part class and every fixture of the cell
  // (slow, once), with the settings scaled to its parts and camera. Every
  // class whose model cannot be built is logged; InvalidArgument naming each
  // of them unless the cell marks the part optional (then it is left out). A
  // mesh in the wrong unit is refused naming the likely unit.
  static Result<std::unique_ptr<Perception>> Build(const Cell& cell, const PerceptionOptions& options = {});
  // The options in use: Build's, scaled to the cell's parts and camera.
  // Implementations that do not segment (TruthPerception, test doubles)
  // keep the defaults.
  virtual const PerceptionOptions& options() const {
    static const PerceptionOptions defaults;
    return defaults;
  }
  // Detects objects of `classes` (part or fixture class ids; empty = all cell
  // parts) in `frame`, inside `region` (nullopt: the bin's roi). Empty ROI,
  // an all-NaN frame or degenerate segments give an OK result with no
  // detections and a reason; never a pose built from NaNs. InvalidArgument
  // for a class that is neither a part nor a fixture of the cell.
  virtual Result<PerceptionResult> Run(const Frame& frame, const std::vector<int>& classes = {},
                                       PerceptionEffort effort = PerceptionEffort::kNormal,
                                       const std::optional<PerceptionRegion>& region = std::nullopt) const = 0;
  // A thorough run (PerceptionEffort::kThorough) within `budget`, its views
  // started most likely to hold a part first: larger waves first, and
  // within a wave the views whose extents fit a class best. The default is
  // Run(frame, classes, kThorough, region) for implementations that do not
  // estimate poses (TruthPerception, test doubles): they finish at once.
  virtual Result<PerceptionResult> RunThorough(const Frame& frame, const std::vector<int>& classes,
                                               const PerceptionBudget& budget,
                                               const std::optional<PerceptionRegion>& region = std::nullopt) const {
    (void)budget;
    return Run(frame, classes, PerceptionEffort::kThorough, region);
  }
};

}  // namespace bp
