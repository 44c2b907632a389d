// The robot simulator's flows (seed robot programs) against the server with
// the scripted test-double planner.
#include "comms/robot_flows.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <iostream>
#include <sstream>

#include "comms/daoai_server.h"
#include "tests/testing/scripted_planner.h"

namespace bp {
namespace {

using testing::MakeTestCell;
using testing::ScriptedPlanner;

// Parameter: the dialect of the cell and of the robot's script. The robot sends
// meta_2 = 1, as both seeds' programs do.
class RobotFlowTest : public ::testing::TestWithParam<DaoaiDialect> {
 protected:
  void SetUp() override {
    planner_ = std::make_shared<ScriptedPlanner>();
    handler_ = std::make_unique<RequestHandler>(MakeTestCell(dialect()), planner_,
                                                std::make_unique<CountingCalibrationService>(4));
    DaoaiServerOptions options;
    options.port = 0;
    server_ = std::move(DaoaiServer::Start(*handler_, options).value());
    RobotClientOptions o;
    o.port = server_->port();
    o.version = 1;
    o.dialect = dialect();
    robot_ = std::move(RobotClient::Connect(o).value());
  }
  void TearDown() override {
    robot_.reset();
    server_->Stop();
    handler_->Shutdown();
  }
  DaoaiDialect dialect() const { return GetParam(); }

  FlowSummary Run(FlowOptions o) {
    Result<FlowSummary> s = RunFlow(*robot_, o, out_);
    EXPECT_TRUE(s.ok()) << s.status().ToString();
    return s.ok() ? *s : FlowSummary{};
  }

  std::shared_ptr<ScriptedPlanner> planner_;
  std::unique_ptr<RequestHandler> handler_;
  std::unique_ptr<DaoaiServer> server_;
  std::unique_ptr<RobotClient> robot_;
  std::ostringstream out_;
};

TEST_P(RobotFlowTest, PickClearsTheBinThenFindsItEmpty) {
  ScriptedPlanner::Script pile;
  pile.grasps = 3;
  pile.pile = 7;
  planner_->SetScript(0, pile);
  FlowOptions o;
  o.flow = "pick";
  const FlowSummary s = Run(o);
  EXPECT_EQ(s.picks, 7) << out_.str();
  EXPECT_TRUE(s.ok) << out_.str();
  EXPECT_EQ(s.last_status, daoai::kBoxEmpty);
  // 3 capture cycles with grasps (3 + 3 + 1), one finding nothing.
  EXPECT_EQ(planner_->captures(), 4 + 1);  // + the empty-box check's capture
  EXPECT_NE(out_.str().find("remaining 3 class 0"), std::string::npos) << out_.str();
  EXPECT_NE(out_.str().find("BOX_EMPTY(41)"), std::string::npos) << out_.str();
  if (std::getenv("BINPICK_VERBOSE")) std::cout << out_.str();
}

TEST_P(RobotFlowTest, PickPlaceGetsADropOffPoseForEachPick) {
  ScriptedPlanner::Script pile;
  pile.pile = 2;
  planner_->SetScript(0, pile);
  FlowOptions o;
  o.flow = "pick-place";
  const FlowSummary s = Run(o);
  EXPECT_EQ(s.picks, 2) << out_.str();
  EXPECT_TRUE(s.ok) << out_.str();
  EXPECT_NE(out_.str().find("DROP_OFF_POSE(6)"), std::string::npos) << out_.str();
}

TEST_P(RobotFlowTest, CalibrationFlowsEndAsTheRobotProgramsExpect) {
  for (const char* flow : {"calib-manual", "calib-auto", "calib-auto-2d", "calib-guidance"}) {
    FlowOptions o;
    o.flow = flow;
    o.manual_poses = 5;
    const FlowSummary s = Run(o);
    EXPECT_TRUE(s.ok) << flow << "\n" << out_.str();
  }
  // Auto: the counting service says done after 4 poses (start + 4 accumulates).
  EXPECT_NE(out_.str().find("DONE_CALIBRATION(33)"), std::string::npos) << out_.str();
  EXPECT_NE(out_.str().find("DONE_2D_AUTO_CALIBRATION(34)"), std::string::npos);
  if (dialect() == DaoaiDialect::kSocketV1) {
    EXPECT_NE(out_.str().find("DONE_GUIDANCE_CALIBRATION(32)"), std::string::npos);
  }
}

TEST_P(RobotFlowTest, HelperFlowsReportTheirStatus) {
  FlowOptions o;
  o.flow = "switch-config";
  o.config_id = 2;
  EXPECT_TRUE(Run(o).ok);
  o.config_id = 9;
  EXPECT_FALSE(Run(o).ok);
  o.flow = "precision";
  o.task_id = 5;
  EXPECT_TRUE(Run(o).ok);
  EXPECT_NE(out_.str().find("error 0.420 mm"), std::string::npos) << out_.str();
  o.flow = "teach";
  o.task_id = 0;
  EXPECT_TRUE(Run(o).ok);
  o.flow = "empty-check";
  EXPECT_TRUE(Run(o).ok);
  EXPECT_NE(out_.str().find("BOX_NOT_EMPTY(42)"), std::string::npos) << out_.str();
  o.flow = "dance";
  EXPECT_FALSE(RunFlow(*robot_, o, out_).ok());
  handler_->Shutdown();  // teaching has no response: wait for it to be stored
  EXPECT_EQ(planner_->taught().size(), 1u);
}

INSTANTIATE_TEST_SUITE_P(Dialects, RobotFlowTest,
                         ::testing::Values(DaoaiDialect::kSocketV1, DaoaiDialect::kVisionPilot),
                         [](const auto& info) { return std::string(ToString(info.param)); });

}  // namespace
}  // namespace bp
