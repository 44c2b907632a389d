// Scoring perception output against ground truth (binpick eval, tests).
//
// Matching: detections, best score first, each take the nearest unmatched
// ground-truth part of the same class whose origin is within
// match_relative_distance * diameter. Recall counts only parts with
// visible_fraction >= min_visible_fraction ("targets"); a detection matched to
// a less visible part is still a true positive for precision. Errors are over
// matched detections, modulo the part's symmetry. ADD-S < adds_relative *
// diameter is counted over all detections (unmatched ones fail).
#pragma once

#include <map>
#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>

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

struct EvalOptions {
  double min_visible_fraction = 0.5;
  double match_relative_distance = 0.25;
  double adds_relative = 0.1;
};

struct DetectionOutcome {
  size_t detection = 0;     // index into PerceptionResult::detections (outcomes are in score order)
  int class_id = 0;
  int truth_instance = -1;  // matched ground-truth instance, -1 = false positive
  bool target = false;      // the matched part is a recall target
  double translation_error = 0.0;  // metres (matched only)
  double rotation_error = 0.0;     // radians (matched only)
  double adds = 0.0;               // metres (matched only)
  bool adds_ok = false;
};

struct FrameEvaluation {
  std::vector<DetectionOutcome> detections;
  std::map<int, int> targets;        // class -> parts >= min visible
  std::map<int, int> targets_found;  // class -> of those, matched
  std::vector<StageTiming> timings;
  double total_ms = 0.0;
};

FrameEvaluation EvaluateFrame(const PerceptionResult& result, const GroundTruth& truth,
                              const std::vector<EvalPartModel>& models, const EvalOptions& options = {});

struct ClassFigures {
  std::string name;  // class name or "all"
  int targets = 0, found = 0, detections = 0, true_positives = 0;
  double recall = 0, precision = 0;
  double t_median_mm = 0, t_p95_mm = 0, r_median_deg = 0, r_p95_deg = 0;
  double adds_ok_fraction = 0;
};
struct StageFigures {
  std::string stage;
  double median_ms = 0, p95_ms = 0;
};
struct EvalReport {
  int frames = 0;
  std::vector<ClassFigures> classes;  // one per class seen, then "all" last
  std::vector<StageFigures> stages;   // in pipeline order, then "total"
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

}  // namespace bp
