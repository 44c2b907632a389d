// The strict evaluation rule (pipeline/evaluation.h): true positives within
// the pose tolerance modulo symmetry, gross errors near a part in the wrong
// pose, duplicates and false positives apart; and where a tool lands on the
// true parts (LandOnTruth), modulo symmetry.
#include "pipeline/evaluation.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <numeric>
#include <random>

namespace bp {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;
constexpr int kBushing = 0, kBracket = 1, kTee = 2;

Pose Rotated(const Vec3& t, const Vec3& axis, double deg) {
  return MakePose(Mat3(Eigen::AngleAxisd(deg * kDeg, axis.normalized())), t);
}

const std::vector<EvalPartModel>& Models() {
  static const std::vector<EvalPartModel> models = [] {
    auto cell = LoadDefaultCell();
    EXPECT_TRUE(cell.ok()) << cell.status().ToString();
    auto m = LoadEvalModels(*cell);
    EXPECT_TRUE(m.ok()) << m.status().ToString();
    return *m;
  }();
  return models;
}

PartTruth Truth(int instance, int class_id, const Pose& X_BO, double visible = 1.0) {
  PartTruth p;
  p.instance_id = instance;
  p.class_id = class_id;
  p.X_BO = X_BO;
  p.visible_pixels = static_cast<int>(100 * visible);
  p.unoccluded_pixels = 100;
  p.visible_fraction = visible;
  return p;
}

Detection Detected(int class_id, const Pose& X_BO, double score) {
  Detection d;
  d.class_id = class_id;
  d.X_BO = X_BO;
  d.score = score;
  return d;
}

// The default cell's tee: run along its x axis, branch along z, symmetric by
// a half turn about z. Turned about its run axis, its origin stays exact.
TEST(StrictEvaluation, ATeeTurnedAboutItsRunAxisAtAnExactOriginIsAGrossError) {
  const Pose X_BO = Rotated(Vec3(0.7, 0.0, 0.05), Vec3(0.3, 0.2, 1.0), 40);
  GroundTruth truth;
  truth.parts.push_back(Truth(1, kTee, X_BO));
  for (double turn_deg : {30.0, 60.0, 90.0}) {
    PerceptionResult result;
    result.detections.push_back(Detected(kTee, X_BO * Rotated(Vec3::Zero(), Vec3::UnitX(), turn_deg), 0.95));
    const FrameEvaluation fe = EvaluateFrame(result, truth, Models());
    ASSERT_EQ(fe.detections.size(), 1u);
    const DetectionOutcome& o = fe.detections[0];
    EXPECT_EQ(o.verdict, DetectionVerdict::kGross) << turn_deg;
    EXPECT_EQ(o.truth_instance, -1);
    EXPECT_EQ(o.near_instance, 1);
    EXPECT_NEAR(o.translation_error, 0.0, 1e-9);
    EXPECT_NEAR(o.rotation_error, turn_deg * kDeg, 1e-6);
    const EvalReport report = Summarize({fe}, Models());
    const ClassFigures& all = report.classes.back();
    EXPECT_EQ(all.found, 0);
    EXPECT_EQ(all.true_positives, 0);
    EXPECT_EQ(all.gross_errors, 1);
    EXPECT_DOUBLE_EQ(all.precision, 0.0);
    EXPECT_DOUBLE_EQ(all.gross_fraction, 1.0);
    EXPECT_NEAR(all.r_near_max_deg, turn_deg, 1e-4);
  }
  // Its half turn about the branch axis is the same tee.
  PerceptionResult result;
  result.detections.push_back(Detected(kTee, X_BO * Rotated(Vec3::Zero(), Vec3::UnitZ(), 180), 0.95));
  EXPECT_EQ(EvaluateFrame(result, truth, Models()).detections[0].verdict, DetectionVerdict::kTrue);
}

// A gross error whose alternatives hold the true pose (within tolerance,
// modulo symmetry) is carried: the planner keeps only grasps that land under
// both. One whose alternatives are all wrong is not.
TEST(StrictEvaluation, AGrossErrorIsCarriedOnlyWhenAnAlternativeIsTheTruePose) {
  const Pose X_BO = Rotated(Vec3(0.7, 0.0, 0.05), Vec3(0.3, 0.2, 1.0), 40);
  GroundTruth truth;
  truth.parts.push_back(Truth(1, kTee, X_BO));
  const Pose turned = X_BO * Rotated(Vec3::Zero(), Vec3::UnitX(), 30);
  PerceptionResult result;
  Detection carried = Detected(kTee, turned, 0.95);
  // The true pose as its symmetric copy (half turn about z), 2 deg off.
  carried.alternatives_X_BO = {X_BO * Rotated(Vec3::Zero(), Vec3::UnitX(), 60),
                               X_BO * Rotated(Vec3::Zero(), Vec3::UnitZ(), 182)};
  result.detections.push_back(carried);
  const FrameEvaluation fe = EvaluateFrame(result, truth, Models());
  ASSERT_EQ(fe.detections.size(), 1u);
  EXPECT_EQ(fe.detections[0].verdict, DetectionVerdict::kGross);
  EXPECT_EQ(fe.detections[0].alternatives, 2);
  EXPECT_TRUE(fe.detections[0].carried);
  EXPECT_EQ(Summarize({fe}, Models()).classes.back().gross_carried, 1);

  result.detections[0].alternatives_X_BO = {X_BO * Rotated(Vec3::Zero(), Vec3::UnitX(), 60),
                                            X_BO * Rotated(Vec3::Zero(), Vec3::UnitX(), 8)};
  const FrameEvaluation wrong = EvaluateFrame(result, truth, Models());
  EXPECT_FALSE(wrong.detections[0].carried);
  EXPECT_EQ(Summarize({wrong}, Models()).classes.back().gross_carried, 0);
  // A true detection is never "carried", whatever its alternatives.
  result.detections[0].X_BO = X_BO;
  result.detections[0].alternatives_X_BO = {turned};
  EXPECT_FALSE(EvaluateFrame(result, truth, Models()).detections[0].carried);
}

TEST(StrictEvaluation, TheToleranceIsTranslationAndRotationModuloSymmetry) {
  const Pose X_BO = Rotated(Vec3(0.7, 0.0, 0.05), Vec3::UnitY(), 20);
  GroundTruth truth;
  truth.parts.push_back(Truth(1, kBushing, X_BO));
  const auto verdict = [&](const Pose& X, const EvalOptions& options = {}) {
    PerceptionResult result;
    result.detections.push_back(Detected(kBushing, X, 0.9));
    return EvaluateFrame(result, truth, Models(), options).detections[0].verdict;
  };
  // The bushing is revolute about its z: any turn about it is free.
  EXPECT_EQ(verdict(X_BO * Rotated(Vec3(0.004, 0, 0), Vec3::UnitZ(), 77)), DetectionVerdict::kTrue);
  EXPECT_EQ(verdict(X_BO * Rotated(Vec3(0.006, 0, 0), Vec3::UnitZ(), 0)), DetectionVerdict::kGross);
  EXPECT_EQ(verdict(X_BO * Rotated(Vec3::Zero(), Vec3::UnitX(), 4.5)), DetectionVerdict::kTrue);
  EXPECT_EQ(verdict(X_BO * Rotated(Vec3::Zero(), Vec3::UnitX(), 5.5)), DetectionVerdict::kGross);
  EvalOptions tight;
  tight.translation_tolerance = 0.002;
  tight.rotation_tolerance = 2 * kDeg;
  EXPECT_EQ(verdict(X_BO * Rotated(Vec3(0.003, 0, 0), Vec3::UnitZ(), 0), tight), DetectionVerdict::kGross);
  EXPECT_EQ(verdict(X_BO * Rotated(Vec3::Zero(), Vec3::UnitX(), 3), tight), DetectionVerdict::kGross);
  EXPECT_EQ(verdict(X_BO * Rotated(Vec3(0.0015, 0, 0), Vec3::UnitX(), 1.5), tight), DetectionVerdict::kTrue);
  // Farther than a quarter diameter from every part of its class: false.
  EXPECT_EQ(verdict(X_BO * Rotated(Vec3(0.05, 0, 0), Vec3::UnitZ(), 0)), DetectionVerdict::kFalse);
}

TEST(StrictEvaluation, SeparatesDuplicatesWrongClassesAndLessVisibleParts) {
  GroundTruth truth;
  truth.parts.push_back(Truth(1, kBracket, Rotated(Vec3(0.7, 0, 0.05), Vec3::UnitZ(), 10)));
  truth.parts.push_back(Truth(2, kBushing, Rotated(Vec3(0.8, 0, 0.05), Vec3::UnitZ(), 0), 0.3));  // not a target
  PerceptionResult result;
  result.detections.push_back(Detected(kBracket, truth.parts[0].X_BO, 0.95));
  result.detections.push_back(Detected(kBracket, truth.parts[0].X_BO * Rotated(Vec3(0.001, 0, 0), Vec3::UnitZ(), 1), 0.9));
  result.detections.push_back(Detected(kTee, truth.parts[0].X_BO, 0.85));  // a tee where the bracket is
  result.detections.push_back(Detected(kBushing, truth.parts[1].X_BO, 0.8));
  const FrameEvaluation fe = EvaluateFrame(result, truth, Models());
  ASSERT_EQ(fe.detections.size(), 4u);
  EXPECT_EQ(fe.detections[0].verdict, DetectionVerdict::kTrue);
  EXPECT_TRUE(fe.detections[0].target);
  EXPECT_EQ(fe.detections[1].verdict, DetectionVerdict::kDuplicate);
  EXPECT_EQ(fe.detections[1].near_instance, 1);
  EXPECT_EQ(fe.detections[2].verdict, DetectionVerdict::kFalse);
  EXPECT_EQ(fe.detections[2].near_instance, -1);
  EXPECT_EQ(fe.detections[3].verdict, DetectionVerdict::kTrue);
  EXPECT_FALSE(fe.detections[3].target);
  const ClassFigures all = Summarize({fe}, Models()).classes.back();
  EXPECT_EQ(all.targets, 1);
  EXPECT_EQ(all.found, 1);
  EXPECT_EQ(all.true_positives, 2);
  EXPECT_EQ(all.duplicates, 1);
  EXPECT_EQ(all.false_positives, 1);
  EXPECT_DOUBLE_EQ(all.precision, 0.5);
}

// A gross error of a higher score does not take the part from a true
// detection of a lower one.
TEST(StrictEvaluation, AGrossErrorDoesNotTakeThePartFromALaterTrueDetection) {
  GroundTruth truth;
  const Pose X_BO = Rotated(Vec3(0.7, 0, 0.05), Vec3::UnitZ(), 0);
  truth.parts.push_back(Truth(1, kTee, X_BO));
  PerceptionResult result;
  result.detections.push_back(Detected(kTee, X_BO * Rotated(Vec3::Zero(), Vec3::UnitX(), 45), 0.99));
  result.detections.push_back(Detected(kTee, X_BO, 0.9));
  const FrameEvaluation fe = EvaluateFrame(result, truth, Models());
  EXPECT_EQ(fe.detections[0].verdict, DetectionVerdict::kGross);
  EXPECT_EQ(fe.detections[1].verdict, DetectionVerdict::kTrue);
  EXPECT_EQ(fe.targets_found.at(kTee), 1);
}

// Property: a tool at a grasp point of a true part, mapped by any element of
// the part's symmetry, lands exactly; moved along the surface by d it is d off.
TEST(GraspLandingOnTruth, IsExactModuloSymmetryAndMeasuresTheOffset) {
  std::mt19937 rng{42};
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  Symmetry revolute;
  revolute.kind = Symmetry::Kind::kRevolute;
  Symmetry discrete;
  discrete.kind = Symmetry::Kind::kDiscrete;
  discrete.order = 2;
  Symmetry none;
  for (int trial = 0; trial < 50; ++trial) {
    const Pose X_BO = Rotated(Vec3(0.7 + 0.1 * U(rng), 0.1 * U(rng), 0.05), Vec3(U(rng), U(rng), U(rng)), 180 * U(rng));
    const Pose X_OG = Rotated(Vec3(0.03 * U(rng), 0.03 * U(rng), 0.03 * U(rng)), Vec3(U(rng), U(rng), U(rng)), 180 * U(rng));
    const std::vector<PartTruth> parts = {Truth(3, kTee, X_BO), Truth(4, kBushing, X_BO * Rotated(Vec3(0.2, 0, 0), Vec3::UnitZ(), 0))};
    const Vec3 p_O = X_OG.translation();
    const Vec3 a_O = X_OG.linear().col(2);
    struct Case {
      const Symmetry* symmetry;
      Pose element;
    };
    const Case cases[] = {{&none, Pose::Identity()},
                          {&discrete, Rotated(Vec3::Zero(), Vec3::UnitZ(), 180)},
                          {&revolute, Rotated(Vec3::Zero(), Vec3::UnitZ(), 360 * U(rng))}};
    for (const Case& c : cases) {
      // The tool planned on a detection that is the truth turned by a symmetry element.
      const Pose X_BT = X_BO * c.element * X_OG;
      const GraspLanding exact = LandOnTruth(X_BT, p_O, a_O, kTee, *c.symmetry, parts);
      EXPECT_EQ(exact.truth_instance, 3);
      EXPECT_NEAR(exact.position_error, 0.0, 1e-9);
      EXPECT_NEAR(exact.approach_error, 0.0, 1e-6);
      // 3 mm along the tool's x (normal to its approach), and tilted 7 deg.
      const Pose moved = X_BT * Rotated(Vec3(0.003, 0, 0), Vec3::UnitY(), 7);
      const GraspLanding off = LandOnTruth(moved, p_O, a_O, kTee, *c.symmetry, parts);
      if (c.symmetry == &revolute) {
        EXPECT_LE(off.position_error, 0.003 + 1e-9);  // part of the offset may be a turn about the axis
      } else {
        EXPECT_NEAR(off.position_error, 0.003, 1e-9);
        EXPECT_NEAR(off.approach_error, 7 * kDeg, 1e-6);
      }
    }
  }
  // No part of the class in the scene.
  EXPECT_EQ(LandOnTruth(Pose::Identity(), Vec3::Zero(), Vec3::UnitZ(), kBracket, none, {}).truth_instance, -1);
}

// A grasp point 1 mm from a 2-fold axis, the tool 3 mm off it towards the copy
// across the axis: that copy is nearer (1.6 mm) but approached 60 deg from the
// other side, so the landing is measured against the grasp itself.
TEST(GraspLandingOnTruth, PrefersTheCopyApproachedFromTheSameSideNearAnAxis) {
  Symmetry discrete;
  discrete.kind = Symmetry::Kind::kDiscrete;
  discrete.order = 2;
  const Pose X_BO = Rotated(Vec3(0.7, 0, 0.05), Vec3::UnitZ(), 0);
  const Pose X_OG = Rotated(Vec3(0.001, 0, 0.01), Vec3::UnitY(), 150);
  const std::vector<PartTruth> parts = {Truth(3, kTee, X_BO)};
  const Pose moved = X_BO * X_OG * Rotated(Vec3(0.003, 0, 0), Vec3::UnitY(), 7);
  const GraspLanding off =
      LandOnTruth(moved, X_OG.translation(), X_OG.linear().col(2), kTee, discrete, parts);
  EXPECT_EQ(off.truth_instance, 3);
  EXPECT_NEAR(off.position_error, 0.003, 1e-9);
  EXPECT_NEAR(off.approach_error, 7 * kDeg, 1e-6);
}

// The cause report (binpick eval --causes) on a frame made by hand: ten
// columns of pixels per part in a label image, each ROI point at its pixel,
// segments and detection supports set per column. Every miss cause and
// every false-positive cause occurs once (the bracket's wrong detection
// twice), and the true pose is scored on exactly the part's own points.
TEST(EvaluationCauses, EachMissAndFalsePositiveIsCountedUnderItsCause) {
  constexpr int kW = 90, kH = 4;
  Frame frame;
  frame.intrinsics.width = kW;
  frame.intrinsics.height = kH;
  frame.intrinsics.fx = frame.intrinsics.fy = 500.0;
  frame.intrinsics.cx = 45.0;
  frame.intrinsics.cy = 2.0;
  frame.depth = DepthImage(kW, kH, 1.0f);
  GroundTruth truth;
  truth.labels = LabelImage(kW, kH, 0);
  // Parts 1-8 at columns 10(i-1) .. 10i-1; columns 60-69 are nothing.
  const int classes[] = {kBushing, kTee, kBushing, kBracket, kBracket, kTee, kBushing, kBracket};
  for (int i = 1; i <= 8; ++i) {
    truth.parts.push_back(Truth(i, classes[i - 1], Rotated(Vec3(1.0 * i, 0, 0), Vec3::UnitZ(), 0)));
  }
  PerceptionResult result;
  std::map<int, std::vector<int32_t>> points_of_column_block;  // block u / 10 -> ROI indices
  for (int v = 0; v < kH; ++v) {
    for (int u = 0; u < kW; ++u) {
      const int block = u / 10;
      if (block != 6) truth.labels.at(u, v) = static_cast<uint16_t>(block < 6 ? block + 1 : block);
      points_of_column_block[block].push_back(static_cast<int32_t>(result.roi_points_B.size()));
      result.roi_points_B.emplace_back(static_cast<float>((u - 45.0) / 500.0), static_cast<float>((v - 2.0) / 500.0),
                                       1.0f);
      int32_t segment = -1;
      if (block == 0) segment = u % 10 < 5 ? 0 : 1;  // part 1 split in halves
      if (block == 1) segment = 2;
      if (block == 3) segment = 3;
      if (block == 4) segment = 4;
      if (block == 5 || block == 6) segment = 5;  // part 6 merged with as much background
      if (block == 7) segment = 6;
      if (block == 8) segment = 7;
      result.segment_of_point.push_back(segment);
    }
  }
  frame.truth = truth;
  // Labels for blocks 7 and 8 are parts 7 and 8.
  const Pose far = Rotated(Vec3(5, 5, 5), Vec3::UnitZ(), 0);
  const auto detection = [&](int class_id, const Pose& X_BO, int block) {
    Detection d = Detected(class_id, X_BO, 0.9);
    d.support = points_of_column_block[block];
    result.detections.push_back(d);
  };
  detection(kBushing, truth.parts[6].X_BO, 7);  // part 7 found
  detection(kBushing, far, 1);                  // on tee 2, missed: other_class_missed; tee 2 wrong_detection
  detection(kBracket, far, 6);                  // on nothing: no_part
  detection(kTee, far, 7);                      // on bushing 7, found: other_class_found
  detection(kBracket, far, 8);                  // on bracket 8: its_class; bracket 8 wrong_detection
  const FrameEvaluation fe = EvaluateFrame(result, truth, Models());
  std::map<int, size_t> scored_points;
  const auto truth_score = [&](const PartTruth& p, const std::vector<Eigen::Vector3f>& own) {
    scored_points[p.instance_id] = own.size();
    return p.instance_id == 4 ? 0.3 : 0.9;
  };
  CauseFigures causes;
  AddFrameCauses(frame, result, fe, truth_score, causes, EvalOptions{}, 17);
  const auto misses = [&](int class_id, MissCause cause) {
    return causes.misses[class_id][static_cast<size_t>(cause)];
  };
  EXPECT_EQ(misses(kBushing, MissCause::kSplit), 1);
  EXPECT_EQ(misses(kBushing, MissCause::kUnsegmented), 1);
  EXPECT_EQ(misses(kTee, MissCause::kWrongDetection), 1);
  EXPECT_EQ(misses(kTee, MissCause::kMerged), 1);
  EXPECT_EQ(misses(kBracket, MissCause::kTruthScoresLow), 1);
  EXPECT_EQ(misses(kBracket, MissCause::kNotFound), 1);
  EXPECT_EQ(misses(kBracket, MissCause::kWrongDetection), 1);
  int all_misses = 0;
  for (const auto& [c, counts] : causes.misses) all_misses += std::accumulate(counts.begin(), counts.end(), 0);
  EXPECT_EQ(all_misses, 7);
  // Each miss listed with its frame, part and cause, in the truth's order.
  ASSERT_EQ(causes.missed.size(), 7u);
  EXPECT_EQ(causes.missed.front().frame, 17);
  EXPECT_EQ(causes.missed.front().instance_id, 1);
  EXPECT_EQ(causes.missed.front().class_id, kBushing);
  EXPECT_EQ(causes.missed.front().cause, MissCause::kSplit);
  EXPECT_EQ(causes.missed.back().instance_id, 8);
  EXPECT_EQ(causes.missed.back().cause, MissCause::kWrongDetection);
  const auto fps = [&](int class_id, FalseCause cause) {
    return causes.false_positives[class_id][static_cast<size_t>(cause)];
  };
  EXPECT_EQ(fps(kBushing, FalseCause::kOnOtherClassMissed), 1);
  EXPECT_EQ(fps(kBracket, FalseCause::kOnNoPart), 1);
  EXPECT_EQ(fps(kTee, FalseCause::kOnOtherClassFound), 1);
  EXPECT_EQ(fps(kBracket, FalseCause::kOnItsClass), 1);
  // Scored on its own 40 points; not scored when a wrong detection sits on it.
  EXPECT_EQ(scored_points[4], 10u * kH);
  EXPECT_EQ(scored_points.count(2), 0u);
  EXPECT_EQ(scored_points.count(8), 0u);
  // The cut of the split part.
  const std::vector<int> owners = RoiPointOwners(frame, result);
  const PartCut cut = CutOfPart(1, owners, result.segment_of_point);
  EXPECT_EQ(cut.points, 10 * kH);
  EXPECT_EQ(cut.segments, 2);
  EXPECT_DOUBLE_EQ(cut.largest_share, 0.5);
  EXPECT_DOUBLE_EQ(cut.largest_purity, 1.0);
  EXPECT_DOUBLE_EQ(CutOfPart(6, owners, result.segment_of_point).largest_purity, 0.5);
}

}  // namespace
}  // namespace bp
