// Scoring perception output against ground truth (binpick eval, tests).
//
// Strict matching (docs/perception.md, "How figures are measured"):
// detections, best score first, each take the unmatched ground-truth part of
// the same class whose pose is within the tolerance (translation_tolerance
// metres AND rotation_tolerance radians, both modulo the part's symmetry);
// among several, the one with the smallest error relative to the tolerance.
// A detection matching no part in tolerance is
//   - a gross error when a part of its class has its origin within
//     gross_relative_distance * diameter (near a real part, wrong pose),
//   - a duplicate when that part is within tolerance but already taken,
//   - a false positive otherwise.
// Only true positives count for precision and recall. Recall counts only
// parts with visible_fraction >= min_visible_fraction ("targets"); a true
// positive on a less visible part still counts for precision. Visibility is
// the ground truth's: the part's pixels in the full scene's label render
// divided by its pixels rendered alone from the same camera (before noise).
// ADD-S < adds_relative * diameter is counted over all detections.
#pragma once

#include <array>
#include <functional>
#include <map>
#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/pose.h"

#include "core/cell.h"
#include "core/status.h"
#include "pipeline/frame.h"
#include "pipeline/perception.h"

namespace bp {

struct EvalPartModel {
  int class_id = 0;
  std::string name;
  Symmetry symmetry;
  double diameter = 0.0;                 // metres
  std::vector<Eigen::Vector3f> points_O; // surface samples for ADD-S
};

// Loads every cell part's mesh and samples its surface (seeded, 500 points).
Result<std::vector<EvalPartModel>> LoadEvalModels(const Cell& cell);

// Rotation error modulo symmetry, radians in [0, pi]. Revolute parts compare
// only the axis; discrete parts take the best of the order rotations; extra
// flips combine with either.
double SymmetryAwareRotationError(const Pose& X_BO_a, const Pose& X_BO_b, const Symmetry& symmetry);
// Origin distance after applying the symmetry element that minimises the rotation error.
double SymmetryAwareTranslationError(const Pose& X_BO_a, const Pose& X_BO_b, const Symmetry& symmetry);
// ADD-S: mean over points_O of the distance from X_a p to the nearest X_b q, metres.
double AddSDistance(std::span<const Eigen::Vector3f> points_O, const Pose& X_BO_a, const Pose& X_BO_b);

// Where a tool lands on the true parts. The grasp's point p_O and approach
// a_O (unit; both in the part frame, as planned on the detection) are mapped
// onto every true part of `class_id` under every symmetry element g (revolute
// axes: the best angle, exactly): position error |t(X_BT) - X_BO g p_O| and
// approach error angle(z of X_BT, R_BO g a_O). @returns the part and element
// with the smallest position error + 10 mm per radian of approach error (so a
// copy across a symmetry axis approached from the other side is not chosen for
// being a little nearer); truth_instance -1 when no part of the class is in
// `parts`.
struct GraspLanding {
  int truth_instance = -1;
  double position_error = 0.0;  // metres
  double approach_error = 0.0;  // radians
};
GraspLanding LandOnTruth(const Pose& X_BT, const Vec3& p_O, const Vec3& a_O, int class_id, const Symmetry& symmetry,
                         std::span<const PartTruth> parts);

struct EvalOptions {
  double min_visible_fraction = 0.5;
  // Strict match: 5 mm and 5 deg, the pose error a grasp on a 40-100 mm part
  // tolerates (binpick eval --tol-mm / --tol-deg).
  double translation_tolerance = 0.005;             // metres
  double rotation_tolerance = 5.0 * 3.14159265358979323846 / 180.0;  // radians
  double gross_relative_distance = 0.25;  // of the part's diameter
  double adds_relative = 0.1;
};

enum class DetectionVerdict {
  kTrue,       // within tolerance of an unmatched part of its class
  kGross,      // near a part of its class (origin within a quarter diameter), outside tolerance
  kDuplicate,  // within tolerance of a part another detection already took
  kFalse,      // near no part of its class
};
const char* ToString(DetectionVerdict verdict);  // "true", "gross", "duplicate", "false"

struct DetectionOutcome {
  size_t detection = 0;     // index into PerceptionResult::detections (outcomes are in score order)
  int class_id = 0;
  DetectionVerdict verdict = DetectionVerdict::kFalse;
  int truth_instance = -1;  // matched ground-truth instance (kTrue only), else -1
  int near_instance = -1;   // the part the errors are measured to (kTrue, kGross, kDuplicate), else -1
  bool target = false;      // the matched part is a recall target
  // Errors to near_instance, modulo its symmetry (0 without one).
  double translation_error = 0.0;  // metres
  double rotation_error = 0.0;     // radians
  double adds = 0.0;               // metres
  bool adds_ok = false;
  // Detection::alternatives_X_BO: how many, and (kGross) whether one of them
  // is within tolerance of near_instance: the wrong pose was carried with
  // the right one as an ambiguity, and the planner keeps only grasps that
  // land under both.
  int alternatives = 0;
  bool carried = false;
};

// One handed-out grasp judged against the true scene (grasp/grasp_judge.h
// does the judging; the figures live here so that eval reports them).
struct GraspOutcome {
  int detection = -1;        // the detection it was planned on
  int class_id = 0;
  std::string name;          // the grasp's name (cell grasp, "@k" symmetry copy, "~v" turned)
  Pose X_BT = Pose::Identity();
  int truth_instance = -1;   // the true part whose grasp point is nearest the tool centre
  double position_error = 0.0;  // metres: tool centre to that grasp point (modulo symmetry)
  double approach_error = 0.0;  // radians: tool z to the grasp's approach on that part
  bool on_part = false;         // within the judge's limits (grasp/grasp_judge.h)
  std::string failure;          // "" when on_part, else "no_part", "off_part" or "approach"
};

struct FrameEvaluation {
  std::vector<DetectionOutcome> detections;
  std::map<int, int> targets;        // class -> parts >= min visible
  std::map<int, int> targets_found;  // class -> of those, matched
  std::vector<StageTiming> timings;
  double total_ms = 0.0;
  // The planner's queue for the frame in order (the first is handed out
  // first); empty when grasps were not planned or none survived.
  std::vector<GraspOutcome> grasps;
  bool grasps_planned = false;
};

FrameEvaluation EvaluateFrame(const PerceptionResult& result, const GroundTruth& truth,
                              const std::vector<EvalPartModel>& models, const EvalOptions& options = {});

struct ClassFigures {
  std::string name;  // class name or "all"
  int targets = 0, found = 0, detections = 0, true_positives = 0;
  int gross_errors = 0, duplicates = 0, false_positives = 0;
  int gross_carried = 0;  // gross errors whose true pose is among their alternatives
  double recall = 0, precision = 0;
  double gross_fraction = 0;  // gross errors / detections
  // Over true positives.
  double t_median_mm = 0, t_p95_mm = 0, r_median_deg = 0, r_p95_deg = 0;
  // Over true positives and gross errors (every detection near a part of its
  // class): how far off the detections that are not right are.
  double r_near_p95_deg = 0, r_near_max_deg = 0;
  double adds_ok_fraction = 0;
};
struct GraspFigures {
  int frames = 0;              // frames whose grasps were planned
  int frames_with_grasp = 0;   // of those, with at least one grasp
  int first_on_part = 0;       // first grasps on their part
  int grasps = 0;              // every grasp of every queue
  int on_part = 0;
  std::map<std::string, int> failures;  // cause -> grasps
  double first_fraction = 0;   // first_on_part / frames_with_grasp (1 with none)
  double all_fraction = 0;     // on_part / grasps (1 with none)
};
struct StageFigures {
  std::string stage;
  double median_ms = 0, p95_ms = 0;
};
struct EvalReport {
  int frames = 0;
  std::vector<ClassFigures> classes;  // one per class seen, then "all" last
  std::vector<StageFigures> stages;   // in pipeline order, then "total"
  GraspFigures grasps;
};

// Segmentation against the ground-truth label image (organized synthetic
// frames): a target part is split when its largest segment holds less than
// 80% of its segmented points, merged when that segment gets 20% or more of
// its points from one other part. Frames without labels give zeros.
struct SegmentationFigures {
  int parts = 0;    // targets with at least 50 ROI points
  int split = 0;
  int merged = 0;
  int segments = 0;
};
SegmentationFigures EvaluateSegmentation(const Frame& frame, const PerceptionResult& result, const Cell& cell,
                                         const EvalOptions& options = {});

EvalReport Summarize(const std::vector<FrameEvaluation>& frames, const std::vector<EvalPartModel>& models);

// Causes (binpick eval --causes): why a recall target was missed and what a
// detection matching no part lies on, from the label image (organized
// synthetic frames; before noise).
//
// Each ROI point's true owner: the label of the pixel it projects to (the
// instance id; 0 nothing, GroundTruth::kBinLabel the bin), -1 outside the
// image. Empty without labels.
std::vector<int> RoiPointOwners(const Frame& frame, const PerceptionResult& result);

// How the segmentation cut one part's ROI points.
struct PartCut {
  int points = 0;               // its ROI points
  int unsegmented = 0;          // of those, in no segment (segment -1)
  int segments = 0;             // segments holding any of them
  double largest_share = 0.0;   // the largest such segment's share of its segmented points, [0, 1]
  double largest_purity = 0.0;  // its points' share of that segment, [0, 1]
};
PartCut CutOfPart(int instance_id, std::span<const int> owners, std::span<const int32_t> segment_of_point);

// The first that applies, in this order:
//   kWrongDetection  a detection that is not right sits on it (its support
//                    mostly the part's points, or a gross error near it);
//   kTruthScoresLow  its true pose verified on its own points scores below
//                    `min_score` (no segmentation would have found it);
//   kUnsegmented     more than half its points in no segment;
//   kSplit           its largest segment holds < 80% of its segmented points;
//   kMerged          its points are < 80% of that segment;
//   kNotFound        one clean segment, a true pose scoring the bar: the
//                    search or acceptance lost it.
enum class MissCause { kWrongDetection, kTruthScoresLow, kUnsegmented, kSplit, kMerged, kNotFound };
inline constexpr int kMissCauses = 6;
const char* ToString(MissCause cause);  // "wrong_detection", "truth_low", ...
// truth_score: NaN when not scored (then never kTruthScoresLow).
MissCause ClassifyMiss(const PartCut& cut, bool wrong_detection_on_it, double truth_score, double min_score = 0.6);

// The instance owning most of a detection's support (> 0), or 0 when most of
// it is on no part (nothing, the bin, outside the image).
int SupportOwner(const Detection& detection, std::span<const int> owners);

// A false positive (DetectionVerdict::kFalse) by what its support lies on.
enum class FalseCause {
  kOnOtherClassFound,   // a part of another class that a true detection found
  kOnOtherClassMissed,  // a part of another class no detection found (a bushing in a missed tee)
  kOnItsClass,          // a part of its class, its origin too far for a gross error
  kOnNoPart,            // the bin, the floor, nothing
};
inline constexpr int kFalseCauses = 4;
const char* ToString(FalseCause cause);  // "other_class_found", ...

// One missed target and its cause (the eval's JSON lists them, so that a
// cause can be traced to its frames and parts).
struct MissRecord {
  int frame = 0;  // the frame's index in the run (as --log-level debug names it)
  int instance_id = 0;
  int class_id = 0;
  MissCause cause = MissCause::kNotFound;
};

struct CauseFigures {
  std::map<int, std::array<int, kMissCauses>> misses;          // class -> count per MissCause
  std::map<int, std::array<int, kFalseCauses>> false_positives;  // class -> count per FalseCause
  std::vector<MissRecord> missed;                               // every miss, in frame order
};
// Adds one frame's misses and false positives. truth_score(part, own points)
// verifies the true pose on the part's own ROI points (NaN: not scored).
// frame_index: the frame's index in the run, for MissRecord::frame.
void AddFrameCauses(const Frame& frame, const PerceptionResult& result, const FrameEvaluation& fe,
                    const std::function<double(const PartTruth&, const std::vector<Eigen::Vector3f>&)>& truth_score,
                    CauseFigures& figures, const EvalOptions& options = {}, int frame_index = 0);


}  // namespace bp
