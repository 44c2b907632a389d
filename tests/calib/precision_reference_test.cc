// Precision-check references (RC 50) survive a restart: the reference a
// first check defines is written atomically next to the hand-eye file, and a
// new server reading it measures the next check against it (51 with the
// small repeatability error, not 0 "reference defined"), over loopback.
#include <gtest/gtest.h>

#include <filesystem>

#include "calib/calibration_camera.h"
#include "calib/hand_eye_service.h"
#include "calib/precision_check.h"
#include "comms/daoai_server.h"
#include "comms/request_handler.h"
#include "comms/robot_client.h"
#include "tests/calib/calib_test_util.h"
#include "tests/testing/files.h"

namespace bp {
namespace {

class NoParts final : public GraspPlanner {
 public:
  Result<CaptureHandle> Capture(const PlanRequest&) override { return Status::Unavailable("no parts"); }
  Result<PlanResult> Plan(const PlanRequest&, const CapturedScene&) override { return PlanResult{}; }
};

// One binpickd run: the precision check with its reference file, a robot.
struct Server {
  Server(const Cell& cell, const std::string& reference_file) {
    camera = std::make_shared<SimulatedCalibrationCamera>(cell.camera, *cell.calibration);
    auto state = std::make_shared<HandEyeState>(cell.camera.X_BC);
    PrecisionCheckOptions o;
    o.reference_file = reference_file;
    check = std::make_shared<PrecisionCheckPlanner>(std::make_shared<NoParts>(), cell, camera, state, o);
    load = check->LoadReferences();
    handler = std::make_unique<RequestHandler>(cell, check, nullptr);
    DaoaiServerOptions so;
    so.port = 0;
    server = std::move(DaoaiServer::Start(*handler, so).value());
    RobotClientOptions ro;
    ro.port = server->port();
    ro.version = cell.robot.protocol_version;
    ro.robot_type = cell.robot.model.type;
    ro.convention = cell.robot.model.convention;
    robot = std::move(RobotClient::Connect(ro).value());
  }
  ~Server() {
    robot.reset();
    server->Stop();
    handler->Shutdown();
  }
  std::shared_ptr<SimulatedCalibrationCamera> camera;
  std::shared_ptr<PrecisionCheckPlanner> check;
  Status load;
  std::unique_ptr<RequestHandler> handler;
  std::unique_ptr<DaoaiServer> server;
  std::unique_ptr<RobotClient> robot;
};

TEST(PrecisionReference, FileSitsNextToTheHandEyeFile) {
  Cell cell = testing::CalibCell(false);
  cell.camera.hand_eye_file = "/cells/line3.calibration.yaml";
  EXPECT_EQ(PrecisionReferenceFile(cell), "/cells/line3.calibration.precision.yaml");
  cell.camera.hand_eye_file.clear();
  EXPECT_EQ(PrecisionReferenceFile(cell), "");
}

TEST(PrecisionReference, SurvivesARestartAndTheNextCheckMeasuresAgainstIt) {
  const Cell cell = testing::CalibCell(false);
  const std::string file = testing::FreshDir("precision_ref") + "/hand_eye.precision.yaml";
  {
    Server first(cell, file);
    ASSERT_TRUE(first.load.ok()) << first.load.ToString();  // no file yet
    Result<RobotReply> define = first.robot->Call(daoai::kPrecisionCheck, 0);
    ASSERT_TRUE(define.ok()) << define.status().ToString();
    ASSERT_EQ(define->status, daoai::kPrecisionCheckSuccess);
    EXPECT_EQ(define->raw.payload[0], 0);  // reference defined
  }
  ASSERT_TRUE(std::filesystem::exists(file));
  EXPECT_TRUE(AtomicTempFiles(file).empty());

  Server second(cell, file);
  ASSERT_TRUE(second.load.ok()) << second.load.ToString();
  // A restarted simulator would draw the very same image noise as the check
  // that defined the reference (error exactly 0): move on one draw.
  ASSERT_TRUE(second.camera->CapturePrecisionTarget(Pose::Identity()).ok());
  Result<RobotReply> check = second.robot->Call(daoai::kPrecisionCheck, 0);
  ASSERT_TRUE(check.ok());
  ASSERT_EQ(check->status, daoai::kPrecisionCheckSuccess);
  EXPECT_GT(check->raw.payload[0], 0) << "a restart must not redefine the reference";
  EXPECT_LT(check->payload[0], 0.1);  // mm: image noise only
  // The loaded reference is the one measured before the restart: a camera
  // bumped 2 mm since shows up as 2 mm.
  Pose bumped = second.camera->true_pose();
  bumped.translation() += Vec3(0, 0.002, 0);
  second.camera->set_true_pose(bumped);
  Result<RobotReply> moved = second.robot->Call(daoai::kPrecisionCheck, 0);
  ASSERT_TRUE(moved.ok());
  ASSERT_EQ(moved->status, daoai::kPrecisionCheckSuccess);
  EXPECT_NEAR(moved->payload[0], 2.0, 0.3);
}

TEST(PrecisionReference, ACorruptFileIsReportedWithItsPath) {
  const Cell cell = testing::CalibCell(false);
  const std::string dir = testing::FreshDir("precision_bad");
  const std::string file = dir + "/hand_eye.precision.yaml";
  testing::WriteText(file, "references:\n  - task: 0\n    target_B: [0.6, 0.0]\n    hand_eye: [1]\n");
  Server s(cell, file);
  EXPECT_EQ(s.load.code(), Status::Code::kCorruption);
  EXPECT_NE(s.load.message().find(file), std::string::npos) << s.load.ToString();
  EXPECT_NE(s.load.message().find("target_B"), std::string::npos) << s.load.ToString();
}

}  // namespace
}  // namespace bp
