// Judging grasps against the true scene (grasp/grasp_judge.h): the tool
// centre at the grasp's own point on the true part (2 mm) and the approach
// within the gripper's compliance, modulo the part's symmetry.
#include "grasp/grasp_judge.h"
#include "tests/testing/default_cell.h"

#include <gtest/gtest.h>

#include <cmath>

namespace bp {
namespace {

constexpr double kDeg = M_PI / 180.0;
constexpr int kBushing = 0, kBracket = 1, kTee = 2;

using testing::DefaultCell;

const GraspPlanningModel& Model() {
  static const std::shared_ptr<const GraspPlanningModel> model = [] {
    auto m = GraspPlanningModel::Build(DefaultCell());
    EXPECT_TRUE(m.ok()) << m.status().ToString();
    return *m;
  }();
  return *model;
}

Pose Rotated(const Vec3& t, const Vec3& axis, double deg) {
  return MakePose(Mat3(Eigen::AngleAxisd(deg * kDeg, axis.normalized())), t);
}

PartTruth Truth(int instance, int class_id, const Pose& X_BO) {
  PartTruth p;
  p.instance_id = instance;
  p.class_id = class_id;
  p.X_BO = X_BO;
  p.visible_fraction = 1.0;
  return p;
}

// The cell grasp `name` of `class_id` for `gripper`, planned on a detection at X_BO_detected.
Grasp Planned(int class_id, const std::string& gripper, const std::string& name, const Pose& X_BO_detected) {
  Grasp g;
  g.class_id = class_id;
  g.X_BO = X_BO_detected;
  g.name = name;
  for (const TaughtGrasp& t : Model().CellGrasps(class_id, gripper)) {
    if (t.name == name) g.X_BT = X_BO_detected * t.X_OG;
  }
  EXPECT_FALSE(g.X_BT.isApprox(Pose::Identity())) << name;
  return g;
}

// A tee turned about its run axis with its origin exact (a gross error):
// its branch grasp puts the tool into air beside the real branch.
TEST(GraspJudge, ABranchGraspOnATeeTurnedAboutItsRunIsOffThePart) {
  const Pose X_BO = Rotated(Vec3(0.7, 0.0, 0.05), Vec3::UnitZ(), 15);
  const std::vector<PartTruth> truth = {Truth(5, kTee, X_BO)};
  const GraspOutcome right = JudgeGrasp(Model(), "suction", Planned(kTee, "suction", "branch_side@0", X_BO), truth);
  EXPECT_TRUE(right.on_part) << right.failure;
  EXPECT_EQ(right.truth_instance, 5);
  EXPECT_NEAR(right.position_error, 0.0, 1e-9);
  const Pose turned = X_BO * Rotated(Vec3::Zero(), Vec3::UnitX(), 30);
  const GraspOutcome wrong = JudgeGrasp(Model(), "suction", Planned(kTee, "suction", "branch_side@0", turned), truth);
  EXPECT_FALSE(wrong.on_part);
  EXPECT_EQ(wrong.failure, "off_part");
  EXPECT_GT(wrong.position_error, 0.010);
  // The run's top, 20 mm from the run's axis, moves along the pipe's surface
  // by the chord 2 * 20 mm * sin(15 deg) = 10.4 mm.
  const GraspOutcome run = JudgeGrasp(Model(), "suction", Planned(kTee, "suction", "run_top@0", turned), truth);
  EXPECT_EQ(run.failure, "off_part");
  EXPECT_NEAR(run.position_error, 2 * 0.020 * std::sin(15 * kDeg), 1e-6);
}

TEST(GraspJudge, TwoMillimetresAtTheGraspPointAndTheCompliance) {
  const Pose X_BO = Rotated(Vec3(0.7, 0.0, 0.05), Vec3::UnitY(), 0);
  const std::vector<PartTruth> truth = {Truth(1, kBracket, X_BO), Truth(2, kBracket, X_BO * Rotated(Vec3(0.2, 0, 0), Vec3::UnitZ(), 0))};
  const auto judge = [&](const Pose& X_BO_detected) {
    return JudgeGrasp(Model(), "suction", Planned(kBracket, "suction", "base_top", X_BO_detected), truth);
  };
  EXPECT_TRUE(judge(X_BO * Rotated(Vec3(0.0019, 0, 0), Vec3::UnitZ(), 0)).on_part);
  const GraspOutcome far = judge(X_BO * Rotated(Vec3(0.0021, 0, 0), Vec3::UnitZ(), 0));
  EXPECT_EQ(far.failure, "off_part");
  EXPECT_EQ(far.truth_instance, 1);
  // A detection turned about the grasp point itself: the point stays, the
  // approach turns; the cup complies up to 20 deg.
  const Vec3 p_O(0.045, 0.0, 0.005);
  const auto turned_about_point = [&](double deg) {
    return X_BO * Rotated(p_O, Vec3::UnitX(), deg) * Rotated(-p_O, Vec3::UnitX(), 0);
  };
  EXPECT_TRUE(judge(turned_about_point(19)).on_part);
  const GraspOutcome tilted = judge(turned_about_point(21));
  EXPECT_EQ(tilted.failure, "approach");
  EXPECT_NEAR(tilted.approach_error, 21 * kDeg, 1e-6);
  EXPECT_NEAR(tilted.position_error, 0.0, 1e-9);
  // A bushing's grasp where only brackets are: no part of its class.
  Grasp bushing = Planned(kBushing, "suction", "hub_top@0", X_BO);
  EXPECT_EQ(JudgeGrasp(Model(), "suction", bushing, truth).failure, "no_part");
}

// A "~v" candidate (turned toward vertical by the planner) spends part of the
// cup's compliance: judged against the cell grasp's approach, not its own.
TEST(GraspJudge, ATurnedSuctionGraspSpendsItsTurnOfTheCompliance) {
  const Pose X_BO = Rotated(Vec3(0.7, 0.0, 0.05), Vec3::UnitY(), 0);
  const std::vector<PartTruth> truth = {Truth(1, kBracket, X_BO)};
  Grasp g = Planned(kBracket, "suction", "base_top", X_BO);
  const Vec3 p_B = g.X_BT.translation();
  for (double turn : {10.0, 19.5, 20.5}) {
    Grasp v = g;
    v.name = "base_top~v";
    v.X_BT.linear() = Eigen::AngleAxisd(turn * kDeg, Vec3::UnitY()).toRotationMatrix() * g.X_BT.linear();
    v.X_BT.translation() = p_B;
    const GraspOutcome o = JudgeGrasp(Model(), "suction", v, truth);
    EXPECT_NEAR(o.approach_error, turn * kDeg, 1e-6);
    EXPECT_EQ(o.on_part, turn <= 20.0) << turn;
  }
}

TEST(GraspJudge, AParallelJawAllowsFiveDegrees) {
  const Pose X_BO = Rotated(Vec3(0.7, 0.0, 0.05), Vec3::UnitZ(), 30);
  const std::vector<PartTruth> truth = {Truth(1, kBracket, X_BO)};
  Grasp g = Planned(kBracket, "parallel", "base_pinch_y_up", X_BO);
  EXPECT_TRUE(JudgeGrasp(Model(), "parallel", g, truth).on_part);
  const Vec3 p_B = g.X_BT.translation();
  g.X_BT.linear() = Eigen::AngleAxisd(6 * kDeg, Vec3::UnitX()).toRotationMatrix() * g.X_BT.linear();
  g.X_BT.translation() = p_B;
  EXPECT_EQ(JudgeGrasp(Model(), "parallel", g, truth).failure, "approach");
}

// A pick whose tool touches down on a true part off its grasp point is a
// failed pick, not a collision with that part: the cup meets that part's
// surface as it meets any part it lands on (clear seed 12786: an L-bracket
// detected turned over put upright_inner's cup on the real bracket's plate,
// while the grasp point nearest the tool was another bracket's 73 mm away,
// and the cup's touchdown was counted as hitting the real bracket). Every
// other part is still checked whole. Here a false bushing fitted on a
// bracket's plate puts hub_top's tool centre on the plate; the only true
// bushing stands 200 mm away.
TEST(GraspJudge, ACupTouchingDownOnAPartOffItsGraspPointIsNoCollisionWithIt) {
  const Pose& X_BW = DefaultCell().bin.X_BW;
  const Pose X_BO_bracket = X_BW * Rotated(Vec3(-0.05, 0.0, 0.0), Vec3::UnitZ(), 0);  // flat, base on the floor
  const Pose X_BO_far = X_BW * Rotated(Vec3(0.15, 0.1, 0.0), Vec3::UnitZ(), 0);
  // hub_top@0's tool centre (12, 0, 40) mm in the bushing: 1 mm into the
  // plate's top at (25, 0, 5) mm in the bracket (the cup pressed on it, as
  // in 12786), clear of its holes and upright.
  const Pose X_BO_false = X_BO_bracket * Rotated(Vec3(0.025 - 0.012, 0.0, 0.004 - 0.040), Vec3::UnitZ(), 0);
  const Grasp g = Planned(kBushing, "suction", "hub_top@0", X_BO_false);
  std::vector<PartTruth> truth = {Truth(3, kBracket, X_BO_bracket), Truth(6, kBushing, X_BO_far)};
  const GraspOutcome landing = JudgeGrasp(Model(), "suction", g, truth);
  EXPECT_EQ(landing.failure, "off_part");
  EXPECT_EQ(landing.truth_instance, 6);
  // The swept cup does touch the plate: checked whole, the bracket is hit.
  Detection plate[1];
  plate[0].class_id = kBracket;
  plate[0].X_BO = X_BO_bracket;
  EXPECT_EQ(Model().CheckAgainstParts("suction", g.X_BT, plate, -1, X_BW), RejectReason::kPart);
  const PickContact on_plate = CheckPickOnTruth(Model(), "suction", g, truth, landing, X_BW);
  EXPECT_EQ(on_plate.touched, 0);
  EXPECT_EQ(on_plate.hit, std::nullopt);
  // A bushing standing on the plate whose flange (r 30 mm) reaches 2 mm
  // under the cup (r 8 mm): hit, though the tool centre is 6 mm from it.
  truth.push_back(Truth(7, kBushing, X_BO_bracket * Rotated(Vec3(0.061, 0.0, 0.005), Vec3::UnitZ(), 0)));
  const PickContact beside = CheckPickOnTruth(Model(), "suction", g, truth, JudgeGrasp(Model(), "suction", g, truth), X_BW);
  EXPECT_EQ(beside.touched, 0);
  EXPECT_EQ(beside.hit, RejectReason::kPart);
  // The tool 7 mm above the plate touches down on nothing: every part whole.
  Grasp high = g;
  high.X_BT = g.X_BT * Rotated(Vec3(0, 0, -0.008), Vec3::UnitZ(), 0);
  truth.pop_back();
  const PickContact air = CheckPickOnTruth(Model(), "suction", high, truth, JudgeGrasp(Model(), "suction", high, truth), X_BW);
  EXPECT_EQ(air.touched, -1);
  EXPECT_EQ(air.hit, std::nullopt);
}

}  // namespace
}  // namespace bp
