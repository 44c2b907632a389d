// 6-DoF pose estimation of one CAD part in a scene view: point-pair-feature
// voting (Drost et al. 2010) for coarse poses, point-to-plane ICP refinement,
// and render-free verification (visible-surface support, free-space penalty).
// See docs/perception.md.
//
// Frames: B robot base (the scene), O part (the model mesh), C camera.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>  // core/mesh.h uses AlignedBox3f / Affine3f

#include "core/cell.h"
#include "core/image.h"
#include "core/mesh.h"
#include "core/pose.h"
#include "core/status.h"

namespace bp {

namespace internal {
class PoseEstimatorAccess;  // perception's reuse of an estimate (internal/pose_search.h)
}  // namespace internal

// Distances in metres. Defaults were chosen on the shipped parts
// (docs/tuning.md has the figure behind each and its command).
struct PoseEstimatorOptions {
  // --- model tables (built once by Build) ---
  // PPF sampling distance relative to the model diameter, in (0.005, 0.2]
  // (Drost's tau_d and default).
  double ppf_relative_sampling = 0.05;
  // Angle quantisation of the point pair feature, degrees in [3, 45].
  double ppf_angle_step_deg = 12.0;
  // Table buckets keep at most this many model pairs (>= 1): bounds the
  // voting cost; fuller buckets let a touching part's votes drown the other's
  // (docs/tuning.md).
  int ppf_max_bucket_entries = 50;
  // Spacing of the dense model samples ICP and the closest-point field
  // use (> 0), metres; coarser samples lose recall (docs/tuning.md).
  double icp_model_spacing = 0.0008;
  // Spacing of the model samples verification uses (> 0), metres; denser
  // samples cost time for no gain (docs/tuning.md).
  double verify_model_spacing = 0.003;

  // --- coarse stage ---
  // Fraction of the subsampled scene points used as reference points, in
  // (0, 1], and a cap (>= 1; PoseSearch sets the cap per search).
  double reference_fraction = 0.2;
  int max_reference_points = 20;
  // Each reference point pairs with at most this many of the subsampled
  // points within the model's diameter of it (strided; >= 1).
  int ppf_max_partners = 100;
  // Pose clustering: translation relative to the diameter, rotation (deg).
  double cluster_relative_translation = 0.1;
  double cluster_rotation_deg = 24.0;
  // Coarse poses refined and verified per view (>= 1).
  int max_coarse_poses = 4;
  // The first ICP pass stops at the first coarse pose that scores at least
  // this at a quick look and explains the view, in [0, 1]; 0 = refine all.
  double coarse_stop_score = 0.9;

  // --- refinement ---
  // Fine-pass ICP iterations (>= 1); most stop early.
  int icp_iterations = 30;
  // Coarse-pass ICP iterations (>= 1): most coarse poses are wrong and run
  // all of them, so the fewest that keep recall (docs/tuning.md).
  int icp_coarse_iterations = 5;
  // The fine pass uses at most this many view points (strided, >= 100);
  // 800 left touching parts 1 mm off.
  int icp_max_points = 1500;
  // Correspondence gate of the first iteration, relative to the PPF
  // sampling distance, shrinking to icp_final_distance (metres); both > 0.
  double icp_initial_relative_distance = 1.5;
  double icp_final_distance = 0.002;
  // A pass stops once an iteration changes the residuals by less than this
  // RMS (> 0): the fine pass, and the coarse pass the fine pass refines again.
  double icp_convergence = 5e-5;
  double icp_coarse_convergence = 2e-4;
  // Iterations over which the gate shrinks to its final distance, in both
  // passes (>= 1); no pass stops before it.
  int icp_shrink_iterations = 3;

  // --- verification ---
  // A visible model point is supported by a view point within this (> 0).
  double support_distance = 0.0015;
  // Model points must face the camera by at least this cosine, in [0, 1),
  // to count as visible.
  double visible_min_cos = 0.2;
  // Depth image only: a model point closer to the camera than the measured
  // surface by more than this lies in free space (evidence against, times
  // free_space_weight); farther by more than this it is occluded (none).
  double free_space_distance = 0.003;
  double free_space_weight = 1.0;
  // Poses that sink the part deeper than this below SceneView::support_plane_B
  // are rejected.
  double max_support_penetration = 0.003;
  // Hypotheses below this score are rejected, in [0, 1]; without a depth
  // image occlusion by anything outside the view counts against the part,
  // hence the lower bar.
  double min_score = 0.6;
  double min_score_without_depth = 0.35;
  // The first pass screens each refined coarse pose on every
  // quick_screen_stride-th sample (>= 1) and drops it below
  // quick_screen_min_score (in [0, 1], never above the pass's own bar).
  int quick_screen_stride = 12;
  double quick_screen_min_score = 0.3;
  // Hypotheses need at least this many visible, not occluded model points.
  int min_visible_points = 20;
  // Two hypotheses are one part when their centres are closer than this
  // fraction of the diameter (the lower score is dropped).
  double nms_relative_distance = 0.3;
  // At most this many hypotheses per view (>= 1).
  int max_hypotheses = 4;
  // Near symmetries (near_symmetries()): transforms of O that map at least
  // this fraction, in [0, 1], of the surface onto itself; at most this many
  // (0 = none); a turn replaces a hypothesis scoring at most the slack more.
  double near_symmetry_min_overlap = 0.35;
  int max_near_symmetries = 4;
  double near_symmetry_score_slack = 0.02;
  // Also candidates: the half-turns that swap two arms (two large faces with
  // near-perpendicular normals whose normal lines meet behind both: a tee's
  // run end and branch end). A tee seen as an L, one arm hidden, fits with
  // its branch on either seen arm.
  bool arm_swaps = true;
  // A view is one plane (face seeds, PoseSearch::face_seeds) when its
  // points' RMS distance from their plane is below 1 mm; or, with this
  // share in (0, 1], when that share of them lies within 1.5 mm of a plane
  // fitted to them by trimmed least squares, the rest left out of the
  // seeds' outline: a thin plate seen edge-on at a coarse pixel pitch (an
  // L-bracket's side face, 2-4 pixels wide) keeps mixed pixels and a
  // grazing face's scraps along its outline that a least-squares plane
  // leans to. 0 = the RMS test alone.
  double planar_view_min_share = 0.0;
  // The default search's PoseSearch::unmeasured_is_no_evidence (Estimate
  // without a search). Direct users keep false; perception hands it
  // PerceptionOptions::unmeasured_is_no_evidence.
  bool unmeasured_is_no_evidence = false;
  // The default search's PoseSearch::turns_below_bar. Direct users keep
  // false; perception hands it PerceptionOptions::turns_below_bar.
  bool turns_below_bar = false;
  // Turn axes (turn_axes()): axes the part is nearly round about, found at
  // multiples of this step (degrees, in [0, 180]; 0 = none). Each final
  // hypothesis is also tried turned about them by every multiple, then
  // bisected to an eighth of the step around the best turn.
  double turn_step_deg = 30.0;
  // Pose ambiguity (PoseHypothesis::alternatives): a turned or competing
  // pose more than ambiguity_translation (metres) or ambiguity_rotation_deg
  // from the hypothesis (modulo symmetry; the strict evaluation tolerance)
  // whose supported minus free-space samples are within ambiguity_slack (a
  // fraction, in [0, 1)) of the hypothesis's explains the view as well; at
  // most max_alternatives (>= 0; 0 = ambiguity not sought).
  double ambiguity_translation = 0.005;
  double ambiguity_rotation_deg = 5.0;
  double ambiguity_slack = 0.05;
  int max_alternatives = 4;
  // An alternative that explains more than (1 + ambiguity_net_gain) times
  // what the hypothesis does (supported minus free-space samples, verified
  // in full) and passes verification becomes the hypothesis, the hypothesis
  // an alternative (>= 0; 0 = off): the hypothesis won on score, which a
  // turn hiding more of the part (a tee's branch behind its run) raises.
  double ambiguity_net_gain = 0.06;
  // Filled holes (depth image only): points of a large face's plane that the
  // face encloses, at least hole_margin (> 0) from it, are holes; with >=
  // hole_min_visible in view and more than hole_max_filled of them showing
  // the view's surface through the hole, the pose is rejected (>= 1: off).
  double hole_margin = 0.0015;
  int hole_min_visible = 8;
  double hole_max_filled = 0.5;

  // Returns false with a message if a value is out of range.
  bool IsValid(std::string* error) const;
};

// What the estimator sees of one segment. Spans must outlive the call.
struct SceneView {
  // Segment points in B (metres). Non-finite points are ignored.
  std::span<const Eigen::Vector3f> points_B;
  // Optional normals in B, one per point (any orientation); estimated when empty.
  std::span<const Eigen::Vector3f> normals_B;
  // Camera pose in B; its translation is the viewpoint for visibility.
  Pose X_BC = Pose::Identity();
  // Optional organized depth image (metres along z of C, NaN = invalid) with
  // its intrinsics, for the free-space / occlusion test. Null = none.
  const DepthImage* depth = nullptr;
  Intrinsics intrinsics;
  // Optional support plane in B (e.g. the bin floor): (n, d) with unit normal n
  // pointing to the side where parts are, n . x + d = 0 on the plane. Poses
  // that sink the part more than max_support_penetration below it are
  // rejected: a part's visible face lying flush with the floor explains a
  // floor patch perfectly, and only this physical constraint rules it out.
  std::optional<Eigen::Vector4d> support_plane_B;
};

// How wide the coarse search is. Estimate(view) takes these from the options;
// a caller retrying a view that gave nothing can ask for more.
struct PoseSearch {
  int max_reference_points = 20;
  int max_coarse_poses = 4;
  // With a support plane: per reference point, the best peaks_examined
  // accumulator peaks are tried in order and the first peaks_per_reference
  // poses that do not sink the part into the plane are kept.
  int peaks_per_reference = 1;
  int peaks_examined = 8;
  // With a support plane: also the part lying on it in each resting
  // orientation, centred on the view's top (the last parts of a bin, in
  // views PPF voting cannot resolve). Thorough search only.
  bool resting_seeds = false;
  // A hypothesis the fine pass leaves below 0.9 is also verified at its
  // pre-fine pose and the better kept (weakly constrained views). Costs
  // precision on normal runs: thorough search only.
  bool keep_better_than_fine = false;
  // Depth image only: a visible model point on a grazing face (more than 60
  // deg off the line of sight) over a pixel without depth is no evidence
  // (left out of the score's denominator). Perception sets it on every
  // search (PerceptionOptions::unmeasured_is_no_evidence: grazing dropout
  // leaves true poses below the bar otherwise; docs/tuning.md).
  bool unmeasured_is_no_evidence = false;
  // A fine-pass pose of a part with turn axes (PoseModel::turn_axes) that
  // scores below the bar is turned about them (the same turn grid as a
  // passing pose) before it is rejected: a part nearly round about an axis
  // (a pipe tee about its run) is seen as that round body, and a coarse pose
  // turned the wrong way puts its branch where the camera saw nothing.
  bool turns_below_bar = false;
  // A view that is one plane also gets this many face seeds (the part with
  // one of its large planar faces on the view's plane); 0 = none.
  int face_seeds = 2;
  // Also try each verified hypothesis turned by the model's near
  // symmetries; keep the turn when it explains more of the view.
  bool near_symmetries = true;
  // The first ICP pass stops at the first coarse pose or seed that scores
  // at least this at a quick look and explains the view, in [0, 1]; 0 =
  // every one is refined (PoseEstimatorOptions::coarse_stop_score).
  double stop_score = 0.0;

  // Counts >= 1, peaks_examined >= peaks_per_reference, stop_score in [0, 1].
  bool IsValid() const {
    return max_reference_points >= 1 && max_coarse_poses >= 1 && peaks_per_reference >= 1 &&
           peaks_examined >= peaks_per_reference && stop_score >= 0.0 && stop_score <= 1.0;
  }
};

struct PoseTimings {
  double prepare_ms = 0;  // subsampling, normals
  double coarse_ms = 0;   // PPF voting + clustering
  double refine_ms = 0;   // ICP
  double verify_ms = 0;   // visibility, scoring, NMS
};

struct PoseHypothesis {
  Pose X_BO = Pose::Identity();
  // (supported - free_space_weight * free_space) / (visible - occluded), and
  // also minus unmeasured in the denominator with PoseSearch::unmeasured_is_no_evidence.
  double score = 0;
  int visible_points = 0;    // verification model points facing the camera, not self-occluded
  int occluded_points = 0;   // of those, behind the measured surface (depth image only)
  int supported_points = 0;  // of those, with a scene point within support_distance
  int free_space_points = 0; // of those, in front of the measured surface (depth image only)
  int unmeasured_points = 0; // of those, on a grazing face over a pixel without depth (see PoseSearch)
  int hole_points = 0;        // hole points in view (PoseEstimatorOptions::hole_max_filled)
  int filled_hole_points = 0; // of those, where the measured surface goes on through the hole
  double rms_residual = 0;   // ICP point-to-plane RMS over supporting points, metres
  int coarse_votes = 0;      // summed PPF votes of the cluster this came from
  // Other poses of the part, each beyond the ambiguity tolerance of X_BO and
  // of each other, that explain the view about as well
  // (PoseEstimatorOptions::ambiguity_slack): the view cannot tell them
  // apart from X_BO (a tee turned about its run with the branch hidden).
  // Empty: the pose is unambiguous.
  std::vector<Pose> alternatives;
  // Indices into SceneView::points_B of the points within support_distance.
  std::vector<int> supporting_indices;
};

struct PoseEstimates {
  std::vector<PoseHypothesis> hypotheses;  // best first; may be empty
  std::string no_result_reason;            // why hypotheses is empty
  PoseTimings timings;
  int scene_points = 0;       // finite input points
  int sampled_points = 0;     // after subsampling
  int coarse_refined = 0;     // coarse poses and seeds refined by the first ICP pass
  int screened_out = 0;       // of those, rejected by the quick screen
};

class PoseEstimator {
 public:
  // Samples the model and builds the PPF table and the ICP lookup (tens to
  // hundreds of ms per part). @returns InvalidArgument for an empty or
  // degenerate mesh or invalid options.
  static Result<std::unique_ptr<PoseEstimator>> Build(const TriangleMesh& mesh, const Symmetry& symmetry,
                                                      const PoseEstimatorOptions& options = {});
  ~PoseEstimator();
  PoseEstimator(const PoseEstimator&) = delete;
  PoseEstimator& operator=(const PoseEstimator&) = delete;

  // Thread-safe (const, no shared mutable state): callers may run segments
  // concurrently. A degenerate segment (too few finite points, collinear, ...)
  // gives no hypothesis and a reason, never an error. Errors only for misuse
  // (normals_B of a different size than points_B).
  Result<PoseEstimates> Estimate(const SceneView& view) const;
  // The same with the coarse search's width given (counts >= 1,
  // peaks_examined >= peaks_per_reference; else InvalidArgument).
  Result<PoseEstimates> Estimate(const SceneView& view, const PoseSearch& search) const;
  // The search Estimate(view) runs: the options' counts and coarse_stop_score.
  PoseSearch default_search() const;
  // Verification alone of a given pose against the view (no search, no
  // refinement): the score and counts Estimate(view) gives a hypothesis at
  // X_BO (its default search's unmeasured_is_no_evidence). For diagnostics,
  // e.g. how the true pose of a missed part scores.
  Result<PoseHypothesis> Score(const SceneView& view, const Pose& X_BO) const;

  // Sets (*on_surface)[i] = 1 for the points_B within `tolerance` (metres)
  // of the part's surface at X_BO, as the closest-point field sees it (the
  // sample nearest the point's voxel: a point near a voxel's edge can be
  // missed, never one farther away taken); leaves the others as they are.
  void MarkOnSurface(const Pose& X_BO, std::span<const Eigen::Vector3f> points_B, float tolerance,
                     std::vector<uint8_t>* on_surface) const;

  // How many of points_B lie inside the part's material at X_BO, at least
  // min_depth (metres) behind its surface: the dense sample the closest-point
  // field holds for the point's voxel (1 mm voxels, within the field's band of
  // a few millimetres) has its outward normal pointing away from the point.
  // Points deeper than the band are not counted, so min_depth must stay below
  // half the thinnest wall.
  size_t CountInside(const Pose& X_BO, std::span<const Eigen::Vector3f> points_B, float min_depth) const;

  double diameter() const;         // metres, of the sampled model
  double sampling_distance() const;  // PPF sampling distance, metres
  int model_point_count() const;   // PPF model points
  // Model surface samples in O (verification spacing), e.g. for ADD-S.
  const std::vector<Eigen::Vector3f>& surface_points_O() const;
  // Centroid of the model surface in O.
  Eigen::Vector3f centroid_O() const;
  const Symmetry& symmetry() const;
  // The near symmetries found (transforms of O, see
  // PoseEstimatorOptions::near_symmetry_min_overlap), most overlap first.
  const std::vector<Pose>& near_symmetries() const;
  // The axes the part is nearly round about (PoseEstimatorOptions::
  // turn_step_deg), each as a point on it and a unit direction in O.
  std::vector<std::pair<Eigen::Vector3f, Eigen::Vector3f>> turn_axes() const;

 private:
  friend class internal::PoseEstimatorAccess;
  struct Impl;
  explicit PoseEstimator(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// Rotation error between two part poses modulo the part's symmetry, radians in
// [0, pi]: revolute parts compare only the axis direction; discrete parts take
// the smallest error over the 'order' rotations; 'extra' flips are combined
// with either.
double SymmetricRotationError(const Pose& X_BO_a, const Pose& X_BO_b, const Symmetry& symmetry);
// Translation error of the part origin, metres, modulo symmetry (the symmetry
// element that minimises the rotation error is applied; the axis passes
// through the origin so only 'extra' flips with a translation change it).
double SymmetricTranslationError(const Pose& X_BO_a, const Pose& X_BO_b, const Symmetry& symmetry);
// ADD-S: mean over model points p of min_q |X_a p - X_b q|, metres. Valid for
// any symmetry (it needs none). points_O e.g. PoseEstimator::surface_points_O().
double AddS(std::span<const Eigen::Vector3f> points_O, const Pose& X_BO_a, const Pose& X_BO_b);

}  // namespace bp
