// The Modbus TCP transport over real Modbus TCP on loopback: binpick's
// ModbusMaster against the robot simulator (a libmodbus slave playing the seed
// 000 UR Modbus script), with the scripted test-double planner.
#include <gtest/gtest.h>

#include <sys/wait.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstdlib>
#include <future>
#include <iostream>
#include <random>
#include <sstream>
#include <thread>

#include "comms/modbus_codec.h"
#include "comms/modbus_master.h"
#include "comms/modbus_robot_sim.h"
#include "comms/robot_flows.h"
#include "tests/testing/process_stats.h"
#include "tests/testing/run_command.h"
#include "tests/testing/scripted_planner.h"

namespace bp {
namespace {

// A loopback port that was free a moment ago (a slave bound it, then closed).
int FreeLoopbackPort() {
  auto probe = ModbusRobotSim::Start({});
  return probe.ok() ? (*probe)->port() : 0;
}

using namespace std::chrono_literals;
using testing::MakeTestCell;
using testing::ScriptedPlanner;

// ---------------------------------------------------------------- codec

TEST(ModbusCodec, RequestFieldsAreInt16TwosComplementInOrder) {
  daoai::Request r;
  r.position = {4000, -3000, 32767};
  r.orientation = {31416, -1, -32768, 0};
  r.command = daoai::kPickPose;
  r.payload_1 = 3;
  r.payload_2 = -2;
  r.meta_1 = 7;
  r.meta_2 = 2;
  const auto regs = modbus::EncodeRequest(r);
  ASSERT_TRUE(regs.ok());
  const std::array<uint16_t, 12> golden = {0x0FA0, 0xF448, 0x7FFF, 0x7AB8, 0xFFFF, 0x8000,
                                           0x0000, 0x0015, 0x0003, 0xFFFE, 0x0007, 0x0002};
  EXPECT_EQ(*regs, golden);
  EXPECT_EQ(modbus::DecodeRequest(golden), r);
}

// The failed-pick report (command 60, payload_1 task 0, payload_2 reason 2
// slipped) from a UR at (0.5, -0.25, 0.3) m, and its answer 61 (payload_1
// 1 x MULT: the spot reached max_failures), register by register.
TEST(ModbusCodec, FailedPickReportAndItsAnswerHaveGoldenRegisters) {
  daoai::Request r;
  r.position = {5000, -2500, 3000};
  r.orientation = {0, 0, 15708, 0};
  r.command = daoai::kReportPickFailure;
  r.payload_1 = 0;
  r.payload_2 = 2;
  r.meta_1 = 7;
  r.meta_2 = 2;
  const auto regs = modbus::EncodeRequest(r);
  ASSERT_TRUE(regs.ok());
  const std::array<uint16_t, 12> golden = {0x1388, 0xF63C, 0x0BB8, 0x0000, 0x0000, 0x3D5C,
                                           0x0000, 0x003C, 0x0000, 0x0002, 0x0007, 0x0002};
  EXPECT_EQ(*regs, golden);
  EXPECT_EQ(modbus::DecodeRequest(golden), r);

  daoai::Response a;
  a.status = daoai::kPickFailureNoted;
  a.payload[0] = 10000;
  a.meta_1 = 7;
  a.meta_2 = 2;
  const auto answer = modbus::EncodeResponse(a);
  ASSERT_TRUE(answer.ok());
  const std::array<uint16_t, 16> golden_answer = {0, 0, 0, 0, 0, 0, 0, 0x2710, 0, 0, 0, 0, 0, 0x003D, 0x0007, 0x0002};
  EXPECT_EQ(*answer, golden_answer);
  EXPECT_EQ(modbus::DecodeResponse(golden_answer), a);
}

TEST(ModbusCodec, RequestThatDoesNotFitIsRefusedNotWrapped) {
  daoai::Request r;
  r.position[1] = 32768;  // 3.2768 m
  const auto regs = modbus::EncodeRequest(r);
  ASSERT_FALSE(regs.ok());
  EXPECT_EQ(regs.status().code(), Status::Code::kOutOfRange);
  EXPECT_NE(regs.status().message().find("position y"), std::string::npos);
}

TEST(ModbusCodec, ResponseRoundTripsAndDecodesNegativeValues) {
  daoai::Response r;
  r.position = {5000, -1000, 1000};
  r.orientation = {0, 0, 15708, 0};
  r.payload = {20000, 10000, 0, 0, 0, -5};
  r.status = daoai::kObjectsFound;
  r.meta_1 = 7;
  r.meta_2 = 2;
  const auto regs = modbus::EncodeResponse(r);
  ASSERT_TRUE(regs.ok());
  EXPECT_EQ((*regs)[1], 0xFC18);   // -1000
  EXPECT_EQ((*regs)[12], 0xFFFB);  // payload_6 = -5
  EXPECT_EQ((*regs)[13], 2);       // status
  EXPECT_EQ((*regs)[15], 2);       // meta_2: on register 144 in the seed map
  EXPECT_EQ(modbus::DecodeResponse(*regs), r);
}

TEST(ModbusCodec, RemainingCountSaturatesOnlyInPickAnswers) {
  daoai::Response r;
  r.status = daoai::kObjectsFound;
  r.payload[0] = 12 * 10000;  // 12 objects remaining
  std::vector<std::string> saturated;
  const auto regs = modbus::EncodeResponse(r, &saturated);
  ASSERT_TRUE(regs.ok());
  EXPECT_EQ(modbus::FromRegister((*regs)[7]), 32767);
  ASSERT_EQ(saturated.size(), 1u);
  EXPECT_NE(saturated[0].find("payload_1"), std::string::npos);

  r.status = daoai::kPrecisionCheckSuccess;  // payload_1 is an error in mm there
  const auto refused = modbus::EncodeResponse(r);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), Status::Code::kOutOfRange);
}

TEST(ModbusCodec, PoseOrClassThatDoesNotFitRefusesTheResponse) {
  daoai::Response r;
  r.status = daoai::kObjectsFound;
  r.position[0] = -40000;  // -4 m
  EXPECT_FALSE(modbus::EncodeResponse(r).ok());
  r.position[0] = 0;
  r.payload[1] = 4 * 10000;  // class 4
  const auto regs = modbus::EncodeResponse(r);
  ASSERT_FALSE(regs.ok());
  EXPECT_NE(regs.status().message().find("payload_2"), std::string::npos);
  r.meta_1 = 7;
  r.meta_2 = 1;
  const daoai::Response refused = modbus::RefusedResponse(r);
  EXPECT_EQ(refused.status, daoai::kUnknownCommand);
  EXPECT_EQ(refused.position, (std::array<int32_t, 3>{}));
  EXPECT_EQ(refused.payload, (std::array<int32_t, 6>{}));
  EXPECT_EQ(refused.meta_1, 7);
  EXPECT_EQ(refused.meta_2, 1);
}

TEST(ModbusRegisterMap, SeedMapIsValidAndBrokenMapsAreRejected) {
  EXPECT_TRUE(ValidateModbusRegisterMap({}).ok());
  ModbusRegisterMap m;
  m.request_flag = 130;  // inside the request block
  EXPECT_FALSE(ValidateModbusRegisterMap(m).ok());
  m = {};
  m.response_flag = m.request_flag;
  EXPECT_FALSE(ValidateModbusRegisterMap(m).ok());
  m = {};
  m.request_base = 120;  // flag 144 is meta_2, marker 131 would be the response's position z
  EXPECT_FALSE(ValidateModbusRegisterMap(m).ok());
  m.request_base = 130;  // marker 141: payload_6, free
  m.request_flag = 142;
  m.response_flag = 150;
  EXPECT_TRUE(ValidateModbusRegisterMap(m).ok());
  m = {};
  m.response_base = 400;  // 128..415: more than one read
  m.response_flag = 420;
  EXPECT_FALSE(ValidateModbusRegisterMap(m).ok());
  m = {};
  m.response_base = 65530;
  EXPECT_FALSE(ValidateModbusRegisterMap(m).ok());
}

// ---------------------------------------------------------------- over TCP

struct RigOptions {
  int version = 2;
  ModbusRegisterMap map;
  std::chrono::milliseconds poll{1};
  double position_scale = 1.0;
  std::chrono::microseconds write_interval{0};  // the robot's, between registers
  std::chrono::milliseconds backoff{10};         // the master's first reconnect delay
  double failed_pick_radius = 0.03;              // every task's failed_picks.radius, m
};

class ModbusRig {
 public:
  explicit ModbusRig(RigOptions o = {}) : o_(o) {
    planner_ = std::make_shared<ScriptedPlanner>();
    Cell cell = MakeTestCell();
    cell.robot.position_scale = o.position_scale;
    for (TaskSpec& t : cell.tasks) t.failed_picks.radius = o.failed_pick_radius;
    handler_ = std::make_unique<RequestHandler>(cell, planner_,
                                                std::make_unique<CountingCalibrationService>(4));
    StartRobot(0);
    ModbusMasterOptions mo;
    mo.port = sim_->port();
    mo.map = o.map;
    mo.poll_interval = o.poll;
    mo.timeout = 500ms;
    mo.backoff_min = o.backoff;
    mo.backoff_max = std::max(o.backoff, std::chrono::milliseconds(50));
    master_ = std::move(ModbusMaster::Start(*handler_, mo).value());
    EXPECT_TRUE(sim_->WaitForMaster(5s));
  }
  ~ModbusRig() {
    robot_.reset();
    master_->Stop();
    handler_->Shutdown();
    sim_->Stop();
  }

  // (Re)starts the robot's slave, on `port` (0: ephemeral), with fresh registers.
  void StartRobot(int port) {
    robot_.reset();
    if (sim_) sim_->Stop();
    ModbusRobotSimOptions so;
    so.port = port;
    so.map = o_.map;
    so.write_interval = o_.write_interval;
    sim_ = std::move(ModbusRobotSim::Start(so).value());
    RobotClientOptions ro;
    ro.version = o_.version;
    ro.position_scale = o_.position_scale;
    ro.timeout = 5s;
    robot_ = RobotClient::Over(sim_->Transport(), ro);
  }

  FlowSummary Run(FlowOptions f) {
    Result<FlowSummary> s = RunFlow(*robot_, f, out_);
    EXPECT_TRUE(s.ok()) << s.status().ToString() << "\n" << out_.str();
    if (std::getenv("BINPICK_VERBOSE")) std::cout << out_.str();
    return s.ok() ? *s : FlowSummary{};
  }

  RigOptions o_;
  std::shared_ptr<ScriptedPlanner> planner_;
  std::unique_ptr<RequestHandler> handler_;
  std::unique_ptr<ModbusRobotSim> sim_;
  std::unique_ptr<ModbusMaster> master_;
  std::unique_ptr<RobotClient> robot_;
  std::ostringstream out_;
};

class ModbusVersionTest : public ::testing::TestWithParam<int> {};

TEST_P(ModbusVersionTest, PickCycleClearsTheBinThenFindsItEmpty) {
  RigOptions o;
  o.version = GetParam();
  ModbusRig rig(o);
  ScriptedPlanner::Script pile;
  pile.grasps = 3;
  pile.pile = 7;
  rig.planner_->SetScript(0, pile);
  FlowOptions f;
  f.flow = "pick";
  const FlowSummary s = rig.Run(f);
  EXPECT_EQ(s.picks, 7) << rig.out_.str();
  EXPECT_TRUE(s.ok) << rig.out_.str();
  EXPECT_EQ(s.last_status, daoai::kBoxEmpty);
  EXPECT_TRUE(rig.planner_->WaitForHandedOut(7));
  EXPECT_EQ(rig.planner_->handed_out().size(), 7u);
  EXPECT_NE(rig.out_.str().find("remaining 3 class 0"), std::string::npos) << rig.out_.str();
  // The robot moved to the grasp the planner made (0.1 mm wire resolution).
  EXPECT_NE(rig.out_.str().find("pose [0.5000 -0.1000 0.1000"), std::string::npos) << rig.out_.str();
  EXPECT_EQ(rig.sim_->stats().unexpected_responses, 0u);
  EXPECT_EQ(rig.master_->stats().requests, static_cast<uint64_t>(s.steps));
}

// Grasps 1 and 3 lie on parts touching part 0 (Grasp::stale_after): over
// Modbus too, the first pick pose says 3 left (grasps 0, 2, 4), not 5.
TEST_P(ModbusVersionTest, AfterAPickGraspsOnATouchingNeighbourAreWithdrawnAndTheRemainingCountSaysSo) {
  RigOptions o;
  o.version = GetParam();
  ModbusRig rig(o);
  ScriptedPlanner::Script five;
  five.grasps = 5;
  five.stale_after = {{1, {0}}, {3, {0, 2}}};
  rig.planner_->SetScript(0, five);
  Result<RobotReply> capture = rig.robot_->Call(daoai::kCaptureAndProcess, 0);
  ASSERT_TRUE(capture.ok()) << capture.status().ToString();
  ASSERT_EQ(capture->status, daoai::kDetection);
  std::vector<double> remaining, x_mm;
  for (int i = 0; i < 4; ++i) {
    Result<RobotReply> r = rig.robot_->Call(daoai::kPickPose, 0);
    ASSERT_TRUE(r.ok()) << r.status().ToString();
    remaining.push_back(r->payload[0]);
    if (r->status == daoai::kObjectsFound && r->X_BT) x_mm.push_back(std::round(1000 * r->X_BT->translation().x()));
  }
  EXPECT_EQ(remaining, (std::vector<double>{3, 2, 1, 0}));
  EXPECT_EQ(x_mm, (std::vector<double>{500, 520, 540}));  // grasps 0, 2, 4
  EXPECT_EQ(rig.planner_->handed_out().size(), 3u);
}

// The Modbus twin of command 60: the same registers carry the report, and
// the next capture's first pick is away from the failed part (grasps 10 mm
// apart, radius 15 mm: the part at 0.50 m and its neighbour at 0.51 m withheld).
TEST_P(ModbusVersionTest, AFailedPickReportedOverModbusSendsTheNextPickElsewhere) {
  RigOptions o;
  o.version = GetParam();
  o.failed_pick_radius = 0.015;
  ModbusRig rig(o);
  ScriptedPlanner::Script five;
  five.grasps = 5;
  rig.planner_->SetScript(0, five);
  auto pick_x_mm = [&] {
    Result<RobotReply> r = rig.robot_->Call(daoai::kPickPose, 0);
    EXPECT_TRUE(r.ok() && r->status == daoai::kObjectsFound && r->X_BT);
    return r.ok() && r->X_BT ? std::round(1000 * r->X_BT->translation().x()) : -1.0;
  };
  ASSERT_EQ(rig.robot_->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  EXPECT_EQ(pick_x_mm(), 500);
  Result<RobotReply> noted = rig.robot_->Call(daoai::kReportPickFailure, 0, 2);
  ASSERT_TRUE(noted.ok()) << noted.status().ToString();
  EXPECT_EQ(noted->status, daoai::kPickFailureNoted);
  Result<RobotReply> bad = rig.robot_->Call(daoai::kReportPickFailure, 0, 5);
  ASSERT_TRUE(bad.ok()) << bad.status().ToString();
  EXPECT_EQ(bad->status, daoai::kUnknownCommand) << "reason 5 does not exist";
  ASSERT_EQ(rig.robot_->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  EXPECT_EQ(pick_x_mm(), 520);
  EXPECT_EQ(rig.handler_->stats().pick_failures, 1u);
}

TEST_P(ModbusVersionTest, AutoCalibrationStartsAndAccumulatesUntilDone) {
  RigOptions o;
  o.version = GetParam();
  ModbusRig rig(o);
  FlowOptions f;
  f.flow = "calib-auto";
  const FlowSummary s = rig.Run(f);
  EXPECT_TRUE(s.ok) << rig.out_.str();
  EXPECT_EQ(s.last_status, daoai::kDoneCalibration);
  EXPECT_EQ(s.steps, 1 + 4) << rig.out_.str();  // start + 4 poses (CountingCalibrationService(4))
  EXPECT_NE(rig.out_.str().find("MODE_AUTO_CALIBRATION(11) pose"), std::string::npos)
      << rig.out_.str();
}

TEST_P(ModbusVersionTest, EmptyBoxCheckAnswersBothWays) {
  RigOptions o;
  o.version = GetParam();
  ModbusRig rig(o);
  FlowOptions f;
  f.flow = "empty-check";
  EXPECT_EQ(rig.Run(f).last_status, daoai::kBoxNotEmpty);
  ScriptedPlanner::Script empty;
  empty.pile = 0;
  rig.planner_->SetScript(0, empty);
  EXPECT_EQ(rig.Run(f).last_status, daoai::kBoxEmpty);
}

// Requests without a response between requests with one, 1000 in a row:
// every request is taken exactly once and every response answers its own
// request. Version 1 is the hard case: its responses leave 1 (meta_2) in the
// request flag register 144.
// `n` requests in a row, a fifth of them without a response; each answer is
// checked against its request, and neither side may count one too many.
void ExpectEveryRequestAnsweredOnce(const RigOptions& o, int n) {
  ModbusRig rig(o);
  std::mt19937 rng{42};
  int calls = 0, sends = 0;
  for (int i = 0; i < n; ++i) {
    if (rng() % 5 == 0) {
      ASSERT_TRUE(rig.robot_->Send(daoai::kNoCommand).ok()) << i;  // pose update
      ++sends;
      continue;
    }
    const int config = static_cast<int>(rng() % 3) + 1;  // 3 does not exist
    Result<RobotReply> r = rig.robot_->Call(daoai::kSwitchConfig, config);
    ASSERT_TRUE(r.ok()) << i << ": " << r.status().ToString();
    ASSERT_EQ(r->status, config == 3 ? daoai::kSwitchConfigFail : daoai::kSwitchConfigSuccess) << i;
    EXPECT_EQ(r->raw.meta_2, o.version);
    // Version 1 leaves 1 in register 144: the handshake's marker rides on payload_4.
    EXPECT_EQ(r->raw.payload[3], o.version == 1 ? -32768 : 0);
    if (config != 3) {
      EXPECT_EQ(rig.handler_->camera_config_id(), config);
    }
    ++calls;
  }
  // Let the master poll a while longer: a stale flag would show up as a request.
  std::this_thread::sleep_for(30ms);
  const ModbusMasterStats m = rig.master_->stats();
  EXPECT_EQ(m.requests, static_cast<uint64_t>(calls + sends));
  EXPECT_EQ(m.responses, static_cast<uint64_t>(calls));
  EXPECT_EQ(m.connects, 1u);
  const ModbusRobotSimStats r = rig.sim_->stats();
  EXPECT_EQ(r.responses_read, static_cast<uint64_t>(calls));
  EXPECT_EQ(r.unexpected_responses, 0u);
}

TEST_P(ModbusVersionTest, HandshakeNeverAnswersTwiceNorMissesOver1000Requests) {
  RigOptions o;
  o.version = GetParam();
  ExpectEveryRequestAnsweredOnce(o, 1000);
}

// A robot slower than the master's poll, as a real one is: the master reads
// the complete request between the robot's last request register and its
// flag write. In version 1 the flag already reads 1 (the last response's
// meta_2), so the robot's flag write lands after the master took the
// request; it must not be taken for a second one.
TEST_P(ModbusVersionTest, SlowRobotFlagWriteAfterTheTakeIsNotASecondRequest) {
  RigOptions o;
  o.version = GetParam();
  o.poll = 0ms;                 // the master polls back to back
  o.write_interval = 400us;     // the robot writes a register every 0.4 ms
  ExpectEveryRequestAnsweredOnce(o, 150);
}

INSTANTIATE_TEST_SUITE_P(Versions, ModbusVersionTest, ::testing::Values(1, 2),
                         [](const auto& info) { return "v" + std::to_string(info.param); });

class ModbusMapTest : public ::testing::TestWithParam<ModbusRegisterMap> {};

TEST_P(ModbusMapTest, PickCycleWorksWithOtherRegisterAddresses) {
  RigOptions o;
  o.version = 1;  // meta_2 = 1: the marker matters when the flag is a response register
  o.map = GetParam();
  ModbusRig rig(o);
  ScriptedPlanner::Script pile;
  pile.pile = 4;
  rig.planner_->SetScript(0, pile);
  FlowOptions f;
  f.flow = "pick";
  const FlowSummary s = rig.Run(f);
  EXPECT_EQ(s.picks, 4) << rig.out_.str();
  EXPECT_TRUE(s.ok) << rig.out_.str();
  // The seed's registers are untouched.
  for (int reg = 128; reg <= 145; ++reg) EXPECT_EQ(rig.sim_->ReadRegister(reg), 0) << reg;
  EXPECT_EQ(rig.sim_->stats().unexpected_responses, 0u);
}

ModbusRegisterMap Map(int request_base, int request_flag, int response_base, int response_flag) {
  ModbusRegisterMap m;
  m.request_base = request_base;
  m.request_flag = request_flag;
  m.response_base = response_base;
  m.response_flag = response_flag;
  return m;
}

INSTANTIATE_TEST_SUITE_P(
    Maps, ModbusMapTest,
    ::testing::Values(Map(1000, 1020, 1030, 1050),  // disjoint: flags are their own registers
                      Map(200, 230, 215, 240),      // flag inside the response, marker apart
                      Map(0, 15, 0 + 12, 28)),      // requests at 0, response 12..27 holds flag 15
    [](const auto& info) { return "at" + std::to_string(info.param.request_base) + "_" +
                                  std::to_string(info.param.response_base); });

TEST(ModbusMaster, RobotRestartingMidRequestIsServedAfterReconnect) {
  ModbusRig rig;
  ScriptedPlanner::Script slow;
  slow.capture_delay = 500ms;  // the restart happens during this capture
  slow.pile = 2;
  rig.planner_->SetScript(0, slow);
  const int port = rig.sim_->port();
  // The robot asks for a capture; the master takes it (clears the flag) and
  // the robot restarts while the camera is capturing.
  ASSERT_TRUE(rig.sim_->SendRobotData(rig.robot_->MakeRequest(daoai::kCaptureAndProcess, 0),
                                      true, 1s).ok());
  const auto deadline = std::chrono::steady_clock::now() + 2s;
  while (rig.sim_->ReadRegister(144) == 1 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(1ms);
  }
  ASSERT_EQ(rig.sim_->ReadRegister(144), 0) << "the master never took the request";
  rig.StartRobot(port);  // same address, registers back to 0
  ScriptedPlanner::Script fast;
  fast.pile = 2;
  rig.planner_->SetScript(0, fast);
  ASSERT_TRUE(rig.sim_->WaitForMaster(5s));
  // The restarted program runs its pick cycle from the start.
  FlowOptions f;
  f.flow = "pick";
  const FlowSummary s = rig.Run(f);
  EXPECT_EQ(s.picks, 2) << rig.out_.str();
  EXPECT_TRUE(s.ok) << rig.out_.str();
  const ModbusMasterStats m = rig.master_->stats();
  EXPECT_EQ(m.connects, 2u);
  EXPECT_EQ(m.lost, 1u);  // the answer to the capture before the restart
  EXPECT_EQ(rig.sim_->stats().unexpected_responses, 0u);
}

// Issue 39: the connection fails while the master takes a request (seed
// map: marker and cleared flag in one write). Whether or not the write
// reached the robot (here it did not), the request is served once after the
// reconnect: taken again when its flag is still set, finished when the marker
// is in place.
TEST(ModbusMaster, ARequestWhoseTakeWasCutIsServedOnceAfterTheReconnect) {
  ModbusRig rig;
  const ModbusRegisterMap map;
  rig.sim_->DropNextWriteTo(map.request_base + modbus::kMarkerField);  // the take
  Result<RobotReply> capture = rig.robot_->Call(daoai::kCaptureAndProcess, 0);
  ASSERT_TRUE(capture.ok()) << capture.status().ToString();
  EXPECT_EQ(capture->status, daoai::kDetection);
  EXPECT_EQ(rig.sim_->stats().dropped_writes, 1u);
  const ModbusMasterStats m = rig.master_->stats();
  EXPECT_EQ(m.connects, 2u);
  EXPECT_EQ(m.lost, 0u);
  EXPECT_EQ(rig.planner_->captures(), 1);
  Result<RobotReply> pick = rig.robot_->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(pick.ok());
  EXPECT_EQ(pick->status, daoai::kObjectsFound);
}

// Issue 39: the connection fails while the answer is written (seed map: the
// 16 response registers and the flag in one write): the answer (here a pick,
// its grasp taken and reserved) is written after the reconnect, not handled
// twice and not lost.
TEST(ModbusMaster, AnAnswerNotWrittenBeforeTheReconnectIsWrittenAfterIt) {
  for (const int version : {1, 2}) {
    RigOptions o;
    o.version = version;
    ModbusRig rig(o);
    ASSERT_EQ(rig.robot_->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
    rig.sim_->DropNextWriteTo(ModbusRegisterMap{}.response_base);  // answer and flag
    Result<RobotReply> pick = rig.robot_->Call(daoai::kPickPose, 0);
    ASSERT_TRUE(pick.ok()) << "v" << version << ": " << pick.status().ToString();
    EXPECT_EQ(pick->status, daoai::kObjectsFound);
    EXPECT_NEAR(pick->payload[0], 3.0, 1e-9);  // the first of 3: handed out once
    EXPECT_TRUE(rig.planner_->WaitForHandedOut(1));
    EXPECT_EQ(rig.planner_->handed_out().size(), 1u);
    const ModbusMasterStats m = rig.master_->stats();
    EXPECT_EQ(m.resumed, 1u) << "v" << version;
    EXPECT_EQ(m.lost, 0u);
    Result<RobotReply> next = rig.robot_->Call(daoai::kPickPose, 0);
    ASSERT_TRUE(next.ok());
    EXPECT_NEAR(next->payload[0], 2.0, 1e-9);
    EXPECT_EQ(rig.sim_->stats().unexpected_responses, 0u);
  }
}

// Issue 39: the connection fails after the pick answer's write (the 16
// response registers and the flag, one FC16) was applied and before its
// reply: the robot has the answer and its grasp, the master saw a failed
// write. Whether the master reconnects before the robot reads the answer,
// after it read it, or after its next request, the answer is not written
// again (the robot would read it twice, or as the answer to its next
// request) and its grasp is not put back: handed out exactly once, and the
// next pick gets the next grasp.
TEST(ModbusMaster, AnAnswerThatReachedTheRobotBeforeItsReplyWasLostIsHandedOutOnce) {
  enum Order { kReadAfterTheReconnect, kReadBeforeTheReconnect, kAskedAgainBeforeTheReconnect };
  for (const int version : {1, 2}) {
    for (const Order order : {kReadAfterTheReconnect, kReadBeforeTheReconnect,
                              kAskedAgainBeforeTheReconnect}) {
      SCOPED_TRACE("version " + std::to_string(version) + ", order " + std::to_string(order));
      RigOptions o;
      o.version = version;
      // The robot's reads take well under a millisecond: a 300 ms first
      // reconnect delay puts them before the reconnect.
      if (order != kReadAfterTheReconnect) o.backoff = 300ms;
      ModbusRig rig(o);
      ModbusRobotSim& robot = *rig.sim_;
      ASSERT_EQ(rig.robot_->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
      robot.LoseReplyToNextWrite(ModbusRegisterMap{}.response_base);
      const daoai::Request pick = rig.robot_->MakeRequest(daoai::kPickPose, 0);
      ASSERT_TRUE(robot.SendRobotData(pick, true, 1s).ok());
      ASSERT_TRUE(testing::WaitUntil([&] { return robot.stats().lost_replies == 1; }));
      // The master reconnected and settled the exchange: found it delivered,
      // wrote it again, or dropped it.
      auto settled = [&] {
        const ModbusMasterStats m = rig.master_->stats();
        return m.delivered + m.resumed + m.lost == 1;
      };
      if (order == kReadAfterTheReconnect) {
        ASSERT_TRUE(testing::WaitUntil(settled));
      }
      Result<daoai::Response> first = robot.RecvDaoaiData(1s);
      ASSERT_TRUE(first.ok()) << first.status().ToString();
      if (order == kAskedAgainBeforeTheReconnect) {
        ASSERT_TRUE(robot.SendRobotData(pick, true, 1s).ok());
      }
      if (order == kReadBeforeTheReconnect) {
        EXPECT_EQ(rig.master_->stats().connects, 1u) << "reconnected before the robot read";
      }
      ASSERT_TRUE(testing::WaitUntil(settled));
      if (order != kAskedAgainBeforeTheReconnect) {
        ASSERT_TRUE(robot.SendRobotData(pick, true, 1s).ok());
      }
      Result<daoai::Response> second = robot.RecvDaoaiData(2s);
      ASSERT_TRUE(second.ok()) << second.status().ToString();

      EXPECT_EQ(first->status, daoai::kObjectsFound);
      EXPECT_EQ(first->payload[0], 30000);  // the first of 3
      EXPECT_EQ(first->position[0], 5000);  // grasp 0 at x = 0.5 m
      EXPECT_EQ(second->status, daoai::kObjectsFound);
      EXPECT_EQ(second->payload[0], 20000);  // not the same grasp again
      EXPECT_EQ(second->position[0], 5100);
      ASSERT_TRUE(rig.planner_->WaitForHandedOut(2));
      EXPECT_EQ(rig.planner_->handed_out(),
                (std::vector<std::pair<int, int>>{{0, 0}, {0, 1}}));
      EXPECT_EQ(rig.handler_->QueueSize(0), 1);
      EXPECT_EQ(rig.handler_->stats().grasps_requeued, 0u);
      const ModbusMasterStats m = rig.master_->stats();
      EXPECT_EQ(m.connects, 2u);
      EXPECT_EQ(m.lost, 0u);
      EXPECT_EQ(m.resumed, 0u);  // not written again
      EXPECT_EQ(m.delivered, 1u);
      EXPECT_EQ(robot.stats().unexpected_responses, 0u);
    }
  }
}

// Issue 39: Stop() returns while a request waits in the handler (a pick
// behind a detection that does not end): the request is abandoned and pops
// nothing. Before, Stop joined a thread blocked in Handle() until the
// detection ended, so SIGTERM could hang with a Modbus robot.
TEST(ModbusMaster, StopReturnsAtOnceWhileARequestWaitsForItsDetection) {
  ModbusRig rig;
  rig.planner_->HoldPlans(true);
  ASSERT_EQ(rig.robot_->Call(daoai::kCaptureAndProcessAsync, 0)->status, daoai::kDetection);
  ASSERT_TRUE(rig.sim_->SendRobotData(rig.robot_->MakeRequest(daoai::kPickPose, 0), true, 1s).ok());
  ASSERT_TRUE(testing::WaitUntil([&] { return rig.master_->stats().requests == 2; }));
  std::promise<void> stopped;
  std::thread stopper([&] {
    rig.master_->Stop();
    stopped.set_value();
  });
  // A liveness bound, not a speed figure: without the abandon, Stop waits
  // for the held detection, i.e. forever.
  const bool returned = stopped.get_future().wait_for(10s) == std::future_status::ready;
  rig.planner_->HoldPlans(false);
  stopper.join();
  EXPECT_TRUE(returned) << "ModbusMaster::Stop() blocked behind the detection";
  ASSERT_TRUE(testing::WaitUntil([&] { return rig.handler_->Snapshot(0)->in_flight == 0; }));
  EXPECT_TRUE(rig.planner_->handed_out().empty());
  EXPECT_EQ(rig.handler_->QueueSize(0), 3);
}

// Fault injection (docs/reliability.md): the robot's Modbus slave vanishes
// between two pick cycles and stays away while the master retries, then
// comes back on the same address. Every grasp is handed out once, and the
// retries leak no descriptor.
TEST(ModbusMaster, SlaveVanishingBetweenCyclesLosesNothingAndLeaksNoDescriptor) {
  ModbusRig rig;
  ScriptedPlanner::Script pile;
  pile.pile = 4;
  rig.planner_->SetScript(0, pile);
  const int port = rig.sim_->port();
  ASSERT_EQ(rig.robot_->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  ASSERT_EQ(rig.robot_->Call(daoai::kPickPose, 0)->status, daoai::kObjectsFound);
  ASSERT_TRUE(rig.planner_->WaitForHandedOut(1));
  ASSERT_EQ(rig.planner_->handed_out().size(), 1u);
  const int fds = testing::OpenFdCount();  // slave listening + both ends connected
  rig.robot_.reset();
  rig.sim_->Stop();
  ASSERT_TRUE(testing::WaitUntil([&] { return !rig.master_->stats().connected; }));
  std::this_thread::sleep_for(300ms);  // refused reconnects with backoff (10..50 ms)
  EXPECT_LE(testing::OpenFdCount(), fds - 3) << "a retry left a descriptor open";
  rig.StartRobot(port);
  ASSERT_TRUE(rig.sim_->WaitForMaster(5s));
  FlowOptions f;
  f.flow = "pick";  // capture and pick until the bin is empty
  const FlowSummary s = rig.Run(f);
  EXPECT_TRUE(s.ok) << rig.out_.str();
  EXPECT_EQ(s.picks, 3);
  EXPECT_TRUE(rig.planner_->WaitForHandedOut(4));
  EXPECT_EQ(rig.planner_->handed_out().size(), 4u) << "every part of the pile picked once";
  EXPECT_EQ(rig.master_->stats().connects, 2u);
  EXPECT_EQ(testing::OpenFdCount(), fds);
}

TEST(ModbusMaster, ConnectsToARobotThatStartsLater) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  // Find a free port, then leave it free.
  const int port = FreeLoopbackPort();
  ASSERT_GT(port, 0);
  ModbusMasterOptions mo;
  mo.port = port;
  mo.backoff_min = 10ms;
  mo.backoff_max = 40ms;
  auto master = ModbusMaster::Start(handler, mo);
  ASSERT_TRUE(master.ok());
  std::this_thread::sleep_for(60ms);  // a few refused connects
  EXPECT_FALSE((*master)->stats().connected);
  ModbusRobotSimOptions so;
  so.port = port;
  auto sim = ModbusRobotSim::Start(so);
  ASSERT_TRUE(sim.ok());
  ASSERT_TRUE((*sim)->WaitForMaster(2s));
  auto robot = RobotClient::Over((*sim)->Transport(), RobotClientOptions{});
  Result<RobotReply> r = robot->Call(daoai::kSwitchConfig, 2);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->status, daoai::kSwitchConfigSuccess);
  (*master)->Stop();
  handler.Shutdown();
}

TEST(ModbusMaster, NewRequestOverAnUnreadResponseIsServed) {
  ModbusRig rig;
  ASSERT_TRUE(rig.sim_->SendRobotData(rig.robot_->MakeRequest(daoai::kSwitchConfig, 2), true, 1s).ok());
  const auto deadline = std::chrono::steady_clock::now() + 2s;
  while (rig.sim_->ReadRegister(145) == 0 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(1ms);
  }
  ASSERT_EQ(rig.sim_->ReadRegister(145), 1);
  // The robot program restarted: it never reads that response and asks again.
  ASSERT_TRUE(rig.sim_->SendRobotData(rig.robot_->MakeRequest(daoai::kSwitchConfig, 1), true, 1s).ok());
  const auto served = std::chrono::steady_clock::now() + 2s;
  while (rig.master_->stats().responses < 2 && std::chrono::steady_clock::now() < served) {
    std::this_thread::sleep_for(1ms);
  }
  ASSERT_EQ(rig.master_->stats().responses, 2u);
  EXPECT_EQ(rig.master_->stats().unread, 1u);
  Result<daoai::Response> r = rig.sim_->RecvDaoaiData(1s);
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->status, daoai::kSwitchConfigSuccess);
  EXPECT_EQ(rig.handler_->camera_config_id(), 1);
}

TEST(ModbusMaster, OverflowSaturatesTheRemainingCountAndRefusesOtherFields) {
  ModbusRig rig;
  ScriptedPlanner::Script many;
  many.grasps = 6;  // 5 remaining after the first pick: 50000 does not fit
  many.precision_error_mm = 5.0;  // 50000 does not fit either
  rig.planner_->SetScript(0, many);
  rig.planner_->SetScript(5, many);
  ASSERT_EQ(rig.robot_->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  Result<RobotReply> pick = rig.robot_->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(pick.ok());
  EXPECT_EQ(pick->status, daoai::kObjectsFound);
  EXPECT_DOUBLE_EQ(pick->payload[0], 3.2767);  // "3 or more left": still > 0 for the script
  ASSERT_TRUE(pick->X_BT.has_value());
  EXPECT_NEAR(pick->X_BT->translation().x(), 0.5, 1e-4);
  EXPECT_EQ(rig.master_->stats().saturated, 1u);

  Result<RobotReply> precision = rig.robot_->Call(daoai::kPrecisionCheck, 5);
  ASSERT_TRUE(precision.ok());
  EXPECT_EQ(precision->status, daoai::kUnknownCommand);
  EXPECT_EQ(precision->payload[0], 0.0);
  EXPECT_EQ(rig.master_->stats().refused, 1u);
}

// Seed 000's daoai_teach_pose never sets payload_1: after a pick pose with 4
// or more left the Modbus robot holds 3.2767 (saturated) and sends back 3,
// which names task 3, another pick task. The master remembers the answer as
// the robot read it, so binpick sees the stale 3 and files the pose on task 0,
// the task picked from (with the answer as built, 5 left, it would not match).
TEST(ModbusMaster, TeachAfterASaturatedRemainingCountIsFiledOnTheTaskPickedFrom) {
  ModbusRig rig;
  ScriptedPlanner::Script many;
  many.grasps = 6;
  rig.planner_->SetScript(0, many);
  ASSERT_EQ(rig.robot_->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  Result<RobotReply> pick = rig.robot_->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(pick.ok());
  ASSERT_DOUBLE_EQ(pick->payload[0], 3.2767);
  ASSERT_TRUE(rig.robot_->Send(daoai::kSendPose, 3).ok());  // trunc(daoai_payload_1)
  const auto deadline = std::chrono::steady_clock::now() + 5s;
  while (rig.planner_->taught().empty() && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(1ms);
  }
  const std::vector<TeachRequest> taught = rig.planner_->taught();
  ASSERT_EQ(taught.size(), 1u);
  EXPECT_EQ(taught[0].task.id, 0);
}

// Nothing is lost in 16 bits: the pick pose is encoded and range-checked
// before its grasp leaves the queue; one that cannot be sent stays queued and
// the robot gets UNKNOWN_COMMAND with its own pose (every seed program stops
// on it and none moves anywhere new).
TEST(ModbusMaster, PoseThatDoesNotFitStaysQueuedAndTheRobotKeepsItsPose) {
  RigOptions o;
  o.position_scale = 0.001;  // millimetres: 500 mm x MULT does not fit
  ModbusRig rig(o);
  // The robot 2 mm from the base origin (its own pose fits: 20000 x 0.1 um).
  rig.robot_->SetPose(MakePose(Mat3::Identity(), Vec3(0.002, -0.001, 0.003)));
  ASSERT_EQ(rig.robot_->Call(daoai::kCaptureAndProcess, 0)->status, daoai::kDetection);
  Result<RobotReply> pick = rig.robot_->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(pick.ok());
  EXPECT_EQ(pick->status, daoai::kUnknownCommand);
  EXPECT_EQ(pick->raw.position, (std::array<int32_t, 3>{20000, -10000, 30000}));
  EXPECT_EQ(pick->payload[0], 0.0);
  EXPECT_EQ(rig.master_->stats().refused, 1u);
  EXPECT_EQ(rig.handler_->QueueSize(0), 3);  // nothing popped
  EXPECT_TRUE(rig.planner_->handed_out().empty());
  EXPECT_EQ(rig.handler_->stats().grasps_requeued, 0u);  // never taken, never put back
  // A socket robot (int32 fields) on the same task gets the grasp.
  ClientContext socket_robot;
  daoai::Request request = rig.robot_->MakeRequest(daoai::kPickPose, 0);
  const std::optional<daoai::Response> r = rig.handler_->Handle(request, socket_robot);
  ASSERT_TRUE(r);
  EXPECT_EQ(r->status, daoai::kObjectsFound);
  EXPECT_EQ(r->payload[0], 30000);
  EXPECT_EQ(rig.handler_->QueueSize(0), 2);
}

TEST(ModbusMaster, OnlyTheConfiguredUnitIdIsServed) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ModbusRobotSimOptions so;
  so.unit_id = 3;
  auto sim = std::move(ModbusRobotSim::Start(so).value());
  auto robot = RobotClient::Over(sim->Transport(), RobotClientOptions{});
  robot->set_timeout(300ms);
  ModbusMasterOptions mo;
  mo.port = sim->port();
  mo.timeout = 50ms;
  mo.unit_id = 1;  // the robot is unit 3: it does not answer
  auto wrong = std::move(ModbusMaster::Start(handler, mo).value());
  Result<RobotReply> r = robot->Call(daoai::kSwitchConfig, 2);
  EXPECT_FALSE(r.ok());
  wrong->Stop();
  EXPECT_EQ(wrong->stats().requests, 0u);
  mo.unit_id = 3;
  auto right = std::move(ModbusMaster::Start(handler, mo).value());
  r = robot->Call(daoai::kSwitchConfig, 2);  // the request is still pending: answered
  ASSERT_TRUE(r.ok()) << r.status().ToString();
  EXPECT_EQ(r->status, daoai::kSwitchConfigSuccess);
  right->Stop();
  handler.Shutdown();
}

TEST(ModbusMaster, RejectsAnInvalidMapAtStart) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ModbusMasterOptions mo;
  mo.map.request_flag = 131;
  auto master = ModbusMaster::Start(handler, mo);
  ASSERT_FALSE(master.ok());
  EXPECT_EQ(master.status().code(), Status::Code::kInvalidArgument);
  handler.Shutdown();
}

// `binpick robot --modbus`: the executable is the slave, this process the master.
TEST(ModbusRobotCommand, PlaysThePickFlowAsAModbusSlave) {
  auto planner = std::make_shared<ScriptedPlanner>();
  ScriptedPlanner::Script pile;
  pile.grasps = 2;
  pile.pile = 3;
  planner->SetScript(0, pile);
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  const int port = FreeLoopbackPort();
  ASSERT_GT(port, 0);
  ModbusMasterOptions mo;
  mo.port = port;
  mo.backoff_min = 10ms;
  mo.backoff_max = 50ms;
  auto master = std::move(ModbusMaster::Start(handler, mo).value());
  const std::string cmd = BINPICK_BINARY_DIR "/bin/binpick-robot --modbus --flow pick --port " +
                          std::to_string(port) + " --wait-master 10";
  const auto [exit_code, out] = test::RunCommand(cmd);
  EXPECT_EQ(exit_code, 0) << out;
  EXPECT_NE(out.find("Modbus slave listening on 127.0.0.1:" + std::to_string(port)),
            std::string::npos) << out;
  EXPECT_NE(out.find("OBJECTS_FOUND(2) pose [0.5000 -0.1000 0.1000 | 0.0000 0.0000 1.5708 "
                     "0.0000] remaining 2 class 0"), std::string::npos) << out;
  EXPECT_NE(out.find("pick: 10 steps, 3 picks"), std::string::npos) << out;
  EXPECT_NE(out.find("BOX_EMPTY(41)"), std::string::npos) << out;
  master->Stop();
  handler.Shutdown();
}

// Cross-implementation: the robot is a pymodbus slave (scripts/modbus_robot_sim.py).
TEST(ModbusMaster, ServesAPymodbusRobotInBothVersions) {
  if (std::system("/usr/bin/python3 -c 'import pymodbus.server' >/dev/null 2>&1") != 0) {
    GTEST_SKIP() << "no /usr/bin/python3 with pymodbus (scripts/install_deps.sh)";
  }
  for (int version : {1, 2}) {
    auto planner = std::make_shared<ScriptedPlanner>();
    RequestHandler handler(MakeTestCell(), planner, nullptr);
    const int port = FreeLoopbackPort();
    ASSERT_GT(port, 0);
    ModbusMasterOptions mo;
    mo.port = port;
    mo.backoff_min = 20ms;
    mo.backoff_max = 100ms;
    auto master = std::move(ModbusMaster::Start(handler, mo).value());
    const std::string cmd = "/usr/bin/python3 " BINPICK_SOURCE_DIR
                            "/scripts/modbus_robot_sim.py --count 40 --version " +
                            std::to_string(version) + " --port " + std::to_string(port);
    const auto [exit_code, out] = test::RunCommand(cmd);
    EXPECT_EQ(exit_code, 0) << out;
    EXPECT_NE(out.find("40 of 40 answers right"), std::string::npos) << out;
    master->Stop();
    EXPECT_EQ(master->stats().requests, 40u) << "version " << version;
    EXPECT_EQ(master->stats().responses, 40u) << "version " << version;
    handler.Shutdown();
  }
}

// Figure: request -> response latency at the default poll interval (printed,
// not asserted; every answer is checked).
TEST(ModbusLatency, MeasuresRequestToResponseAtTheDefaultPollInterval) {
  RigOptions o;
  o.poll = ModbusMasterOptions{}.poll_interval;
  ModbusRig rig(o);
  std::vector<double> ms;
  std::mt19937 rng{7};
  for (int i = 0; i < 200; ++i) {
    // The robot moves between requests: send at a random phase of the poll.
    std::this_thread::sleep_for(std::chrono::microseconds(500 + rng() % 3000));
    const auto t0 = std::chrono::steady_clock::now();
    Result<RobotReply> r = rig.robot_->Call(daoai::kSwitchConfig, 1 + i % 2);
    ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    ASSERT_TRUE(r.ok());
    ASSERT_EQ(r->status, daoai::kSwitchConfigSuccess);
  }
  std::sort(ms.begin(), ms.end());
  std::cout << "modbus request->response (switch config, poll " << o.poll.count()
            << " ms, 200 requests): median " << ms[ms.size() / 2] << " ms, p99 "
            << ms[ms.size() * 99 / 100] << " ms, max " << ms.back() << " ms\n";
}

}  // namespace
}  // namespace bp
