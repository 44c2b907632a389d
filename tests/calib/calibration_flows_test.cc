// Hand-eye calibration over the protocols, against the simulator's ground
// truth: the DaoAI flows (seed robot programs over a loopback socket, both
// versions), guidance (version 1), the GRI HEC actions (both formats), the
// result file (atomic, previous one kept on failure and on a crash), and the
// precision check (RC 50).
#include <sys/wait.h>
#include <unistd.h>

#include <gtest/gtest.h>

#include <atomic>
#include <filesystem>
#include <future>
#include <thread>
#include <sstream>

#include "calib/board.h"
#include "calib/calibration_camera.h"
#include "calib/hand_eye_service.h"
#include "calib/precision_check.h"
#include "comms/daoai_server.h"
#include "comms/gri_handler.h"
#include "comms/request_handler.h"
#include "comms/robot_client.h"
#include "comms/robot_flows.h"
#include "core/conventions.h"
#include "tests/calib/calib_test_util.h"
#include "tests/testing/files.h"
#include "tests/testing/run_command.h"

namespace bp {
namespace {

class NoPartsPlanner final : public GraspPlanner {
 public:
  Result<CaptureHandle> Capture(const PlanRequest&) override { return Status::Unavailable("no parts"); }
  Result<PlanResult> Plan(const PlanRequest&, const CapturedScene&) override { return PlanResult{}; }
};

// A server (RequestHandler + DaoAI socket) with the real calibration service
// and precision check, and a robot connected to it.
struct Rig {
  // `version` 1: a seed 004 robot (meta_2 1) on a socket_v1 cell; 2: a seed
  // 000 robot sending meta_2 2 on a vision_pilot cell.
  Rig(Cell c, int version, const std::string& result_file) : cell(std::move(c)) {
    cell.robot.dialect = version == 1 ? DaoaiDialect::kSocketV1 : DaoaiDialect::kVisionPilot;
    camera = std::make_shared<SimulatedCalibrationCamera>(cell.camera, *cell.calibration);
    state = std::make_shared<HandEyeState>(cell.camera.eye_in_hand ? cell.camera.X_FC : cell.camera.X_BC);
    HandEyeServiceOptions o;
    o.result_file = result_file;
    auto svc = std::make_unique<HandEyeCalibrationService>(cell, camera, state, nullptr, o);
    service = svc.get();
    planner = std::make_shared<PrecisionCheckPlanner>(std::make_shared<NoPartsPlanner>(), cell, camera, state);
    handler = std::make_unique<RequestHandler>(cell, planner, std::move(svc));
    DaoaiServerOptions so;
    so.port = 0;
    server = std::move(DaoaiServer::Start(*handler, so).value());
    RobotClientOptions ro;
    ro.port = server->port();
    ro.version = version;
    ro.dialect = cell.robot.dialect;
    ro.robot_type = cell.robot.model.type;
    ro.convention = cell.robot.model.convention;
    robot = std::move(RobotClient::Connect(ro).value());
  }
  ~Rig() {
    robot.reset();
    server->Stop();
    handler->Shutdown();
  }
  // Waits for calibration work already posted (a no-op job on the same sequence).
  void Drain() {
    std::promise<void> p;
    EXPECT_TRUE(handler->RunCalibration([&p](CalibrationService&) { p.set_value(); }));
    p.get_future().wait();
  }

  Cell cell;
  std::shared_ptr<SimulatedCalibrationCamera> camera;
  std::shared_ptr<HandEyeState> state;
  HandEyeCalibrationService* service = nullptr;
  std::shared_ptr<PrecisionCheckPlanner> planner;
  std::unique_ptr<RequestHandler> handler;
  std::unique_ptr<DaoaiServer> server;
  std::unique_ptr<RobotClient> robot;
};

class DaoaiCalibration : public ::testing::TestWithParam<int> {
 protected:
  int version() const { return GetParam(); }
};

TEST_P(DaoaiCalibration, AutoFlowRecoversTheTrueTransformWithinTargets) {
  const std::string file = testing::FreshDir("auto") + "/hand_eye.yaml";
  Rig rig(testing::CalibCell(false), version(), file);
  FlowOptions o;
  o.flow = "calib-auto";
  o.calib_start_X_BF = BoardFacingStartPose(rig.cell);
  std::ostringstream out;
  Result<FlowSummary> s = RunFlow(*rig.robot, o, out);
  ASSERT_TRUE(s.ok()) << s.status().ToString();
  EXPECT_TRUE(s->ok) << out.str();
  EXPECT_EQ(s->last_status, daoai::kDoneCalibration) << out.str();
  rig.Drain();
  ASSERT_TRUE(rig.service->last_solution().has_value()) << out.str();
  const HandEyeSolution sol = *rig.service->last_solution();
  EXPECT_LE(sol.poses, 15);
  const Pose& truth = rig.cell.calibration->true_pose;
  EXPECT_LT(TranslationErrorMm(sol.X, truth), 0.5);
  EXPECT_LT(RotationErrorDeg(sol.X, truth), 0.05);
  // The new pose is in use and on disk, where the cell loader reads it.
  EXPECT_TRUE(rig.state->Get().isApprox(sol.X));
  const std::string text = testing::ReadBytes(file);
  EXPECT_NE(text.find("pose: {xyz: ["), std::string::npos);
  EXPECT_NE(text.find("poses_used:"), std::string::npos);
  EXPECT_NE(text.find("timestamp: "), std::string::npos);
}

TEST_P(DaoaiCalibration, ManualFlowSolvesWhenTheRobotStops) {
  const std::string file = testing::FreshDir("manual") + "/hand_eye.yaml";
  Rig rig(testing::CalibCell(false), version(), file);
  FlowOptions o;
  o.flow = "calib-manual";
  o.calib_start_X_BF = BoardFacingStartPose(rig.cell);
  std::ostringstream out;
  Result<FlowSummary> s = RunFlow(*rig.robot, o, out);
  ASSERT_TRUE(s.ok()) << s.status().ToString();
  EXPECT_TRUE(s->ok) << out.str();
  // Version 2's stop has no answer: wait for the server to have read it.
  for (int i = 0; i < 500 && !rig.service->last_solution(); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
    rig.Drain();
  }
  ASSERT_TRUE(rig.service->last_solution().has_value()) << out.str();
  const Pose& truth = rig.cell.calibration->true_pose;
  EXPECT_LT(TranslationErrorMm(rig.service->last_solution()->X, truth), 1.0);
  EXPECT_LT(RotationErrorDeg(rig.service->last_solution()->X, truth), 0.1);
  EXPECT_TRUE(std::filesystem::exists(file));
}

TEST_P(DaoaiCalibration, EyeInHandAutoFlow) {
  Rig rig(testing::CalibCell(true), version(), "");
  FlowOptions o;
  o.flow = "calib-auto";
  o.calib_start_X_BF = BoardFacingStartPose(rig.cell);
  std::ostringstream out;
  Result<FlowSummary> s = RunFlow(*rig.robot, o, out);
  ASSERT_TRUE(s.ok());
  EXPECT_TRUE(s->ok) << out.str();
  rig.Drain();
  ASSERT_TRUE(rig.service->last_solution().has_value()) << out.str();
  const Pose& truth = rig.cell.calibration->true_pose;
  EXPECT_LT(TranslationErrorMm(rig.service->last_solution()->X, truth), 0.5);
  EXPECT_LT(RotationErrorDeg(rig.service->last_solution()->X, truth), 0.05);
}

TEST_P(DaoaiCalibration, BoardOutOfViewIsAnsweredAsSuch) {
  Rig rig(testing::CalibCell(false), version(), "");
  Pose away = BoardFacingStartPose(rig.cell);
  away.translation() += Vec3(0.6, 0, 0);
  rig.robot->SetPose(away);
  ASSERT_EQ(rig.robot->Call(daoai::kStartManualCalibration)->status, daoai::kModeCalibration);
  // Manual accumulate where the camera cannot see the board: not accumulated (-1).
  EXPECT_EQ(rig.robot->Call(daoai::kManualAccumulatePose)->status, daoai::kUnknownCommand);
  // An auto calibration cannot start from there either: the robot is told
  // to stay (its own pose, never a zero pose: seed 000's loop moves to every
  // answer but 33), and after three failed views in a row the calibration
  // ends with 33, the status the seed's loop stops on.
  ASSERT_EQ(rig.robot->Call(daoai::kStartAutoCalibration)->status, daoai::kModeAutoCalibration);
  for (int i = 0; i < 3; ++i) {
    Result<RobotReply> r = rig.robot->Call(daoai::kAutoAccumulatePose);
    ASSERT_TRUE(r.ok());
    EXPECT_EQ(r->status, i < 2 ? daoai::kModeAutoCalibration : daoai::kDoneCalibration) << i;
    ASSERT_TRUE(r->X_BT);
    EXPECT_LT((r->X_BT->translation() - away.translation()).norm(), 2e-4) << i;
    EXPECT_LT(RotationErrorDeg(*r->X_BT, away), 0.05) << i;
  }
  rig.Drain();
  EXPECT_EQ(rig.service->poses(), 0u);
  EXPECT_EQ(rig.robot->Call(daoai::kAutoAccumulatePose)->status, daoai::kUnknownCommand);
}

TEST_P(DaoaiCalibration, PrecisionCheckMeasuresACameraThatMoved) {
  Rig rig(testing::CalibCell(false), version(), "");
  // The first check defines the reference; repeated checks see only noise.
  Result<RobotReply> first = rig.robot->Call(daoai::kPrecisionCheck, 0);
  ASSERT_TRUE(first.ok());
  ASSERT_EQ(first->status, daoai::kPrecisionCheckSuccess);
  EXPECT_EQ(first->raw.payload[0], 0);
  double worst = 0;
  for (int i = 0; i < 5; ++i) {
    Result<RobotReply> r = rig.robot->Call(daoai::kPrecisionCheck, 0);
    ASSERT_EQ(r->status, daoai::kPrecisionCheckSuccess);
    worst = std::max(worst, r->payload[0]);
  }
  EXPECT_LT(worst, 0.1);  // mm: repeatability target
  // Bump the camera by 2 mm sideways: the check reports it.
  Pose bumped = rig.camera->true_pose();
  bumped.translation() += Vec3(0.002, 0, 0);
  rig.camera->set_true_pose(bumped);
  Result<RobotReply> r = rig.robot->Call(daoai::kPrecisionCheck, 0);
  ASSERT_EQ(r->status, daoai::kPrecisionCheckSuccess);
  EXPECT_NEAR(r->payload[0], 2.0, 0.3);
  // A camera turned away from the target does not find it: 52.
  Pose turned = bumped;
  turned.linear() = turned.linear() * Mat3(Eigen::AngleAxisd(0.8, Vec3::UnitX()));
  rig.camera->set_true_pose(turned);
  EXPECT_EQ(rig.robot->Call(daoai::kPrecisionCheck, 0)->status, daoai::kPrecisionCheckFail);
}

INSTANTIATE_TEST_SUITE_P(Versions, DaoaiCalibration, ::testing::Values(1, 2),
                         [](const auto& info) { return "V" + std::to_string(info.param); });

TEST(GuidanceCalibration, Version1AnswersGoodBadAndDone) {
  Rig rig(testing::CalibCell(false), 1, "");
  const Pose start = BoardFacingStartPose(rig.cell);
  rig.robot->SetPose(start);
  EXPECT_EQ(rig.robot->Call(daoai::kGuidanceCalibration)->status, daoai::kGuidanceGood);
  // The same pose again adds nothing: bad.
  EXPECT_EQ(rig.robot->Call(daoai::kGuidanceCalibration)->status, daoai::kGuidanceBad);
  // A pose where the board is out of view: bad, with the robot's own pose
  // (seed 004 does not print its guidance program: one that moves to the
  // answer stays where it is, never goes to the base origin).
  Pose away = start;
  away.translation() += Vec3(0.6, 0, 0);
  rig.robot->SetPose(away);
  Result<RobotReply> bad = rig.robot->Call(daoai::kGuidanceCalibration);
  ASSERT_TRUE(bad.ok());
  EXPECT_EQ(bad->status, daoai::kGuidanceBad);
  ASSERT_TRUE(bad->X_BT);
  EXPECT_LT((bad->X_BT->translation() - away.translation()).norm(), 2e-4);
  EXPECT_LT(RotationErrorDeg(*bad->X_BT, away), 0.05);
  // Planned poses: good until enough, then done.
  const Vec3 c_B = rig.cell.camera.X_BC.translation();
  const Vec3 p_B = rig.camera->true_pose() * (rig.camera->TrueX_CT(start) * BoardCentre(*rig.cell.calibration));
  const std::vector<Pose> plan = HandEyeCalibrationService::PlanAround(start, p_B, c_B, 11);
  int status = 0;
  for (size_t i = 0; i < plan.size(); ++i) {
    rig.robot->SetPose(plan[i]);
    status = rig.robot->Call(daoai::kGuidanceCalibration)->status;
    if (i + 1 < plan.size()) {
      EXPECT_EQ(status, daoai::kGuidanceGood) << i;
    }
  }
  EXPECT_EQ(status, daoai::kDoneGuidanceCalibration);
  rig.Drain();
  ASSERT_TRUE(rig.service->last_solution().has_value());
  EXPECT_LT(TranslationErrorMm(rig.service->last_solution()->X, rig.cell.calibration->true_pose), 0.5);
}

// Calibrates once through the service to have a result file on disk.
void CalibrateOnce(HandEyeCalibrationService& svc, const Cell& cell, const SimulatedCalibrationCamera& camera,
                   int poses) {
  const Pose start = BoardFacingStartPose(cell);
  const Vec3 p_B = camera.true_pose() * (camera.TrueX_CT(start) * BoardCentre(*cell.calibration));
  std::vector<Pose> plan = {start};
  for (const Pose& p : HandEyeCalibrationService::PlanAround(start, p_B, cell.camera.X_BC.translation(), poses - 1)) {
    plan.push_back(p);
  }
  ASSERT_TRUE(svc.Start(CalibrationKind::kManual, start).ok());
  for (int i = 0; i < poses; ++i) ASSERT_TRUE(svc.Accumulate(CalibrationKind::kManual, plan[i]).ok());
}

TEST(ResultFile, TooFewPosesAreAnErrorAndThePreviousCalibrationStays) {
  const std::string file = testing::FreshDir("few") + "/hand_eye.yaml";
  const Cell cell = testing::CalibCell(false);
  auto camera = std::make_shared<SimulatedCalibrationCamera>(cell.camera, *cell.calibration);
  auto state = std::make_shared<HandEyeState>(cell.camera.X_BC);
  HandEyeServiceOptions o;
  o.result_file = file;
  HandEyeCalibrationService svc(cell, camera, state, nullptr, o);
  CalibrateOnce(svc, cell, *camera, 8);
  ASSERT_TRUE(svc.Finish(CalibrationKind::kManual).ok());
  const std::string before = testing::ReadBytes(file);
  const Pose in_use = state->Get();
  CalibrateOnce(svc, cell, *camera, 3);  // min_poses is 6
  const Status s = svc.Finish(CalibrationKind::kManual);
  EXPECT_EQ(s.code(), Status::Code::kInvalidArgument);
  EXPECT_NE(s.message().find("needs 6 poses"), std::string::npos) << s.message();
  EXPECT_EQ(testing::ReadBytes(file), before);
  EXPECT_TRUE(state->Get().isApprox(in_use));
}

TEST(ResultFile, CrashBetweenWriteAndRenameLeavesTheOldCalibration) {
  const std::string file = testing::FreshDir("crash") + "/hand_eye.yaml";
  const Cell cell = testing::CalibCell(false);
  testing::WriteText(file, "pose: {xyz: [0.7, 0, 1.05], rpy_deg: [180, 0, 0]}\n");
  const std::string before = testing::ReadBytes(file);
  const pid_t pid = fork();
  ASSERT_GE(pid, 0);
  if (pid == 0) {
    auto camera = std::make_shared<SimulatedCalibrationCamera>(cell.camera, *cell.calibration);
    auto state = std::make_shared<HandEyeState>(cell.camera.X_BC);
    HandEyeServiceOptions o;
    o.result_file = file;
    o.write.before_rename = [] { _exit(42); };  // the crash
    HandEyeCalibrationService svc(cell, camera, state, nullptr, o);
    CalibrateOnce(svc, cell, *camera, 8);
    (void)svc.Finish(CalibrationKind::kManual);
    _exit(1);  // never reached: the write crashes first
  }
  int status = 0;
  ASSERT_EQ(waitpid(pid, &status, 0), pid);
  ASSERT_TRUE(WIFEXITED(status));
  EXPECT_EQ(WEXITSTATUS(status), 42);
  EXPECT_EQ(testing::ReadBytes(file), before);
}

TEST(ResultFile, CellLoaderUsesTheSavedCalibration) {
  const std::string dir = testing::FreshDir("load");
  const std::string file = dir + "/hand_eye.yaml";
  const Cell cell = testing::CalibCell(false);
  auto camera = std::make_shared<SimulatedCalibrationCamera>(cell.camera, *cell.calibration);
  auto state = std::make_shared<HandEyeState>(cell.camera.X_BC);
  HandEyeServiceOptions o;
  o.result_file = file;
  HandEyeCalibrationService svc(cell, camera, state, nullptr, o);
  CalibrateOnce(svc, cell, *camera, 10);
  ASSERT_TRUE(svc.Finish(CalibrationKind::kManual).ok());
  // The default cell with camera.hand_eye_file pointing at the result.
  std::string yaml = testing::ReadBytes(std::string(BINPICK_SOURCE_DIR) + "/assets/cells/default.yaml");
  const std::string key = "  # hand_eye_file: calib/hand_eye.yaml";
  ASSERT_NE(yaml.find(key), std::string::npos);
  yaml.replace(yaml.find(key), key.size(), "  hand_eye_file: " + file);
  Result<Cell> loaded = ParseCell(yaml, std::string(BINPICK_SOURCE_DIR) + "/assets/cells/default.yaml");
  ASSERT_TRUE(loaded.ok()) << loaded.status().ToString();
  EXPECT_LT(TranslationErrorMm(loaded->camera.X_BC, svc.last_solution()->X), 1e-6);
  EXPECT_LT(RotationErrorDeg(loaded->camera.X_BC, svc.last_solution()->X), 1e-6);
}

// last_solution() and poses() are read on another thread while the steps
// run, as the calibration tests and binpick calib do with the request
// handler's job thread (under TSan, RobotCommandCalibration.* reported the
// read of last_ there as a race). Here a reader polls both while this thread
// calibrates twice; every solution it sees is a whole one. Run under TSan
// (scripts/test.sh's tsan stage builds bp_calib_tests only with the TSan
// extension), this test is where an unguarded read shows.
TEST(HandEyeServiceThreads, LastSolutionAndPosesAreReadWhileStepsRun) {
  const Cell cell = testing::CalibCell(false);
  auto camera = std::make_shared<SimulatedCalibrationCamera>(cell.camera, *cell.calibration);
  auto state = std::make_shared<HandEyeState>(cell.camera.X_BC);
  HandEyeCalibrationService svc(cell, camera, state);
  constexpr int kPoses = 8;
  std::atomic<bool> done{false};
  int reads = 0, solutions = 0, bad_solutions = 0, bad_counts = 0;
  std::thread reader([&] {
    for (bool last = false; !last;) {
      last = done.load();
      const size_t n = svc.poses();
      if (n > static_cast<size_t>(kPoses)) ++bad_counts;
      if (const std::optional<HandEyeSolution> sol = svc.last_solution()) {
        ++solutions;
        if (sol->poses != kPoses || TranslationErrorMm(sol->X, cell.calibration->true_pose) > 0.5) ++bad_solutions;
      }
      ++reads;
    }
  });
  for (int round = 0; round < 2; ++round) {
    CalibrateOnce(svc, cell, *camera, kPoses);
    EXPECT_EQ(svc.poses(), static_cast<size_t>(kPoses));
    EXPECT_TRUE(svc.Finish(CalibrationKind::kManual).ok());
  }
  done = true;
  reader.join();
  EXPECT_GT(reads, 1);
  EXPECT_GE(solutions, 1);  // at least the read after `done`
  EXPECT_EQ(bad_solutions, 0);
  EXPECT_EQ(bad_counts, 0);
}

TEST(Auto2D, ForwardedToTheGivenServiceElseUnavailable) {
  const Cell cell = testing::CalibCell(false);
  auto camera = std::make_shared<SimulatedCalibrationCamera>(cell.camera, *cell.calibration);
  auto state = std::make_shared<HandEyeState>(cell.camera.X_BC);
  HandEyeCalibrationService none(cell, camera, state);
  EXPECT_EQ(none.Start(CalibrationKind::kAuto2D, Pose::Identity()).code(), Status::Code::kUnavailable);
  auto counting = std::make_unique<CountingCalibrationService>(2);
  CountingCalibrationService* c = counting.get();
  HandEyeCalibrationService with(cell, camera, state, std::move(counting));
  ASSERT_TRUE(with.Start(CalibrationKind::kAuto2D, Pose::Identity()).ok());
  ASSERT_TRUE(with.Accumulate(CalibrationKind::kAuto2D, Pose::Identity()).ok());
  EXPECT_EQ(c->poses().size(), 1u);
  EXPECT_EQ(with.poses(), 0u);
}

// ---- GRI ------------------------------------------------------------------

class GriHec : public ::testing::TestWithParam<gri::Format> {
 protected:
  gri::Response Send(GriHandler& gri, uint8_t action, const std::optional<Pose>& X_BF, int32_t d1 = 0,
                     int32_t d2 = 0) {
    gri::Request r;
    r.format = GetParam();
    r.action = action;
    r.pose_format = 0;
    r.data = {d1, d2, 0, 0};
    if (X_BF) {
      r.pose_format = 3;  // M_EULER_DEGREE (positions in mm in the official format)
      std::array<double, 7> v = EncodeGriPose(*X_BF, static_cast<GriPoseFormat>(3)).value();
      if (r.format == gri::Format::kOfficial) {
        for (int i = 0; i < 3; ++i) v[i] *= 1000.0;
      }
      r.pose = v;
    }
    std::promise<gri::Response> p;
    gri.HandleAsync(r, client_, [&p](GriHandler::Reply reply) { p.set_value(reply()); });
    return p.get_future().get();
  }
  int32_t Code(gri::Code c) const { return gri::WireErrorCode(GetParam(), c); }
  ClientContext client_;
};

TEST_P(GriHec, InitSetPosesCalibrate) {
  Rig rig(testing::CalibCell(false), 2, "");
  GriHandler gri(*rig.handler);
  const Pose start = BoardFacingStartPose(rig.cell);
  // Before HEC_INIT nothing is stored.
  EXPECT_EQ(Send(gri, gri::kHecSetPose, start, 0, 1).error_code, Code(gri::Code::kHecInitError));
  EXPECT_EQ(Send(gri, gri::kHecInit, std::nullopt, 1).error_code, 0);
  const Vec3 p_B = rig.camera->true_pose() * (rig.camera->TrueX_CT(start) * BoardCentre(*rig.cell.calibration));
  std::vector<Pose> poses = {start};
  for (const Pose& p : HandEyeCalibrationService::PlanAround(start, p_B, rig.cell.camera.X_BC.translation(), 7)) {
    poses.push_back(p);
  }
  // Too few for a solve: insufficient detection (and nothing changes).
  EXPECT_EQ(Send(gri, gri::kHecSetPose, poses[0], 1, 1).error_code, 0);
  EXPECT_EQ(Send(gri, gri::kHecCalibrate, std::nullopt, 1).error_code, Code(gri::Code::kHecInsufficientDetection));
  EXPECT_FALSE(rig.service->last_solution().has_value());
  EXPECT_EQ(Send(gri, gri::kHecInit, std::nullopt, 1).error_code, 0);
  for (int slot = 0; slot < 8; ++slot) {
    EXPECT_EQ(Send(gri, gri::kHecSetPose, poses[slot], 1, slot).error_code, 0) << slot;
  }
  // A slot sent again replaces its pose; a slot out of range and a pose
  // without the board are errors.
  EXPECT_EQ(Send(gri, gri::kHecSetPose, poses[3], 1, 3).error_code, 0);
  EXPECT_EQ(Send(gri, gri::kHecSetPose, poses[3], 1, 9).error_code, Code(gri::Code::kHecSetPoseError));
  Pose away = start;
  away.translation() += Vec3(0.6, 0, 0);
  EXPECT_EQ(Send(gri, gri::kHecSetPose, away, 1, 2).error_code, Code(gri::Code::kHecSetPoseError));
  EXPECT_EQ(rig.service->poses(), 8u);
  EXPECT_EQ(Send(gri, gri::kHecCalibrate, std::nullopt, 1).error_code, 0);
  ASSERT_TRUE(rig.service->last_solution().has_value());
  EXPECT_LT(TranslationErrorMm(rig.service->last_solution()->X, rig.cell.calibration->true_pose), 0.5);
  // HEC_CALIBRATE again without HEC_INIT: init error.
  EXPECT_EQ(Send(gri, gri::kHecCalibrate, std::nullopt, 1).error_code, Code(gri::Code::kHecInitError));
}

TEST_P(GriHec, CellWithoutCalibrationIsAConfigError) {
  Cell cell = testing::CalibCell(false);
  cell.calibration.reset();
  RequestHandler handler(cell, std::make_shared<NoPartsPlanner>(), nullptr);
  GriHandler gri(handler);
  EXPECT_EQ(Send(gri, gri::kHecInit, std::nullopt, 1).error_code, Code(gri::Code::kHecConfigError));
  handler.Shutdown();
}

INSTANTIATE_TEST_SUITE_P(Formats, GriHec, ::testing::Values(gri::Format::kV2, gri::Format::kOfficial),
                         [](const auto& info) { return info.param == gri::Format::kV2 ? "V2" : "Official"; });

TEST(WireCodes, HecErrorsOfBothFormats) {
  using gri::Code;
  using gri::Format;
  EXPECT_EQ(gri::WireErrorCode(Format::kV2, Code::kHecConfigError), 17);
  EXPECT_EQ(gri::WireErrorCode(Format::kV2, Code::kHecInsufficientDetection), 21);
  EXPECT_EQ(gri::WireErrorCode(Format::kOfficial, Code::kHecConfigError), -14);
  EXPECT_EQ(gri::WireErrorCode(Format::kOfficial, Code::kHecInsufficientDetection), -18);
}

// `binpick robot --flow calib-*` against a server on binpickd's default cell:
// with the cell, the robot program starts where the board faces the camera
// (from the robot's nominal detection pose the board is not in view).
TEST(RobotCommandCalibration, SeedProgramsCalibrateAgainstTheDefaultCell) {
  Result<Cell> cell = LoadCellOrDefault("");
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  ASSERT_TRUE(cell->calibration.has_value());
  Rig rig(*cell, 2, "");
  const std::string robot = std::string(BINPICK_BINARY_DIR) + "/bin/binpick-robot --port " +
                            std::to_string(rig.server->port());
  const test::CommandRun automatic = test::RunCommand(robot + " --flow calib-auto");
  EXPECT_EQ(automatic.exit_code, 0) << automatic.out;
  EXPECT_NE(automatic.out.find("DONE_CALIBRATION(33)"), std::string::npos) << automatic.out;
  rig.Drain();
  ASSERT_TRUE(rig.service->last_solution().has_value()) << automatic.out;
  EXPECT_LT(TranslationErrorMm(rig.service->last_solution()->X, cell->calibration->true_pose), 0.5);
  const test::CommandRun manual = test::RunCommand(robot + " --flow calib-manual");
  EXPECT_EQ(manual.exit_code, 0) << manual.out;
  EXPECT_EQ(manual.out.find("UNKNOWN_COMMAND"), std::string::npos) << manual.out;
  EXPECT_EQ(test::RunCommand(robot + " --flow calib-auto --cell /no/such/cell.yaml").exit_code, 2);
}

}  // namespace
}  // namespace bp
