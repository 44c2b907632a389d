// 6-DoF pose estimation of one CAD part in a scene segment: point-pair-feature
// voting (Drost et al. 2010) for coarse poses, point-to-plane ICP refinement,
// and render-free verification (visible-surface support, free-space penalty).
// See docs/perception.md for the design and the measured figures.
//
// Frames: B robot base (the scene), O part (the model mesh), C camera.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
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

struct PoseEstimatorOptions {
  // --- model tables (built once by Build) ---
  // PPF sampling distance relative to the model diameter (Drost's tau_d).
  double ppf_relative_sampling = 0.05;
  // Alpha / normal angle quantisation of the point pair feature, degrees.
  double ppf_angle_step_deg = 12.0;
  // Table buckets (one per quantised feature) keep at most this many model
  // pairs; bounds the voting cost (see internal/ppf_matcher.h).
  int ppf_max_bucket_entries = 50;
  // Spacing of the dense model samples used by ICP, metres.
  double icp_model_spacing = 0.0008;
  // Spacing of the model samples used by verification, metres. Measured
  // against 2 mm (`binpick eval --scenes 30`, seeds 11 / 41, and 10 scenes
  // seed 1): recall 0.886 / 0.864 / 0.877 against 0.882 / 0.874 / 0.877,
  // precision 0.968 / 0.971 / 0.994 against 0.962 / 0.969 / 0.981, total
  // median 84 / 86 / 85 ms against 94 / 95 / 90.
  double verify_model_spacing = 0.003;

  // --- coarse stage ---
  // Fraction of the subsampled scene points used as reference points, and a cap.
  double reference_fraction = 0.2;
  int max_reference_points = 20;
  // Each reference point pairs with at most about this many subsampled scene
  // points (strided). Measured (`binpick eval`, seeds 1-10 / 11-40 / 41-70):
  // with 250 recall 0.933 / 0.942 / 0.936 against 0.926 / 0.938 / 0.934 with
  // every point, the same precision, the coarse stage 0.56 instead of 0.86 ms
  // per estimate (large segments have 300-500 subsampled points). Now the
  // partners are strided among the points within the model's diameter of
  // the reference point (the others make no pair in the table), at most
  // 100 (all 130 scenes of docs/perception_pipeline.md, with the fit
  // residual limit): recall 0.9486 -> 0.9505, precision 0.9870 -> 0.9875
  // against 250 strided over the whole view (100 strided so: 0.9505 /
  // 0.9862; 150 in range: 0.9515 / 0.9870); `BM_PerceptionRun` 640x480
  // 66.5 -> 61.8 ms, CPU 115 -> 105 ms per frame, in one session.
  int ppf_max_partners = 100;
  // Pose clustering thresholds: translation relative to the diameter, rotation.
  double cluster_relative_translation = 0.1;
  double cluster_rotation_deg = 24.0;
  // Clusters (coarse poses) refined and verified per segment.
  int max_coarse_poses = 4;
  // The first ICP pass takes the coarse poses (then the seeds) in order and
  // stops at the first that passes the quick verification with at least
  // this score (PoseSearch::stop_score of Estimate(view)); 0 = every one is
  // refined. Most views show one part, and the poses after a good one
  // converge to it or fail. Measured (`binpick --log-level debug eval
  // --scenes 40 --seed 1`): first-pass ICPs 9892 -> 8137 (-17.7%); all 130
  // scenes of docs/perception_pipeline.md recall 2002 -> 2003 / 2101,
  // precision 2221 / 2239 -> 2220 / 2236; held out unchanged. 0.8 lost
  // held-out parts (recall 0.950 -> 0.944).
  double coarse_stop_score = 0.9;

  // --- refinement ---
  // Fine ICP iterations, most stop early.
  int icp_iterations = 30;
  // Coarse-pass ICP iterations (most coarse poses run all of them: they are
  // wrong, and the quick verification after the pass drops them). Was
  // max(4, icp_iterations / 4) = 7. Measured with icp_shrink_iterations 3
  // (2026-12-03): 5 gives `BM_PerceptionRun` 640x480 87.7 -> 82.0 ms, CPU
  // 153 -> 144 ms per frame (interleaved; 1920x1200 107.6 -> 107.2 ms), all
  // 130 scenes recall 2003 -> 2002 / 2101, the same 2221 / 2239 true
  // positives, held out the same (439 / 462, 490 / 494); 6: 2002, 2220 /
  // 2240; 4: 1999, 2220 / 2241.
  int icp_coarse_iterations = 5;
  // The fine ICP pass uses at most this many segment points (strided). 800
  // was 3-5 ms faster per frame, but two touching brackets came out 1.01 mm off
  // and a standing one 2.07 mm off (the tests' 1 mm and 2 mm).
  int icp_max_points = 1500;
  // Correspondence distance at the first ICP iteration (relative to the PPF
  // sampling distance), shrinking to icp_final_distance.
  double icp_initial_relative_distance = 1.5;
  double icp_final_distance = 0.002;
  // A pass stops once an iteration changes the residuals by less than this
  // RMS, metres (IcpOptions::convergence): the fine pass, and the coarse pass
  // whose result the fine pass refines again. Both were 20 um. Measured on
  // all 130 scenes of docs/perception_pipeline.md "Measured" (2026-12-03):
  // fine 50 um: fine-pass point-iterations -15% (seeds 1-10), recall 0.9524
  // -> 0.9529, precision 0.9924 -> 0.9920 (held out 0.946 / 0.990); and
  // coarse 200 um: coarse-pass point-iterations -24%, the same recall and
  // false positives (one true positive fewer among the detections; held out
  // 0.944 / 0.990, one part fewer); median errors 0.042-0.050 mm,
  // 0.056-0.063 deg either way. 100 um fine lost two parts on seeds 1-10.
  double icp_convergence = 5e-5;
  double icp_coarse_convergence = 2e-4;
  // Iterations over which the gate shrinks to its final distance, in both
  // passes (IcpOptions::shrink_iterations); no pass stops before it. Was
  // min(iterations / 3, 6): 2 for the coarse pass (7 iterations), 6 for the
  // fine. Measured on all 130 scenes (2026-12-03): recall 2002 -> 2003 / 2101,
  // precision 2225 / 2243 -> 2221 / 2239 (0.9920 both), held out 0.944 /
  // 0.990 -> 0.950 / 0.992; 3 for the fine pass alone: 2001, 0.9906, held out
  // 0.946; for the coarse pass alone: 2002, 0.9920, held out 0.948 / 0.986;
  // 2 for the fine pass: 2001, 0.9915; 4: 2002, 0.9915, held out 0.944.
  int icp_shrink_iterations = 3;

  // --- verification ---
  // A visible model point is supported by a scene point within this distance.
  double support_distance = 0.0015;
  // Model points must face the camera by at least this cosine to count as visible.
  double visible_min_cos = 0.2;
  // Depth image only: a model point closer to the camera than the measured
  // surface by more than this lies in free space (evidence against);
  // farther by more than this it is occluded (no evidence).
  double free_space_distance = 0.003;
  double free_space_weight = 1.0;
  // See SceneView::support_plane_B, metres.
  double max_support_penetration = 0.003;
  // Hypotheses below this score are rejected. With a depth image, occluded
  // model points are recognised and excluded, so true detections score high
  // (>= 0.63 on the synthetic default cell, the worst wrong one 0.57);
  // without one, occlusion by anything outside the segment counts against
  // the part, hence the lower bar.
  double min_score = 0.6;
  double min_score_without_depth = 0.35;
  // The first pass verifies each refined coarse pose on every 3rd model
  // sample and keeps those scoring at least 0.6 * min_score. Before that, a
  // screen on every quick_screen_stride-th sample rejects a pose scoring
  // below quick_screen_min_score, or below the pass's own bar when that is
  // lower (no depth image: 0.6 * min_score_without_depth); 0 = no screen. Measured (2026-12-04, all
  // 130 scenes and the held-out 30 of docs/perception_pipeline.md): 12 /
  // 0.3 gives every detection as without the screen, callgrind instructions
  // of `PerceptionImpl::Run` 495.7 -> 472.8 M per frame; every 16th or 24th
  // sample changed detections (24: recall 2003 -> 2002 / 2101).
  int quick_screen_stride = 12;
  double quick_screen_min_score = 0.3;
  // Hypotheses need at least this many visible model points.
  int min_visible_points = 20;
  // Two hypotheses are one physical part when their centres are closer than
  // this fraction of the diameter (the lower score is dropped).
  double nms_relative_distance = 0.3;
  // At most this many hypotheses per segment (sorted by score).
  int max_hypotheses = 4;
  // Near symmetries (not symmetries of the part, but transforms F of O that
  // map at least this fraction of its surface onto its surface: an L-bracket
  // turned over about its upright, whose base is then hidden under it, looks
  // the same from above but for the upright's hole). Candidates are the 180
  // deg turns about each large planar face's normal through its centre and
  // about each plate's in-plane axes through its mid-plane; the
  // max_near_symmetries that keep the most surface are kept, none that the
  // part's declared symmetry already covers. Each verified hypothesis is
  // also refined and verified at X_BO * F (PoseSearch::near_symmetries); the
  // turn replaces it when it explains more of the view (supported minus
  // free-space model points) and scores at most near_symmetry_score_slack
  // lower. The default cell finds one for the bushing (upside down), four
  // for the L-bracket, one for the tee (about its run pipe). Measured
  // (`binpick eval`, 10 scenes seed 1, 30 scenes seeds 11 / 41 / 71 / 101):
  // recall 0.951 / 0.950 / 0.957 / 0.944 / 0.943 against 0.951 / 0.950 /
  // 0.955 / 0.938 / 0.933 without, precision 0.988 / 0.981 / 0.990 / 0.980
  // / 0.984 against 0.988 / 0.979 / 0.987 / 0.976 / 0.973. Keeping the
  // better score instead gave recall 0.939 / 0.952 / 0.949, precision 0.977
  // / 0.981 / 0.983 on the first three: the turn that hides more of the
  // part scores higher.
  // max_near_symmetries = 0: none.
  double near_symmetry_min_overlap = 0.35;
  int max_near_symmetries = 4;
  double near_symmetry_score_slack = 0.02;
  // Filled holes (depth image only). Points of a large planar face's plane
  // that the face encloses but does not cover (a bushing's bore, a
  // bracket's holes, a pipe's opening), at least hole_margin from the face,
  // are the part's holes. Where a visible hole point's pixel measures a
  // surface at the hole point's depth (within support_distance) that is not
  // the part's own surface (farther than hole_margin from it), the view's
  // surface goes on through where the part has a hole: a flange fitted
  // into a larger plate. A hypothesis with at least hole_min_visible such
  // points in view, more than hole_max_filled of them filled, is rejected.
  // hole_max_filled >= 1: off.
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
// a caller retrying a segment that gave nothing can ask for more.
struct PoseSearch {
  int max_reference_points = 20;
  int max_coarse_poses = 4;
  // With a support plane: per reference point, the best peaks_examined
  // accumulator peaks are tried in order and the first peaks_per_reference
  // poses that do not sink the part into the plane are kept.
  int peaks_per_reference = 1;
  int peaks_examined = 8;
  // With a support plane: also try the part lying on the plane in each of
  // its resting orientations (faces on its convex hull that hold its centre
  // above them), at 10 deg steps of yaw plus the two yaws that align its
  // top-view principal axis with the segment's, its top over the segment's
  // top, plus tilted copies when the segment's upward faces tilt. These
  // seeds go to ICP and verification with the coarse poses. For the last
  // parts of a bin, which lie on the floor in views PPF voting cannot
  // resolve: an L-bracket on its side shows only its 5 mm edges.
  bool resting_seeds = false;
  // Point-to-plane ICP can slide a part whose view constrains it weakly (an
  // L-bracket on its side shows only 5 mm plate edges) out of the position
  // the coarse pass found. With this, a hypothesis the fine pass leaves below
  // 0.9 is also verified in full at its pose before the fine pass, and the
  // better of the two is kept. Measured: on 36 L-brackets lying on their
  // side or standing, 6 not found instead of 12; on normal runs it cost
  // precision (0.949 instead of 0.961 on 30 piles), so only the thorough
  // search sets it.
  bool keep_better_than_fine = false;
  // With a depth image: a visible model point on a grazing face (more than
  // 60 deg off the line of sight) whose pixel has no measurement and that no
  // scene point supports is no evidence either way; it leaves the score's
  // denominator like an occluded one. A depth camera drops such pixels: an
  // L-bracket lying on its side, alone in the bin, scored 0.69 at its true
  // pose (177 of its 625 visible points unmeasured) and 0.94 with this. On
  // piles it let more wrong poses through (precision 0.959 instead of 0.968
  // on 30 piles, seeds 11-40), so only the thorough search sets it.
  bool unmeasured_is_no_evidence = false;
  // A view that is one plane (an L-bracket's plate: a segment of coplanar
  // points, on which point pair features tie between every placement of the
  // part's flat faces) also gets face seeds: the part with each of its large
  // planar faces on the view's plane, the face's principal axis along the
  // view's principal axis or one of its longest hull edges, its box holding
  // the view's (docs/perception.md, "Face seeds"). The best this many by a
  // quick verification go on with the coarse poses. 0 = none.
  int face_seeds = 2;
  // Also try each verified hypothesis turned by the model's near symmetries
  // (PoseEstimatorOptions::near_symmetry_min_overlap) and keep the better.
  bool near_symmetries = true;
  // The first ICP pass stops at the first coarse pose or seed that passes
  // the quick verification with at least this score (in [0, 1]; 0 = every
  // one is refined; PoseEstimatorOptions::coarse_stop_score).
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
  // refinement): the score and counts Estimate gives a hypothesis at X_BO.
  // For diagnostics, e.g. how the true pose of a missed part scores.
  Result<PoseHypothesis> Score(const SceneView& view, const Pose& X_BO) const;

  // Sets (*on_surface)[i] = 1 for the points_B within `tolerance` (metres)
  // of the part's surface at X_BO, as the closest-point field sees it (the
  // sample nearest the point's voxel: a point near a voxel's edge can be
  // missed, never one farther away taken); leaves the others as they are.
  void MarkOnSurface(const Pose& X_BO, std::span<const Eigen::Vector3f> points_B, float tolerance,
                     std::vector<uint8_t>* on_surface) const;

  // How many of points_B lie inside the part's material at X_BO, at least
  // min_depth (metres) behind its surface: the dense model sample nearest
  // the point's voxel of the closest-point field (1 mm voxels, within the
  // field's band, a few millimetres) has its outward normal pointing away
  // from the point. Points deeper than the band are not counted, so
  // min_depth must stay below half the thinnest wall.
  // The voxel's sample, not the 8-voxel search for the nearest: 43.1 ->
  // 26.4 M instructions over 4 frames, the same detections on all 130 eval
  // scenes and the held-out 30 (docs/perception_pipeline.md, stage `verify`).
  // Two parts of one pile never interpenetrate; two detections that do
  // cannot both be right.
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
