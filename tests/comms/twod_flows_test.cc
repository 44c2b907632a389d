// 2D tasks over the DaoAI socket (issue 9): the robot simulator's 2D flows
// (seed 000 send_robot_data_2d / recv_daoai_data_2d) against a server whose
// pick_2d task runs the 2D planner and whose RC 11/12 run the plane
// calibration, on loopback.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <iostream>
#include <sstream>

#include "comms/daoai_server.h"
#include "comms/modbus_master.h"
#include "comms/modbus_robot_sim.h"
#include "comms/plane_calibration_service.h"
#include "comms/robot_flows.h"
#include "tests/testing/files.h"
#include "tests/testing/twod.h"
#include "twod/planner_2d.h"

namespace bp {
namespace {

class TwoDFlowTest : public ::testing::Test {
 protected:
  void Start(Cell cell) {
    cell_ = cell;
    file_ = testing::FreshDir("twod") + "/plane.yaml";
    camera_ = std::move(SyntheticPlaneCamera::Create(cell).value());
    store_ = std::make_shared<PlaneCalibrationStore>();
    auto planner = std::make_shared<TaskKindPlanner>(nullptr, std::make_unique<Plane2DPlanner>(cell, camera_, store_));
    PlaneCalibrationOptions options;
    options.file = file_;
    handler_ = std::make_unique<RequestHandler>(cell, planner,
                                                std::make_unique<PlaneCalibrationService>(camera_, store_, options));
    DaoaiServerOptions server_options;
    server_options.port = 0;
    server_ = std::move(DaoaiServer::Start(*handler_, server_options).value());
    RobotClientOptions o;
    o.port = server_->port();
    robot_ = std::move(RobotClient::Connect(o).value());
  }
  void TearDown() override {
    if (std::getenv("BINPICK_VERBOSE")) std::cout << out_.str();
    robot_.reset();
    if (server_) server_->Stop();
    if (handler_) handler_->Shutdown();
  }
  FlowSummary Run(const std::string& flow) {
    FlowOptions o;
    o.flow = flow;
    Result<FlowSummary> s = RunFlow(*robot_, o, out_);
    EXPECT_TRUE(s.ok()) << s.status().ToString();
    return s.ok() ? *s : FlowSummary{};
  }

  Cell cell_;
  std::string file_;
  std::shared_ptr<SyntheticPlaneCamera> camera_;
  std::shared_ptr<PlaneCalibrationStore> store_;
  std::unique_ptr<RequestHandler> handler_;
  std::unique_ptr<DaoaiServer> server_;
  std::unique_ptr<RobotClient> robot_;
  std::ostringstream out_;
};

TEST_F(TwoDFlowTest, AutoCalibrationWalksTheGridAndPersistsAFitWithinTwoTenthsOfAMillimetre) {
  Start(testing::LoadTwodCell());
  const FlowSummary s = Run("calib-auto-2d");
  EXPECT_TRUE(s.ok) << out_.str();
  EXPECT_EQ(s.last_status, daoai::kDone2DAutoCalibration) << out_.str();
  EXPECT_EQ(s.steps, 1 + 21) << out_.str();  // start, the centre, 20 grid points
  // The grid's corner: 0.18 m, 0.12 m from the centre.
  EXPECT_NE(out_.str().find("pose [-0.1800 -0.1200 0.0000"), std::string::npos) << out_.str();
  Result<PlaneCalibration> saved = LoadPlaneCalibration(file_);
  ASSERT_TRUE(saved.ok()) << saved.status().ToString();
  EXPECT_EQ(saved->points, 21);
  EXPECT_LE(saved->residual_rms_mm, 0.2);
  std::printf("2D calibration over the socket: %d points, residual %.4f mm rms, %.4f mm max\n", saved->points,
              saved->residual_rms_mm, saved->residual_max_mm);
  ASSERT_NE(store_->Get(), nullptr);
  // A second calibration keeps the first file as the backup.
  EXPECT_TRUE(Run("calib-auto-2d").ok);
  EXPECT_TRUE(std::filesystem::exists(file_ + ".bak"));
}

TEST_F(TwoDFlowTest, PickFlowPicksEveryPartAtItsTruePlanePose) {
  Start(testing::LoadTwodCell());
  ASSERT_TRUE(Run("calib-auto-2d").ok) << out_.str();
  ASSERT_TRUE(camera_->Scatter(6, 3).ok());
  const std::vector<FlatPartTruth> truth = camera_->parts();
  ASSERT_EQ(truth.size(), 6u);
  const FlowSummary s = Run("pick-2d");
  EXPECT_TRUE(s.ok) << out_.str();
  EXPECT_EQ(s.picks, 6) << out_.str();
  EXPECT_EQ(s.last_status, daoai::kBoxEmpty) << out_.str();
  EXPECT_NE(out_.str().find("remaining 6 class"), std::string::npos) << out_.str();
  EXPECT_TRUE(camera_->parts().empty());
  double max_mm = 0, max_deg = 0;
  for (const Pose& X_PT : s.pick_poses) {
    // The nearest true grasp of any part.
    const Pose2D got = ToPose2D(X_PT);
    double best_mm = 1e9, best_deg = 0;
    for (const FlatPartTruth& t : truth) {
      for (const Grasp2DSpec& g : cell_.FindPart(t.class_id)->flat_2d->grasps) {
        const Pose2D want = t.X_PO.Compose({g.xy.x(), g.xy.y(), g.angle});
        const double mm = (want.xy() - got.xy()).norm() * 1000;
        if (mm < best_mm) {
          best_mm = mm;
          best_deg = std::abs(WrapAngle(want.theta - got.theta)) * 180 / M_PI;
        }
      }
    }
    max_mm = std::max(max_mm, best_mm);
    max_deg = std::max(max_deg, best_deg);
    EXPECT_NEAR((X_PT.linear().col(2) - Vec3(0, 0, -1)).norm(), 0, 1e-3);  // tool down
  }
  std::printf("2D picks over the socket: %d, max %.3f mm, max %.3f deg from ground truth\n", s.picks, max_mm,
              max_deg);
  EXPECT_LE(max_mm, 0.5);
  EXPECT_LE(max_deg, 0.5);
}

TEST_F(TwoDFlowTest, EveryFootprintOverlappingANeighbourAnswersNoCollisionFreePose) {
  Cell cell = testing::LoadTwodCell();
  cell.grippers[0].footprint = {{-0.06, -0.06}, {0.06, -0.06}, {0.06, 0.06}, {-0.06, 0.06}};
  Start(cell);
  ASSERT_TRUE(Run("calib-auto-2d").ok) << out_.str();
  camera_->SetParts({{1, 0, {-0.05, 0.0, 0.0}}, {2, 1, {-0.05, -0.045, 0.3}}});
  ASSERT_EQ(robot_->Call(daoai::kCaptureAndProcess, 0).value().status, daoai::kDetection);
  const RobotReply pick = robot_->Call(daoai::kPickPose, 0).value();
  EXPECT_EQ(pick.status, daoai::kNoCollisionFreePose);
  EXPECT_EQ(pick.payload[0], 0.0);
  EXPECT_EQ(camera_->parts().size(), 2u);  // nothing was handed out
}

// Without a 2D calibration nothing can be located: the planner fails, and
// the pick is answered as an error (-1, payload_1 0), not NO_OBJECT_FOUND,
// which would send the robot to check for an empty bin (issue 39).
TEST_F(TwoDFlowTest, PickBeforeCalibrationIsAnsweredAsAnError) {
  Start(testing::LoadTwodCell());
  ASSERT_TRUE(camera_->Scatter(3, 1).ok());
  ASSERT_EQ(robot_->Call(daoai::kCaptureAndProcess, 0).value().status, daoai::kDetection);
  const RobotReply pick = robot_->Call(daoai::kPickPose, 0).value();
  EXPECT_EQ(pick.status, daoai::kUnknownCommand);
  EXPECT_EQ(pick.payload[0], 0.0);
}

// The same 2D flows with the robot as a Modbus TCP slave (seed 000's UR
// registers) and binpick as master.
TEST(TwoDModbus, CalibrationAndPickFlowsRunOverTheRegisters) {
  using namespace std::chrono_literals;
  const Cell cell = testing::LoadTwodCell();
  std::shared_ptr<SyntheticPlaneCamera> camera = std::move(SyntheticPlaneCamera::Create(cell).value());
  auto store = std::make_shared<PlaneCalibrationStore>();
  RequestHandler handler(cell,
                         std::make_shared<TaskKindPlanner>(nullptr, std::make_unique<Plane2DPlanner>(cell, camera, store)),
                         std::make_unique<PlaneCalibrationService>(camera, store, PlaneCalibrationOptions{}));
  auto sim = std::move(ModbusRobotSim::Start({}).value());
  ModbusMasterOptions mo;
  mo.port = sim->port();
  mo.timeout = 500ms;
  auto master = std::move(ModbusMaster::Start(handler, mo).value());
  ASSERT_TRUE(sim->WaitForMaster(5s));
  RobotClientOptions ro;
  ro.timeout = 10s;
  auto robot = RobotClient::Over(sim->Transport(), ro);
  std::ostringstream out;
  FlowOptions f;
  f.flow = "calib-auto-2d";
  Result<FlowSummary> calib = RunFlow(*robot, f, out);
  ASSERT_TRUE(calib.ok()) << calib.status().ToString();
  EXPECT_TRUE(calib->ok) << out.str();
  ASSERT_NE(store->Get(), nullptr);
  EXPECT_LE(store->Get()->residual_rms_mm, 0.2);
  ASSERT_TRUE(camera->Scatter(4, 5).ok());
  f.flow = "pick-2d";
  Result<FlowSummary> pick = RunFlow(*robot, f, out);
  ASSERT_TRUE(pick.ok()) << pick.status().ToString();
  EXPECT_TRUE(pick->ok) << out.str();
  EXPECT_EQ(pick->picks, 4) << out.str();
  if (std::getenv("BINPICK_VERBOSE")) std::cout << out.str();
  robot.reset();
  master->Stop();
  handler.Shutdown();
  sim->Stop();
}

TEST(PlaneCalibrationService, HandlesOnlyThe2DKind) {
  const Cell cell = testing::LoadTwodCell();
  std::shared_ptr<SyntheticPlaneCamera> camera = std::move(SyntheticPlaneCamera::Create(cell).value());
  PlaneCalibrationService service(camera, std::make_shared<PlaneCalibrationStore>(), {});
  EXPECT_EQ(service.Start(CalibrationKind::kAuto, Pose::Identity()).code(), Status::Code::kUnavailable);
  EXPECT_EQ(service.Accumulate(CalibrationKind::kManual, Pose::Identity()).status().code(),
            Status::Code::kUnavailable);
  EXPECT_FALSE(service.Accumulate(CalibrationKind::kAuto2D, Pose::Identity()).ok());  // not started
}

// The robot is told DONE (34) either way, the status seed 000's loop stops
// on; a fit that fails is reported by Finish and publishes nothing.
TEST(PlaneCalibrationService, ACollinearGridEndsTheCalibrationAndFinishReportsTheFailedFit) {
  const Cell cell = testing::LoadTwodCell();
  std::shared_ptr<SyntheticPlaneCamera> camera = std::move(SyntheticPlaneCamera::Create(cell).value());
  auto store = std::make_shared<PlaneCalibrationStore>();
  PlaneCalibrationOptions options;
  options.grid_x = 5;
  options.grid_y = 1;  // every point on the line y = 0
  PlaneCalibrationService service(camera, store, options);
  Pose X = Pose::Identity();
  ASSERT_TRUE(service.Start(CalibrationKind::kAuto2D, X).ok());
  for (int i = 0; i < 5; ++i) {
    Result<CalibrationStep> step = service.Accumulate(CalibrationKind::kAuto2D, X);
    ASSERT_TRUE(step.ok()) << step.status().ToString();
    ASSERT_FALSE(step->done);
    X = *step->next_X_BF;
  }
  Result<CalibrationStep> last = service.Accumulate(CalibrationKind::kAuto2D, X);
  ASSERT_TRUE(last.ok()) << last.status().ToString();
  EXPECT_TRUE(last->done);
  EXPECT_FALSE(service.last().has_value());
  EXPECT_EQ(service.Finish(CalibrationKind::kAuto2D).code(), Status::Code::kInvalidArgument);
  EXPECT_EQ(store->Get(), nullptr);
}

// A grid point where the marker is not found is skipped: the next point is
// proposed and the fit uses the points seen.
TEST(PlaneCalibrationService, AGridPointWithoutTheMarkerIsSkipped) {
  const Cell cell = testing::LoadTwodCell();
  std::shared_ptr<SyntheticPlaneCamera> camera = std::move(SyntheticPlaneCamera::Create(cell).value());
  auto store = std::make_shared<PlaneCalibrationStore>();
  PlaneCalibrationService service(camera, store, {});  // 5 x 4 grid
  Pose X = Pose::Identity();
  ASSERT_TRUE(service.Start(CalibrationKind::kAuto2D, X).ok());
  int skipped = 0;
  for (int i = 0; i <= 20; ++i) {
    // The third grid point: the robot is 2 m away, the marker out of the image.
    Pose at = X;
    if (i == 3) at.translation().x() += 2.0;
    Result<CalibrationStep> step = service.Accumulate(CalibrationKind::kAuto2D, at);
    ASSERT_TRUE(step.ok()) << i << ": " << step.status().ToString();
    skipped += step->good ? 0 : 1;
    if (i < 20) {
      ASSERT_FALSE(step->done) << i;
      X = *step->next_X_BF;
    } else {
      EXPECT_TRUE(step->done);
    }
  }
  EXPECT_EQ(skipped, 1);
  ASSERT_TRUE(service.last().has_value());
  EXPECT_EQ(service.last()->points, 20);  // the centre and 19 of the 20 grid points
  EXPECT_TRUE(service.Finish(CalibrationKind::kAuto2D).ok());
  EXPECT_NE(store->Get(), nullptr);
}

}  // namespace
}  // namespace bp
