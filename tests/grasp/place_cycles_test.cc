// Seed 003's pick -> correct in hand -> place cycles (grasp/place_cycles.h)
// with ground-truth detections: the scoring itself, with perception's
// errors taken out.
#include "grasp/place_cycles.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <memory>

#include "grasp/robot_targets.h"
#include "pipeline/truth_perception.h"

namespace bp {
namespace {

Cell SmallPileCell(double slip_translation, double slip_rotation_deg) {
  Cell cell = LoadDefaultCell().value();
  cell.source.num_parts = 4;
  cell.source.slip_translation = slip_translation;
  cell.source.slip_rotation_deg = slip_rotation_deg;
  return cell;
}

TEST(PlaceCycles, TheInHandAnswerPutsAPartThatSlippedExactlyWhereTheMovedFixtureWantsIt) {
  const Cell cell = SmallPileCell(0.01, 10);
  PlaceCyclesOptions o;
  o.cycles = 6;
  o.seed = 21;
  Result<PlaceCyclesReport> r = RunPlaceCycles(cell, std::make_shared<TruthPerception>(cell), o);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  ASSERT_EQ(r->cycles.size(), 6u);
  EXPECT_EQ(r->placed, 6) << r->Describe();
  double largest_uncorrected = 0;
  for (const PlaceCycle& c : r->cycles) {
    EXPECT_LT(c.in_hand_error_mm, 1e-3);
    EXPECT_LT(c.place_error_mm, 1e-3);
    EXPECT_LT(c.place_error_deg, 1e-3);
    EXPECT_LE(c.slip_mm, 10 + 1e-9);
    EXPECT_LE(c.slip_deg, 10 + 1e-9);
    largest_uncorrected = std::max(largest_uncorrected, c.uncorrected_mm);
  }
  // Without the correction the slip goes into the place.
  EXPECT_GT(largest_uncorrected, 2.0) << r->Describe();
  EXPECT_EQ(r->poses_sent, 3 * 6);  // grasp, pre-grasp, the computed place
  EXPECT_EQ(r->sent_outside, 0);
}

TEST(PlaceCycles, WithoutSlipTheOraclesPickAloneAlreadyPlacesExactly) {
  const Cell cell = SmallPileCell(0, 0);
  PlaceCyclesOptions o;
  o.cycles = 3;
  o.seed = 22;
  Result<PlaceCyclesReport> r = RunPlaceCycles(cell, std::make_shared<TruthPerception>(cell), o);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  for (const PlaceCycle& c : r->cycles) {
    EXPECT_EQ(c.outcome, "placed");
    EXPECT_LT(c.slip_mm, 1e-9);
    EXPECT_LT(c.grasp_error_mm, 1e-3);
    EXPECT_LT(c.uncorrected_mm, 1e-3);
    EXPECT_LT(c.uncorrected_deg, 1e-3);
  }
}

TEST(PlaceCycles, APlaceOutsideTheWorkspaceIsRefusedNotSent) {
  Cell cell = SmallPileCell(0.005, 5);
  // The bin (x 0.45 to 0.95 m, y -0.18 to 0.18 m) inside, the fixture (x
  // 0.37 m, y 0.23 m) outside.
  cell.robot.workspace = Eigen::AlignedBox3d(Vec3(0.42, -1.3, -0.2), Vec3(1.3, 0.19, 1.5));
  PlaceCyclesOptions o;
  o.pick_task_id = 0;  // picks any grasp (task 7 would pick none: none could be placed)
  o.cycles = 2;
  o.seed = 23;
  Result<PlaceCyclesReport> r = RunPlaceCycles(cell, std::make_shared<TruthPerception>(cell), o);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->refused, 2);
  EXPECT_EQ(r->placed, 0);
  EXPECT_EQ(r->poses_sent, 2 * 2);  // the picks' grasp and pre-grasp only
  EXPECT_EQ(r->sent_outside, 0);
  for (const PlaceCycle& c : r->cycles) EXPECT_EQ(c.outcome, "outside_workspace");
}

TEST(PlaceCycles, TasksOfTheWrongKindAreRefused) {
  const Cell cell = SmallPileCell(0, 0);
  PlaceCyclesOptions o;
  o.in_hand_task_id = 0;
  const Result<PlaceCyclesReport> r = RunPlaceCycles(cell, std::make_shared<TruthPerception>(cell), o);
  EXPECT_EQ(r.status().code(), Status::Code::kInvalidArgument);
  EXPECT_NE(r.status().message().find("task 0 is not an in_hand task"), std::string::npos) << r.status().ToString();
}

TEST(RobotTargets, NameThePoseAndTheLimitItBreaks) {
  Cell cell = LoadDefaultCell().value();
  cell.robot.workspace = Eigen::AlignedBox3d(Vec3(0.42, -1.3, -0.2), Vec3(1.3, 1.3, 1.5));
  const TaskSpec& place_area = *cell.FindTask(3);
  const GripperSpec& suction = *cell.FindGripper(place_area.gripper);
  Grasp answer;
  answer.name = "place_offset";
  answer.X_BT = MakePose(Mat3::Identity(), Vec3(0.01, 0, 0));  // the offset itself is never a target
  EXPECT_TRUE(CheckRobotTargets(cell, place_area, answer).ok());
  // The place the program computes: straight down onto the fixture at x = 0.365 m.
  const Pose X_BT = MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), Vec3(0.365, 0.1, 0.07));
  answer.implied_X_BT = {X_BT};
  const Status refused = CheckRobotTargets(cell, place_area, answer);
  EXPECT_EQ(refused.code(), Status::Code::kOutOfRange);
  const Vec3 flange = (X_BT * suction.X_FT.inverse()).translation();
  char expected[160];
  std::snprintf(expected, sizeof(expected), "puts the flange at (%.3f, %.3f, %.3f) m is outside robot.workspace: x %.3f < min 0.420",
                flange.x(), flange.y(), flange.z(), flange.x());
  EXPECT_NE(refused.message().find("tool pose (0.365, 0.100, 0.070 m | rotation vector "),
            std::string::npos)
      << refused.message();
  EXPECT_NE(refused.message().find(expected), std::string::npos) << refused.message();
  // A pick's grasp and pre-grasp are its targets; in_hand has none.
  Grasp pick;
  pick.X_BT = MakePose(Mat3::Identity(), Vec3(0.7, 0, 0.1));
  pick.X_BT_pre = MakePose(Mat3::Identity(), Vec3(0.3, 0, 0.1));
  EXPECT_EQ(RobotTargets(*cell.FindTask(0), pick).size(), 2u);
  EXPECT_FALSE(CheckRobotTargets(cell, *cell.FindTask(0), pick).ok());  // the pre-grasp's flange is at x < 0.42
  EXPECT_TRUE(RobotTargets(*cell.FindTask(1), pick).empty());
}

}  // namespace
}  // namespace bp
