// The DaoAI server over real loopback sockets, with the scripted (test double)
// planner. Golden response bytes are written out by hand from the protocol
// table in docs/protocols.md; the grasp poses come from ScriptedPlanner.
#include "comms/daoai_server.h"

#include <gtest/gtest.h>

#include <atomic>
#include <cctype>
#include <cmath>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include "comms/calibration_service.h"
#include "comms/robot_client.h"
#include "tests/testing/scripted_planner.h"

namespace bp {
namespace {

using testing::MakeTestCell;
using testing::ScriptedPlanner;
using namespace std::chrono_literals;

std::string Hex(std::span<const uint8_t> bytes) {
  static const char* kDigits = "0123456789ABCDEF";
  std::string s;
  for (size_t i = 0; i < bytes.size(); ++i) {
    if (i > 0 && i % 4 == 0) s += ' ';
    s += kDigits[bytes[i] >> 4];
    s += kDigits[bytes[i] & 15];
  }
  return s;
}

std::string Normalize(const std::string& hex) {
  std::string digits;
  for (char c : hex) {
    if (std::isxdigit(static_cast<unsigned char>(c))) digits += static_cast<char>(std::toupper(c));
  }
  std::string s;
  for (size_t i = 0; i < digits.size(); ++i) {
    if (i > 0 && i % 8 == 0) s += ' ';
    s += digits[i];
  }
  return s;
}

// Responses (16 words: position[3] orientation[4] payload[6] status meta_1 meta_2).
// Status-only answers of a version-2 UR cell.
const char* kCalib10 = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "0000000A 00000007 00000002";
// Answers the robot moves to (4, 7, 11, 12, 21) carry its own pose, the
// request's (0.5, -0.25, 0.3) m, rotation vector (0, 0, 1.5708), unless they
// carry a planned one.
const char* kAuto33 = "00001388 FFFFF63C 00000BB8" "00000000 00000000 00003D5C 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "00000021 00000007 00000002";
const char* kPickUnknown = "00001388 FFFFF63C 00000BB8" "00000000 00000000 00003D5C 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "FFFFFFFF 00000007 00000002";
// Auto calibration: the counting service proposes the robot's own pose,
// (0.5, -0.25, 0.3) m, rotation vector (0, 0, 1.5708).
const char* kAuto11 = "00001388 FFFFF63C 00000BB8" "00000000 00000000 00003D5C 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "0000000B 00000007 00000002";
const char* k2D14 = "00001388 FFFFF63C 00000BB8" "00000000 00000000 00003D5C 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "0000000E 00000007 00000002";
const char* k2D34 = "00001388 FFFFF63C 00000BB8" "00000000 00000000 00003D5C 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "00000022 00000007 00000002";
const char* kCapture5 = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "00000005 00000007 00000002";
const char* kFail9 = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "00000009 00000007 00000002";
const char* kNoObj3 = "00001388 FFFFF63C 00000BB8" "00000000 00000000 00003D5C 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "00000003 00000007 00000002";
const char* kNoCf4 = "00001388 FFFFF63C 00000BB8" "00000000 00000000 00003D5C 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "00000004 00000007 00000002";
const char* kUnknown = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "FFFFFFFF 00000007 00000002";
// Task 0 grasps: (0.50 / 0.51 / 0.52, -0.1, 0.1) m, rotation vector (0, 0, pi/2);
// payload_1 = remaining incl. this x MULT, payload_2 = class x MULT.
const char* kPick0_3 = "00001388 FFFFFC18 000003E8" "00000000 00000000 00003D5C 00000000" "00007530 00000000 00000000 00000000 00000000 00000000" "00000002 00000007 00000002";
const char* kPick0_2 = "000013EC FFFFFC18 000003E8" "00000000 00000000 00003D5C 00000000" "00004E20 00002710 00000000 00000000 00000000 00000000" "00000002 00000007 00000002";
const char* kPick0_1 = "00001450 FFFFFC18 000003E8" "00000000 00000000 00003D5C 00000000" "00002710 00004E20 00000000 00000000 00000000 00000000" "00000002 00000007 00000002";
const char* kTask1Pick = "00001388 FFFFFCE0 000003E8" "00000000 00000000 00003D5C 00000000" "00007530 00000000 00000000 00000000 00000000 00000000" "00000002 00000007 00000002";
// Place task 2: DROP_OFF_POSE (6) at (0.5, -0.06, 0.1).
const char* kPlace = "00001388 FFFFFDA8 000003E8" "00000000 00000000 00003D5C 00000000" "00007530 00000000 00000000 00000000 00000000 00000000" "00000006 00000007 00000002";
const char* kEmpty = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "00000029 00000007 00000002";
const char* kNotEmpty = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "0000002A 00000007 00000002";
// 0.42 mm x MULT = 4200 in payload_1.
const char* kPrecOk = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00001068 00000000 00000000 00000000 00000000 00000000" "00000033 00000007 00000002";
const char* kPrecFail = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "00000034 00000007 00000002";
const char* kCfgOk = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "00000042 00000007 00000002";
const char* kCfgFail = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "00000043 00000007 00000002";
// A version-1 cell.
const char* kV1Unknown = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "FFFFFFFF 00000007 00000001";
// Seed 004's guidance answers carry the robot's own pose (Req's), never the base origin.
const char* kV1Good = "00001388 FFFFF63C 00000BB8" "00000000 00000000 00003D5C 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "0000000C 00000007 00000001";
const char* kV1Done32 = "00001388 FFFFF63C 00000BB8" "00000000 00000000 00003D5C 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "00000020 00000007 00000001";
const char* kV1NoImage4 = "00001388 FFFFF63C 00000BB8" "00000000 00000000 00003D5C 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "00000004 00000007 00000001";
const char* kV1NoObj3 = "00001388 FFFFF63C 00000BB8" "00000000 00000000 00003D5C 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "00000003 00000007 00000001";
const char* kV1Calib10 = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "0000000A 00000007 00000001";
const char* kV1Capture5 = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "00000005 00000007 00000001";
const char* kV1Pick0_3 = "00001388 FFFFFC18 000003E8" "00000000 00000000 00003D5C 00000000" "00007530 00000000 00000000 00000000 00000000 00000000" "00000002 00000007 00000001";
const char* kV1Fail9 = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "00000009 00000007 00000001";

// A request as a UR robot at (0.5, -0.25, 0.3) m, rotation vector
// (0, 0, 1.5708) sends it.
daoai::Request Req(int32_t command, int32_t payload_1 = 0, int32_t version = 2, int32_t meta_1 = 7) {
  daoai::Request r;
  r.position = {5000, -2500, 3000};
  r.orientation = {0, 0, 15708, 0};
  r.command = command;
  r.payload_1 = payload_1;
  r.meta_1 = meta_1;
  r.meta_2 = version;
  return r;
}

class DaoaiServerTest : public ::testing::Test {
 protected:
  void Start(DaoaiDialect dialect = DaoaiDialect::kVisionPilot,
             std::chrono::milliseconds read_timeout = 5000ms) {
    Start(MakeTestCell(dialect), read_timeout);
  }
  void Start(Cell cell, std::chrono::milliseconds read_timeout = 5000ms) {
    planner_ = std::make_shared<ScriptedPlanner>();
    handler_ = std::make_unique<RequestHandler>(
        std::move(cell), planner_, std::make_unique<CountingCalibrationService>(3));
    DaoaiServerOptions options;
    options.port = 0;
    options.read_timeout = read_timeout;
    auto server = DaoaiServer::Start(*handler_, options);
    ASSERT_TRUE(server.ok()) << server.status().ToString();
    server_ = std::move(*server);
    ASSERT_GT(server_->port(), 0);
  }

  void TearDown() override {
    if (server_) server_->Stop();
    if (handler_) handler_->Shutdown();
    server_.reset();
    handler_.reset();
  }

  std::unique_ptr<RobotClient> Connect(int version = 2) {
    RobotClientOptions o;
    o.port = server_->port();
    o.version = version;
    o.timeout = 5000ms;
    auto c = RobotClient::Connect(o);
    EXPECT_TRUE(c.ok()) << c.status().ToString();
    return c.ok() ? std::move(*c) : nullptr;
  }

  // Sends `request` and @returns the 64 response bytes as hex ("" on error).
  static std::string Exchange(RobotClient& c, const daoai::Request& request) {
    const auto out = daoai::EncodeRequest(request);
    if (!c.SendBytes(out.data(), out.size()).ok()) return "send failed";
    std::array<uint8_t, daoai::kResponseSize> in{};
    const Status s = c.ReceiveBytes(in.data(), in.size());
    if (!s.ok()) return s.ToString();
    return Hex(in);
  }

  // Sends a command whose robot script reads no answer, and checks none comes.
  static void ExpectNoResponse(RobotClient& c, const daoai::Request& request) {
    const auto out = daoai::EncodeRequest(request);
    ASSERT_TRUE(c.SendBytes(out.data(), out.size()).ok());
    c.set_timeout(150ms);
    uint8_t byte = 0;
    EXPECT_FALSE(c.ReceiveBytes(&byte, 1).ok()) << "command " << request.command
                                                << " must not be answered";
    c.set_timeout(5000ms);
  }

  std::shared_ptr<ScriptedPlanner> planner_;
  std::unique_ptr<RequestHandler> handler_;
  std::unique_ptr<DaoaiServer> server_;
};

#define EXPECT_RESPONSE(client, request, golden) \
  EXPECT_EQ(Exchange(client, request), Normalize(golden)) << "command " << (request).command

TEST_F(DaoaiServerTest, AnswersEveryCommandOfTheVisionPilotDialectWithGoldenBytes) {
  Start();
  auto c = Connect(2);
  ASSERT_TRUE(c);
  // -1 pose update: no response.
  ExpectNoResponse(*c, Req(daoai::kNoCommand));
  // Manual calibration: 1 -> 10, 6 -> 10, 2 -> nothing (the v2 script reads none).
  EXPECT_RESPONSE(*c, Req(daoai::kStartManualCalibration), kCalib10);
  EXPECT_RESPONSE(*c, Req(daoai::kManualAccumulatePose), kCalib10);
  ExpectNoResponse(*c, Req(daoai::kStopManualCalibration));
  // Accumulating outside the mode: UNKNOWN_COMMAND (the robot restarts the handshake).
  EXPECT_RESPONSE(*c, Req(daoai::kManualAccumulatePose), kUnknown);
  // Auto calibration: 4 -> 11 with the next pose, 7 -> 11 ... -> 33 after 3 poses.
  EXPECT_RESPONSE(*c, Req(daoai::kStartAutoCalibration), kAuto11);
  EXPECT_RESPONSE(*c, Req(daoai::kAutoAccumulatePose), kAuto11);
  EXPECT_RESPONSE(*c, Req(daoai::kAutoAccumulatePose), kAuto11);
  EXPECT_RESPONSE(*c, Req(daoai::kAutoAccumulatePose), kAuto33);
  // Guidance calibration: no answer in version 2.
  ExpectNoResponse(*c, Req(daoai::kGuidanceCalibration));
  // 2D auto calibration: 11 -> 14, 12 -> 14 ... -> 34.
  EXPECT_RESPONSE(*c, Req(daoai::kStart2DAutoCalibration), k2D14);
  EXPECT_RESPONSE(*c, Req(daoai::kAutoAccumulate2DPose), k2D14);
  EXPECT_RESPONSE(*c, Req(daoai::kAutoAccumulate2DPose), k2D14);
  EXPECT_RESPONSE(*c, Req(daoai::kAutoAccumulate2DPose), k2D34);
  // Pick before any capture: NO_OBJECT_FOUND.
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 0), kNoObj3);
  // Capture (20) then picks: remaining 3, 2, 1, then NO_OBJECT_FOUND with payload_1 = 0.
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 0), kCapture5);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 0), kPick0_3);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 0), kPick0_2);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 0), kPick0_1);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 0), kNoObj3);
  // Async capture (19) on task 1.
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcessAsync, 1), kCapture5);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 1), kTask1Pick);
  // Place task: DROP_OFF_POSE.
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 2), kCapture5);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 2), kPlace);
  // No collision-free grasp: 4 in version 2.
  ScriptedPlanner::Script blocked;
  blocked.grasps = 0;
  blocked.detections = 2;
  blocked.outcome = PlanResult::Outcome::kNoCollisionFree;
  planner_->SetScript(1, blocked);
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 1), kCapture5);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 1), kNoCf4);
  // Capture failure: 9, then the pick says NO_OBJECT_FOUND.
  ScriptedPlanner::Script broken;
  broken.capture_fails = true;
  planner_->SetScript(0, broken);
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 0), kFail9);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 0), kNoObj3);
  // Teach: no response; the planner receives the robot's pose.
  ExpectNoResponse(*c, Req(daoai::kSendPose, 3));
  // Empty box: task 3 scripted empty (few points, no detections), task 1 not.
  ScriptedPlanner::Script empty;
  empty.grasps = 0;
  empty.roi_points = 900;
  empty.largest_region_points = 500;
  planner_->SetScript(3, empty);
  EXPECT_RESPONSE(*c, Req(daoai::kCheckEmptyBox, 3), kEmpty);
  EXPECT_RESPONSE(*c, Req(daoai::kCheckEmptyBox, 1), kNotEmpty);
  // Precision: 51 with 0.42 mm, 52 when the target is not found.
  EXPECT_RESPONSE(*c, Req(daoai::kPrecisionCheck, 5), kPrecOk);
  ScriptedPlanner::Script lost;
  lost.precision_error_mm.reset();
  planner_->SetScript(5, lost);
  EXPECT_RESPONSE(*c, Req(daoai::kPrecisionCheck, 5), kPrecFail);
  // Camera configs 1 and 2 exist; 7 does not.
  EXPECT_RESPONSE(*c, Req(daoai::kSwitchConfig, 2), kCfgOk);
  EXPECT_RESPONSE(*c, Req(daoai::kSwitchConfig, 7), kCfgFail);
  // Unknown command, unknown task, bad meta: UNKNOWN_COMMAND.
  EXPECT_RESPONSE(*c, Req(99), kUnknown);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 9), kPickUnknown);
  EXPECT_RESPONSE(*c, Req(daoai::kSwitchConfig, 1, /*version=*/7), kUnknown);
  EXPECT_RESPONSE(*c, Req(daoai::kSwitchConfig, 1, 2, /*meta_1=*/55), kUnknown);

  // Side effects the robot cannot see (teaching has no response: let the
  // handler finish its work first).
  server_->Stop();
  handler_->Shutdown();
  ASSERT_EQ(planner_->taught().size(), 1u);
  EXPECT_EQ(planner_->taught()[0].task.id, 3);
  EXPECT_NEAR(planner_->taught()[0].X_BT.translation().x(), 0.5, 1e-9);
  EXPECT_EQ(handler_->camera_config_id(), 2);
}

TEST_F(DaoaiServerTest, AnswersEveryCommandOfTheSocketV1DialectWithGoldenBytes) {
  Start(DaoaiDialect::kSocketV1);
  auto c = Connect(1);
  ASSERT_TRUE(c);
  ExpectNoResponse(*c, Req(daoai::kNoCommand, 0, 1));
  EXPECT_RESPONSE(*c, Req(daoai::kStartManualCalibration, 0, 1), kV1Calib10);
  EXPECT_RESPONSE(*c, Req(daoai::kManualAccumulatePose, 0, 1), kV1Calib10);
  // Seed 004: STOP_MANUAL_CALIBRATION is acknowledged with UNKNOWN_COMMAND.
  EXPECT_RESPONSE(*c, Req(daoai::kStopManualCalibration, 0, 1), kV1Unknown);
  // Guidance: 12 (good) until enough poses, then 32.
  EXPECT_RESPONSE(*c, Req(daoai::kGuidanceCalibration, 0, 1), kV1Good);
  EXPECT_RESPONSE(*c, Req(daoai::kGuidanceCalibration, 0, 1), kV1Good);
  EXPECT_RESPONSE(*c, Req(daoai::kGuidanceCalibration, 0, 1), kV1Done32);
  // No capture yet: NO_IMAGE_CAPTURED (4 in version 1).
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 0, 1), kV1NoImage4);
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 0, 1), kV1Capture5);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 0, 1), kV1Pick0_3);
  // Version 1 has no NO_COLLISION_FREE_POSE: NO_OBJECT_FOUND instead.
  ScriptedPlanner::Script blocked;
  blocked.grasps = 0;
  blocked.detections = 2;
  blocked.outcome = PlanResult::Outcome::kNoCollisionFree;
  planner_->SetScript(1, blocked);
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 1, 1), kV1Capture5);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 1, 1), kV1NoObj3);
  // Capture failure: 9, then NO_IMAGE_CAPTURED.
  ScriptedPlanner::Script broken;
  broken.capture_fails = true;
  planner_->SetScript(0, broken);
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 0, 1), kV1Fail9);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 0, 1), kV1NoImage4);
  EXPECT_RESPONSE(*c, Req(42, 0, 1), kV1Unknown);
}

// Seed 000's programs send meta_2 = 1 (DAOAI_META_VERSION = 1) and pop up
// "interface version does not match" unless the answer carries it back; the
// rules are the cell's dialect whatever meta_2 says.
TEST_F(DaoaiServerTest, EchoesMeta2AndKeepsTheCellsDialect) {
  Start();  // vision_pilot (seed 000)
  auto c = Connect(1);
  ASSERT_TRUE(c);
  ExpectNoResponse(*c, Req(daoai::kStopManualCalibration, 0, 1));
  ExpectNoResponse(*c, Req(daoai::kGuidanceCalibration, 0, 1));
  ScriptedPlanner::Script blocked;
  blocked.grasps = 0;
  blocked.detections = 2;
  blocked.outcome = PlanResult::Outcome::kNoCollisionFree;
  planner_->SetScript(1, blocked);
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 1, 1), kV1Capture5);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 1, 1),  // NO_COLLISION_FREE_POSE, meta_2 = 1
                  "00001388 FFFFF63C 00000BB8" "00000000 00000000 00003D5C 00000000"
                  "00000000 00000000 00000000 00000000 00000000 00000000" "00000004 00000007 00000001");
  Result<RobotReply> r = c->Call(daoai::kSwitchConfig, 1);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->status, daoai::kSwitchConfigSuccess);
  EXPECT_EQ(r->raw.meta_2, 1);
  EXPECT_TRUE(r->warnings.empty()) << r->warnings[0];

  // A socket_v1 cell answers a robot sending meta_2 = 2 by seed 004's rules, with meta_2 = 2.
  TearDown();
  Start(DaoaiDialect::kSocketV1);
  auto v1 = Connect(2);
  ASSERT_TRUE(v1);
  EXPECT_RESPONSE(*v1, Req(daoai::kStopManualCalibration, 0, 2), kUnknown);
  EXPECT_RESPONSE(*v1, Req(daoai::kPickPose, 0, 2), kNoCf4);  // here 4 = NO_IMAGE_CAPTURED
}

// Seed 000's daoai_teach_pose() never sets payload_1: it sends what the last
// answer left in daoai_payload_1 (a remaining count after a pick pose).
TEST_F(DaoaiServerTest, TeachFilesThePoseOnTheLastPickTaskWhenPayload1IsOnlyWhatTheLastAnswerLeft) {
  Start();
  auto c = Connect(1);
  ASSERT_TRUE(c);
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 0, 1), kV1Capture5);
  Result<RobotReply> pick = c->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(pick.ok());
  ASSERT_EQ(pick->raw.payload[0], 30000);  // 3 left: the script's daoai_payload_1 is now 3
  ExpectNoResponse(*c, Req(daoai::kSendPose, 3, 1));  // stale 3 (task 3 is a pick task too)
  ExpectNoResponse(*c, Req(daoai::kSendPose, 2, 1));  // task 2 is a place task
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 0, 1), kV1Capture5);
  ExpectNoResponse(*c, Req(daoai::kSendPose, 3, 1));  // payload_1 set on purpose: the last answer left 0
  server_->Stop();
  handler_->Shutdown();
  const std::vector<TeachRequest> taught = planner_->taught();
  ASSERT_EQ(taught.size(), 3u);
  EXPECT_EQ(taught[0].task.id, 0);
  EXPECT_EQ(taught[1].task.id, 0);
  EXPECT_EQ(taught[2].task.id, 3);
}

// meta_1 99 ("other"): the orientation convention is the cell's robot's
// when the cell names one without an id of its own (a Kawasaki: Euler ZY'Z'').
TEST_F(DaoaiServerTest, OtherRobotTypeUsesTheCellsRobotConvention) {
  Cell cell = MakeTestCell();
  cell.robot.model = *FindRobotModel("kawasaki");
  ASSERT_EQ(cell.robot.model.type, RobotType::kOther);
  Start(cell);
  RobotClientOptions o;
  o.port = server_->port();
  o.robot_type = RobotType::kOther;
  o.convention = OrientationConvention::kEulerZYZIntrinsic;
  auto c = std::move(RobotClient::Connect(o).value());
  // The robot at a pose whose ZY'Z'' and fixed-XYZ fields differ.
  const Pose X_BF = MakePose(Mat3(Eigen::AngleAxisd(0.3, Vec3::UnitZ()) *
                                  Eigen::AngleAxisd(2.5, Vec3::UnitY()) *
                                  Eigen::AngleAxisd(-0.7, Vec3::UnitZ())),
                             Vec3(0.5, -0.25, 0.3));
  c->SetPose(X_BF);
  ASSERT_EQ(c->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  Result<RobotReply> pick = c->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(pick.ok());
  ASSERT_EQ(pick->status, daoai::kObjectsFound);
  ASSERT_TRUE(pick->X_BT);
  const Pose expected = ScriptedPlanner::GraspPose(0, 0);
  EXPECT_LT((pick->X_BT->translation() - expected.translation()).norm(), 1e-3);
  EXPECT_LT(Eigen::AngleAxisd(pick->X_BT->linear().transpose() * expected.linear()).angle(), 1e-3);
  // The capture saw the robot's pose decoded as ZY'Z'' too.
  ASSERT_TRUE(planner_->last_X_BF());
  EXPECT_LT(Eigen::AngleAxisd(planner_->last_X_BF()->linear().transpose() * X_BF.linear()).angle(), 1e-3);
}

TEST_F(DaoaiServerTest, CompletesAShortReadSentInThreeChunks) {
  Start();
  auto c = Connect(2);
  ASSERT_TRUE(c);
  const auto bytes = daoai::EncodeRequest(Req(daoai::kSwitchConfig, 2));
  ASSERT_TRUE(c->SendBytes(bytes.data(), 10).ok());
  std::this_thread::sleep_for(30ms);
  ASSERT_TRUE(c->SendBytes(bytes.data() + 10, 20).ok());
  std::this_thread::sleep_for(30ms);
  ASSERT_TRUE(c->SendBytes(bytes.data() + 30, 18).ok());
  std::array<uint8_t, daoai::kResponseSize> in{};
  ASSERT_TRUE(c->ReceiveBytes(in.data(), in.size()).ok());
  EXPECT_EQ(Hex(in), Normalize(kCfgOk));
}

// A calibration service whose views fail where told: a failure before the
// plan exists is an error (the board was not seen from the start pose), a
// failed planned view is skipped (good = false) and the next pose proposed.
class FlakyCalibrationService final : public CalibrationService {
 public:
  explicit FlakyCalibrationService(std::vector<bool> view_ok) : view_ok_(std::move(view_ok)) {}
  Status Start(CalibrationKind, const Pose&) override {
    views_ = 0;
    planned_ = false;
    return Status::Ok();
  }
  Result<CalibrationStep> Accumulate(CalibrationKind, const Pose& X_BF) override {
    const bool ok = views_ < view_ok_.size() && view_ok_[views_];
    ++views_;
    if (!ok && !planned_) return Status::NotFound("board not visible from the start pose");
    planned_ = true;
    CalibrationStep step;
    step.good = ok;
    step.next_X_BF = X_BF * MakePose(Mat3::Identity(), Vec3(0.01 * static_cast<double>(views_), 0, 0));
    return step;
  }
  Status Finish(CalibrationKind) override {
    ++finished;
    return Status::InvalidArgument("too few views");
  }
  int finished = 0;

 private:
  std::vector<bool> view_ok_;
  size_t views_ = 0;
  bool planned_ = false;
};

TEST(DaoaiServerPoses, AnAutoCalibrationNeverAnswersAZeroPoseAndEndsAfterThreeFailedViewsInARow) {
  // Views: start pose fails twice, then seen; then planned views ok, fail, ok,
  // fail, fail, fail (three in a row: DONE).
  auto service = std::make_unique<FlakyCalibrationService>(
      std::vector<bool>{false, false, true, true, false, true, false, false, false});
  FlakyCalibrationService* flaky = service.get();
  RequestHandler handler(MakeTestCell(), std::make_shared<ScriptedPlanner>(), std::move(service));
  ClientContext client;
  const daoai::Request start = Req(daoai::kStartAutoCalibration);
  const daoai::Request view = Req(daoai::kAutoAccumulatePose);
  std::optional<daoai::Response> r = handler.Handle(start, client);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, daoai::kModeAutoCalibration);
  EXPECT_EQ(r->position, start.position);  // stay for the first view
  EXPECT_EQ(r->orientation, start.orientation);
  const std::vector<int32_t> expected = {11, 11, 11, 11, 11, 11, 11, 11, 33};
  std::vector<int32_t> statuses;
  for (size_t i = 0; i < expected.size(); ++i) {
    r = handler.Handle(view, client);
    ASSERT_TRUE(r);
    statuses.push_back(r->status);
    // Never the base origin: the robot's own pose (start view, DONE) or a planned one.
    EXPECT_NE(r->position, (std::array<int32_t, 3>{})) << "answer " << i;
    const bool planned = i >= 2 && r->status == daoai::kModeAutoCalibration;
    if (planned) {
      EXPECT_NE(r->position, view.position) << "answer " << i << ": the next planned pose";
    } else {
      EXPECT_EQ(r->position, view.position) << "answer " << i << ": the robot's own pose";
    }
  }
  EXPECT_EQ(statuses, expected);
  EXPECT_EQ(flaky->finished, 1);
  // The calibration has ended: a further view is answered -1, still with the robot's pose.
  r = handler.Handle(view, client);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, daoai::kUnknownCommand);
  EXPECT_EQ(r->position, view.position);
  handler.Shutdown();
}

// A robot whose socket keeps Nagle's algorithm on (robot controllers rarely
// let a program set TCP_NODELAY) holds a small write until its previous one
// is acknowledged. Linux delays an ACK by at least 40 ms (TCP_DELACK_MIN)
// when nothing is sent back, so without the server's immediate ACK every
// round below takes 40 ms or more. The bound is generous (a round of 30 ms or
// more in fewer than half of 50 rounds), so a loaded machine does not fail it
// and a server that leaves the ACK delayed cannot pass it. Latency figures:
// bp_server_bench.
int RoundsHeldByADelayedAck(const std::function<void()>& round) {
  int held = 0;
  for (int i = 0; i < 50; ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    round();
    if (std::chrono::steady_clock::now() - t0 >= 30ms) ++held;
  }
  return held;
}

TEST_F(DaoaiServerTest, PoseUpdateThenCommandIsNotHeldByTheDelayedAck) {
  Start();
  RobotClientOptions o;
  o.port = server_->port();
  o.tcp_nodelay = false;
  auto c = RobotClient::Connect(o);
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  const auto update = daoai::EncodeRequest(Req(daoai::kNoCommand));
  const auto command = daoai::EncodeRequest(Req(99));
  std::array<uint8_t, daoai::kResponseSize> in{};
  bool answered = true;
  const int held = RoundsHeldByADelayedAck([&] {
    answered = answered && (*c)->SendBytes(update.data(), update.size()).ok() &&
               (*c)->SendBytes(command.data(), command.size()).ok() &&
               (*c)->ReceiveBytes(in.data(), in.size()).ok();
  });
  ASSERT_TRUE(answered);
  EXPECT_EQ(Hex(in), Normalize(kUnknown));
  EXPECT_LT(held, 25) << held << " of 50 pose-update-then-command rounds took 30 ms or more";
}

TEST_F(DaoaiServerTest, RequestWrittenAnIntAtATimeIsNotHeldByTheDelayedAck) {
  // URScript's socket_send_int writes one int32 per call (seed 003,
  // send_robot_data_2d): 12 writes per request.
  Start();
  RobotClientOptions o;
  o.port = server_->port();
  o.tcp_nodelay = false;
  auto c = RobotClient::Connect(o);
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  const auto command = daoai::EncodeRequest(Req(daoai::kSwitchConfig, 1));
  std::array<uint8_t, daoai::kResponseSize> in{};
  bool answered = true;
  const int held = RoundsHeldByADelayedAck([&] {
    for (size_t i = 0; i < command.size(); i += 4) {
      answered = answered && (*c)->SendBytes(command.data() + i, 4).ok();
    }
    answered = answered && (*c)->ReceiveBytes(in.data(), in.size()).ok();
  });
  ASSERT_TRUE(answered);
  EXPECT_EQ(Hex(in), Normalize(kCfgOk));
  EXPECT_LT(held, 25) << held << " of 50 int-at-a-time requests took 30 ms or more";
}

TEST_F(DaoaiServerTest, ServesTwoRobotsOnTwoTasksConcurrently) {
  Start();
  ScriptedPlanner::Script many;
  many.grasps = 25;
  many.plan_delay = 20ms;
  planner_->SetScript(0, many);
  planner_->SetScript(1, many);
  std::vector<int> remaining[2];
  std::vector<double> x[2];
  std::vector<std::thread> robots;
  for (int task = 0; task < 2; ++task) {
    robots.emplace_back([&, task] {
      auto c = Connect(2);
      if (!c) return;
      for (int cycle = 0; cycle < 2; ++cycle) {
        Result<RobotReply> cap = c->Call(daoai::kCaptureAndProcess, task);
        if (!cap.ok() || cap->status != daoai::kDetection) return;
        for (;;) {
          Result<RobotReply> pick = c->Call(daoai::kPickPose, task);
          if (!pick.ok() || pick->status != daoai::kObjectsFound) break;
          remaining[task].push_back(static_cast<int>(pick->payload[0]));
          x[task].push_back(pick->X_BT->translation().y());
        }
      }
    });
  }
  for (auto& r : robots) r.join();
  for (int task = 0; task < 2; ++task) {
    ASSERT_EQ(remaining[task].size(), 50u) << "task " << task;
    for (int i = 0; i < 50; ++i) {
      EXPECT_EQ(remaining[task][i], 25 - i % 25);
      // Each robot only ever sees its own task's grasps (y = -0.1 + 0.02 task).
      EXPECT_NEAR(x[task][i], -0.1 + 0.02 * task, 1e-4);
    }
  }
}

TEST_F(DaoaiServerTest, RobotDisconnectingMidRequestLosesNoGrasp) {
  Start();
  planner_->HoldPlans(true);
  {
    auto a = Connect(2);
    ASSERT_TRUE(a);
    EXPECT_RESPONSE(*a, Req(daoai::kCaptureAndProcess, 0), kCapture5);  // answered at capture
    const auto pick = daoai::EncodeRequest(Req(daoai::kPickPose, 0));
    ASSERT_TRUE(a->SendBytes(pick.data(), pick.size()).ok());  // waits for detection...
    std::this_thread::sleep_for(50ms);
  }  // ...and the robot is gone.
  for (int i = 0; i < 100 && server_->connection_count() > 0; ++i) std::this_thread::sleep_for(10ms);
  EXPECT_EQ(server_->connection_count(), 0u);
  planner_->HoldPlans(false);
  std::this_thread::sleep_for(50ms);
  EXPECT_TRUE(planner_->handed_out().empty());
  // The next robot continues the queue from its first grasp.
  auto b = Connect(2);
  ASSERT_TRUE(b);
  EXPECT_RESPONSE(*b, Req(daoai::kPickPose, 0), kPick0_3);
  EXPECT_RESPONSE(*b, Req(daoai::kPickPose, 0), kPick0_2);
  EXPECT_TRUE(planner_->WaitForHandedOut(2));
  EXPECT_EQ(planner_->handed_out().size(), 2u);
}

TEST_F(DaoaiServerTest, PickPoseWaitsForTheDetectionAndCaptureDoesNot) {
  Start();
  planner_->HoldPlans(true);  // detection cannot finish until released
  auto c = Connect(2);
  ASSERT_TRUE(c);
  // CAPTURE_SUCCESS comes while the detection is held: it does not wait for it.
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 0), kCapture5);
  // The pick pose is not answered while the detection runs...
  const auto pick = daoai::EncodeRequest(Req(daoai::kPickPose, 0));
  ASSERT_TRUE(c->SendBytes(pick.data(), pick.size()).ok());
  c->set_timeout(300ms);
  std::array<uint8_t, daoai::kResponseSize> in{};
  EXPECT_FALSE(c->ReceiveBytes(in.data(), 1).ok()) << "the pick pose must wait for detection";
  // ...and is, with the detection's first grasp, once it finishes.
  planner_->HoldPlans(false);
  c->set_timeout(5000ms);
  ASSERT_TRUE(c->ReceiveBytes(in.data(), in.size()).ok());
  EXPECT_EQ(Hex(in), Normalize(kPick0_3));
}

TEST_F(DaoaiServerTest, HalfMessageThenSilenceClosesOnlyThatConnection) {
  Start(DaoaiDialect::kVisionPilot, /*read_timeout=*/300ms);
  auto stalled = Connect(2);
  auto silent = Connect(2);
  auto good = Connect(2);
  ASSERT_TRUE(stalled && silent && good);
  const auto bytes = daoai::EncodeRequest(Req(daoai::kSwitchConfig, 1));
  ASSERT_TRUE(stalled->SendBytes(bytes.data(), 24).ok());
  // The good robot keeps talking past the timeout and is never cut off.
  for (int i = 0; i < 10; ++i) {
    EXPECT_RESPONSE(*good, Req(daoai::kSwitchConfig, 1), kCfgOk);
    std::this_thread::sleep_for(60ms);
  }
  uint8_t byte = 0;
  stalled->set_timeout(1000ms);
  const Status s = stalled->ReceiveBytes(&byte, 1);
  EXPECT_NE(s.message().find("closed"), std::string::npos) << s.ToString();
  silent->set_timeout(1000ms);
  EXPECT_NE(silent->ReceiveBytes(&byte, 1).message().find("closed"), std::string::npos);
  EXPECT_RESPONSE(*good, Req(daoai::kSwitchConfig, 1), kCfgOk);
}

TEST_F(DaoaiServerTest, UnknownCommandAnswersMinusOneAndTheConnectionKeepsWorking) {
  Start();
  auto c = Connect(2);
  ASSERT_TRUE(c);
  EXPECT_RESPONSE(*c, Req(1234), kUnknown);
  EXPECT_RESPONSE(*c, Req(-7), kUnknown);
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 0), kCapture5);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 0), kPick0_3);
}

TEST_F(DaoaiServerTest, RemainingCountsRunDownToOneThenZero) {
  Start();
  ScriptedPlanner::Script five;
  five.grasps = 5;
  planner_->SetScript(0, five);
  auto c = Connect(2);
  ASSERT_TRUE(c);
  ASSERT_EQ(c->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  std::vector<double> remaining;
  std::vector<int32_t> statuses;
  for (int i = 0; i < 7; ++i) {
    Result<RobotReply> r = c->Call(daoai::kPickPose, 0);
    ASSERT_TRUE(r.ok());
    statuses.push_back(r->status);
    remaining.push_back(r->payload[0]);
    EXPECT_TRUE(r->warnings.empty());
  }
  EXPECT_EQ(remaining, (std::vector<double>{5, 4, 3, 2, 1, 0, 0}));
  EXPECT_EQ(statuses, (std::vector<int32_t>{2, 2, 2, 2, 2, 3, 3}));
}

// Grasps 1 and 3 lie on parts touching part 0 (Grasp::stale_after): handing
// out grasp 0 withdraws them, so the robot is told 3 left (0, 2, 4), not 5,
// and never gets a grasp on a part that may have moved.
TEST_F(DaoaiServerTest, AfterAPickGraspsOnATouchingNeighbourAreWithdrawnAndTheRemainingCountSaysSo) {
  Start();  // vision_pilot: payload_1 counts the grasp handed out
  ScriptedPlanner::Script five;
  five.grasps = 5;
  five.stale_after = {{1, {0}}, {3, {0, 2}}};
  planner_->SetScript(0, five);
  auto c = Connect(2);
  ASSERT_TRUE(c);
  ASSERT_EQ(c->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  std::vector<double> remaining, x_mm;
  std::vector<int32_t> statuses;
  for (int i = 0; i < 4; ++i) {
    Result<RobotReply> r = c->Call(daoai::kPickPose, 0);
    ASSERT_TRUE(r.ok());
    statuses.push_back(r->status);
    remaining.push_back(r->payload[0]);
    if (r->status == daoai::kObjectsFound) {
      ASSERT_TRUE(r->X_BT);
      x_mm.push_back(std::round(1000 * r->X_BT->translation().x()));
    }
  }
  EXPECT_EQ(remaining, (std::vector<double>{3, 2, 1, 0}));
  EXPECT_EQ(statuses, (std::vector<int32_t>{2, 2, 2, 3}));
  EXPECT_EQ(x_mm, (std::vector<double>{500, 520, 540}));  // grasps 0, 2, 4
  const auto handed = planner_->handed_out();
  ASSERT_EQ(handed.size(), 3u);
  EXPECT_EQ(handed[1].second, 2);
  EXPECT_EQ(handler_->QueueSize(0), 0);
}

// Failed-pick feedback (command 60, docs/protocols.md "Failed-pick
// feedback"). Task 0 of these cells: the scripted grasps lie 10 mm apart
// along x (0.50, 0.51, ...), so a 15 mm radius withholds the failed part
// and its next neighbour.
Cell FeedbackCell(double radius, int captures, int max_failures) {
  Cell cell = MakeTestCell();
  for (TaskSpec& t : cell.tasks) {
    t.failed_picks.radius = radius;
    t.failed_picks.captures = captures;
    t.failed_picks.max_failures = max_failures;
  }
  return cell;
}

// The robot at (0.5, -0.25, 0.3) m reports that its last grasp of task 0
// slipped (payload_2 2).
const char* kReport60 = "00001388 FFFFF63C 00000BB8" "00000000 00000000 00003D5C 00000000" "0000003C 00000000 00000002" "00000007 00000002";
// PICK_FAILURE_NOTED (61), payload_1 0: the spot may still be tried.
const char* kNoted61 = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00000000 00000000 00000000 00000000 00000000 00000000" "0000003D 00000007 00000002";
// 61 with payload_1 1 x MULT: the spot reached max_failures.
const char* kNoted61Refused = "00000000 00000000 00000000" "00000000 00000000 00000000 00000000" "00002710 00000000 00000000 00000000 00000000 00000000" "0000003D 00000007 00000002";

daoai::Request Report(int task, int32_t reason) {
  daoai::Request r = Req(daoai::kReportPickFailure, task);
  r.payload_2 = reason;
  return r;
}

TEST_F(DaoaiServerTest, AFailedPickReportAndItsAnswerHaveGoldenBytes) {
  Start(FeedbackCell(0.015, 3, 3));
  const auto request = daoai::EncodeRequest(Report(0, 2));
  EXPECT_EQ(Hex(request), Normalize(kReport60));
  auto c = Connect(2);
  ASSERT_TRUE(c);
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 0), kCapture5);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 0), kPick0_3);
  EXPECT_RESPONSE(*c, Report(0, 2), kNoted61);
}

TEST_F(DaoaiServerTest, AfterAReportedFailureTheNextPickIsAnotherPartAwayFromIt) {
  Start(FeedbackCell(0.015, 3, 3));
  ScriptedPlanner::Script five;
  five.grasps = 5;
  planner_->SetScript(0, five);
  auto c = Connect(2);
  ASSERT_TRUE(c);
  auto pick_x_mm = [&] {
    Result<RobotReply> r = c->Call(daoai::kPickPose, 0);
    EXPECT_TRUE(r.ok() && r->status == daoai::kObjectsFound && r->X_BT);
    return r.ok() && r->X_BT ? std::round(1000 * r->X_BT->translation().x()) : -1.0;
  };
  ASSERT_EQ(c->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  EXPECT_EQ(pick_x_mm(), 500);
  Result<RobotReply> noted = c->Call(daoai::kReportPickFailure, 0, 1);  // vacuum not built
  ASSERT_TRUE(noted.ok());
  EXPECT_EQ(noted->status, daoai::kPickFailureNoted);
  EXPECT_EQ(noted->payload[0], 0);
  // The queue already lost the neighbour at 0.51 m; a new capture finds the
  // failed part again at 0.50 m and withholds it and its neighbour.
  EXPECT_EQ(handler_->QueueSize(0), 3);
  ASSERT_EQ(c->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  EXPECT_EQ(pick_x_mm(), 520);
  EXPECT_EQ(handler_->FailedSpots(0).size(), 1u);
  EXPECT_EQ(handler_->stats().pick_failures, 1u);
}

TEST_F(DaoaiServerTest, KFailuresOnOneSpotAnswerNoCollisionFreePoseRatherThanTheSameSpot) {
  Start(FeedbackCell(0.015, 3, 2));
  ScriptedPlanner::Script one;
  one.grasps = 1;
  planner_->SetScript(0, one);
  auto c = Connect(2);
  ASSERT_TRUE(c);
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 0), kCapture5);
  ASSERT_EQ(c->Call(daoai::kPickPose, 0)->status, daoai::kObjectsFound);
  EXPECT_RESPONSE(*c, Report(0, 2), kNoted61);
  // Nothing else to pick: the part is tried again (fewer than K = 2 failures).
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 0), kCapture5);
  Result<RobotReply> again = c->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(again.ok());
  ASSERT_EQ(again->status, daoai::kObjectsFound);
  EXPECT_NEAR(again->X_BT->translation().x(), 0.5, 1e-4);
  EXPECT_RESPONSE(*c, Report(0, 2), kNoted61Refused);
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 0), kCapture5);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 0), kNoCf4);
}

TEST_F(DaoaiServerTest, AMalformedFailureReportGetsUnknownCommandAndTheNextRequestIsServed) {
  Start(FeedbackCell(0.015, 3, 3));
  auto c = Connect(2);
  ASSERT_TRUE(c);
  EXPECT_RESPONSE(*c, Report(0, 2), kUnknown) << "no grasp was handed out yet";
  EXPECT_RESPONSE(*c, Req(daoai::kCaptureAndProcess, 0), kCapture5);
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 0), kPick0_3);
  EXPECT_RESPONSE(*c, Report(0, 9), kUnknown) << "reason 9 is not 0, 1, 2 or 3";
  EXPECT_RESPONSE(*c, Report(42, 2), kUnknown) << "no task 42";
  EXPECT_RESPONSE(*c, Report(2, 2), kUnknown) << "task 2 is a place task";
  EXPECT_RESPONSE(*c, Report(0, 2), kNoted61) << "the grasp is still the one to blame";
  EXPECT_RESPONSE(*c, Report(0, 2), kUnknown) << "reported once";
  EXPECT_RESPONSE(*c, Req(daoai::kPickPose, 0), kPick0_1) << "the next request is served";
  EXPECT_EQ(handler_->stats().pick_failures, 1u);
  EXPECT_EQ(handler_->stats().pick_failures_refused, 4u);  // task 42: refused as every unknown task
}

TEST_F(DaoaiServerTest, PipelinedRequestsAreAnsweredInOrder) {
  Start();
  auto c = Connect(2);
  ASSERT_TRUE(c);
  // A misbehaving robot sends three requests without waiting.
  std::vector<uint8_t> burst;
  for (const auto& r : {Req(daoai::kCaptureAndProcess, 0), Req(daoai::kPickPose, 0),
                        Req(daoai::kSwitchConfig, 7)}) {
    const auto b = daoai::EncodeRequest(r);
    burst.insert(burst.end(), b.begin(), b.end());
  }
  ASSERT_TRUE(c->SendBytes(burst.data(), burst.size()).ok());
  std::array<uint8_t, daoai::kResponseSize> in{};
  for (const char* golden : {kCapture5, kPick0_3, kCfgFail}) {
    ASSERT_TRUE(c->ReceiveBytes(in.data(), in.size()).ok());
    EXPECT_EQ(Hex(in), Normalize(golden));
  }
}

TEST_F(DaoaiServerTest, StopClosesRobotConnections) {
  Start();
  auto c = Connect(2);
  ASSERT_TRUE(c);
  EXPECT_RESPONSE(*c, Req(daoai::kSwitchConfig, 1), kCfgOk);
  server_->Stop();
  uint8_t byte = 0;
  c->set_timeout(1000ms);
  EXPECT_NE(c->ReceiveBytes(&byte, 1).message().find("closed"), std::string::npos);
}

TEST(DaoaiServer, RefusesABadBindAddress) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  DaoaiServerOptions options;
  options.bind = "not-an-address";
  options.port = 0;
  auto server = DaoaiServer::Start(handler, options);
  ASSERT_FALSE(server.ok());
  EXPECT_EQ(server.status().code(), Status::Code::kInvalidArgument);
}

}  // namespace
}  // namespace bp
