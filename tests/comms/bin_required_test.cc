// Issue 41, "a frame without a bin is refused when `required`", through the
// protocols on real loopback connections: the real BinPickingPlanner (bin
// detection on the raw frame, ground-truth detections: TruthPerception) on
// a small synthetic pile whose source shows the bin or a bare floor. A
// capture of the bare floor is answered with the protocol's capture-failure
// code (DaoAI and Modbus 9 CAPTURE_FAIL, GRI PIPELINE_NOT_AVAILABLE), its
// reason reaches the observers (status page, metrics, recorder; the log line
// is written beside them), nothing is handed out from it, and the next
// capture with the bin in view is served.
#include <gtest/gtest.h>

#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "comms/daoai_server.h"
#include "comms/gri_handler.h"
#include "comms/gri_server.h"
#include "comms/modbus_master.h"
#include "comms/modbus_robot_sim.h"
#include "comms/request_handler.h"
#include "comms/robot_client.h"
#include "grasp/bin_picking_planner.h"
#include "pipeline/capture_source.h"
#include "pipeline/truth_perception.h"
#include "tests/testing/no_bin_source.h"

namespace bp {
namespace {

using namespace std::chrono_literals;

// A rendering and the planner per capture; generous for the sanitizer trees
// with other tests on the two cores (no timed assertion rests on it).
constexpr std::chrono::milliseconds kAnswerTimeout = 120s;

// The capture failures' reasons, as the status page and the recorder get them.
class CaptureFailures final : public ServerObserver {
 public:
  void OnDetection(const DetectionEvent& event) override {
    if (event.capture_status.ok()) return;
    std::lock_guard lock(mutex_);
    reasons_.push_back(event.capture_status.ToString());
  }
  std::vector<std::string> reasons() const {
    std::lock_guard lock(mutex_);
    return reasons_;
  }

 private:
  mutable std::mutex mutex_;
  std::vector<std::string> reasons_;
};

// The default cell with `bin.detect: required` on 3 bushings (scene 4: each
// has a grasp), the planner on a source whose bin the test takes away, and
// the request handler every transport serves.
class BinRequiredRig {
 public:
  BinRequiredRig() {
    Result<Cell> cell = LoadDefaultCell();
    EXPECT_TRUE(cell.ok()) << cell.status().ToString();
    cell->source.kind = SourceSpec::Kind::kSynthetic;
    cell->source.num_parts = 3;
    cell->source.part_classes = {0};
    cell->source.seed = 4;
    cell->source.simulate_picks = true;
    cell->bin.detect.mode = BinDetectSpec::Mode::kRequired;
    Result<std::unique_ptr<CaptureSource>> synthetic = MakeCaptureSource(*cell);
    EXPECT_TRUE(synthetic.ok()) << synthetic.status().ToString();
    auto source = std::make_unique<testing::BinInViewSource>(*cell, std::move(*synthetic));
    source_ = source.get();
    BinPickingPlannerOptions options;
    options.teach_file = "-";
    auto planner = BinPickingPlanner::Create(*cell, std::make_shared<TruthPerception>(*cell), std::move(source),
                                             options);
    EXPECT_TRUE(planner.ok()) << planner.status().ToString();
    handler_ = std::make_unique<RequestHandler>(*cell, std::shared_ptr<GraspPlanner>(std::move(*planner)), nullptr);
    handler_->AddObserver(failures_);
  }
  ~BinRequiredRig() { handler_->Shutdown(); }

  void set_bin_in_view(bool in_view) { source_->set_bin_in_view(in_view); }
  RequestHandler& handler() { return *handler_; }
  std::vector<std::string> reasons() const { return failures_->reasons(); }

 private:
  testing::BinInViewSource* source_ = nullptr;  // owned by the planner
  std::shared_ptr<CaptureFailures> failures_ = std::make_shared<CaptureFailures>();
  std::unique_ptr<RequestHandler> handler_;
};

// The robot's side over either DaoAI transport: capture and pick on task 0
// with the bin out of view, then in view.
void ExpectRefusedThenServed(BinRequiredRig& rig, RobotClient& robot) {
  rig.set_bin_in_view(false);
  Result<RobotReply> refused = robot.Call(daoai::kCaptureAndProcess, 0);
  ASSERT_TRUE(refused.ok()) << refused.status().ToString();
  EXPECT_EQ(refused->status, daoai::kCaptureFail);
  const std::vector<std::string> reasons = rig.reasons();
  ASSERT_EQ(reasons.size(), 1u);
  EXPECT_NE(reasons[0].find("bin not found (bin.detect: required)"), std::string::npos) << reasons[0];
  EXPECT_NE(reasons[0].find("no rim"), std::string::npos) << reasons[0];
  // Nothing to pick from a refused capture (seed 000's vocabulary).
  Result<RobotReply> nothing = robot.Call(daoai::kPickPose, 0);
  ASSERT_TRUE(nothing.ok()) << nothing.status().ToString();
  EXPECT_EQ(nothing->status, daoai::kNoObjectFound);
  EXPECT_FALSE(nothing->X_BT.has_value() && nothing->payload[0] > 0);

  rig.set_bin_in_view(true);
  Result<RobotReply> captured = robot.Call(daoai::kCaptureAndProcess, 0);
  ASSERT_TRUE(captured.ok()) << captured.status().ToString();
  EXPECT_EQ(captured->status, daoai::kDetection);
  Result<RobotReply> pick = robot.Call(daoai::kPickPose, 0);
  ASSERT_TRUE(pick.ok()) << pick.status().ToString();
  EXPECT_EQ(pick->status, daoai::kObjectsFound);
  EXPECT_EQ(pick->payload[0], 3.0);  // remaining, this one included
  ASSERT_TRUE(pick->X_BT.has_value());
  EXPECT_EQ(rig.reasons().size(), 1u);  // no other capture failed
}

TEST(BinRequired, AFrameWithoutTheBinIsAnsweredCaptureFailOverTheDaoaiSocketThenTheNextCaptureIsServed) {
  BinRequiredRig rig;
  DaoaiServerOptions options;
  options.port = 0;
  Result<std::unique_ptr<DaoaiServer>> server = DaoaiServer::Start(rig.handler(), options);
  ASSERT_TRUE(server.ok()) << server.status().ToString();
  RobotClientOptions o;
  o.port = (*server)->port();
  o.timeout = kAnswerTimeout;
  Result<std::unique_ptr<RobotClient>> robot = RobotClient::Connect(o);
  ASSERT_TRUE(robot.ok()) << robot.status().ToString();
  ExpectRefusedThenServed(rig, *robot.value());
  robot.value().reset();
  (*server)->Stop();
}

TEST(BinRequired, AFrameWithoutTheBinIsAnsweredCaptureFailOverModbusThenTheNextCaptureIsServed) {
  BinRequiredRig rig;
  Result<std::unique_ptr<ModbusRobotSim>> sim = ModbusRobotSim::Start(ModbusRobotSimOptions{});
  ASSERT_TRUE(sim.ok()) << sim.status().ToString();
  ModbusMasterOptions mo;
  mo.port = (*sim)->port();
  Result<std::unique_ptr<ModbusMaster>> master = ModbusMaster::Start(rig.handler(), mo);
  ASSERT_TRUE(master.ok()) << master.status().ToString();
  ASSERT_TRUE((*sim)->WaitForMaster(30s));
  RobotClientOptions o;
  o.timeout = kAnswerTimeout;
  std::unique_ptr<RobotClient> robot = RobotClient::Over((*sim)->Transport(), o);
  ExpectRefusedThenServed(rig, *robot);
  robot.reset();
  (*master)->Stop();
  (*sim)->Stop();
}

// Sends `request` over `robot` and reads the one response of its format.
gri::Response AskGri(RobotClient& robot, const gri::Request& request) {
  const std::vector<uint8_t> bytes = gri::EncodeRequest(request).value();
  EXPECT_TRUE(robot.SendBytes(bytes.data(), bytes.size()).ok());
  std::vector<uint8_t> in(gri::ResponseSize(request.format));
  const Status s = robot.ReceiveBytes(in.data(), in.size());
  EXPECT_TRUE(s.ok()) << s.ToString();
  Result<gri::Response> r = gri::DecodeResponse(in);
  EXPECT_TRUE(r.ok()) << r.status().ToString();
  return r.ok() ? *r : gri::Response{};
}

TEST(BinRequired, AFrameWithoutTheBinFailsTheGriJobInBothFormatsThenTheNextTriggerIsServed) {
  BinRequiredRig rig;
  GriHandler gri(rig.handler());
  GriServerOptions options;
  options.v2_port = -1;
  options.official_port = -1;
  options.processing_timeout = kAnswerTimeout;
  Result<std::unique_ptr<GriServer>> server = GriServer::Start(gri, options);
  ASSERT_TRUE(server.ok()) << server.status().ToString();
  size_t failed = 0;
  for (const gri::Format format : {gri::Format::kV2, gri::Format::kOfficial}) {
    SCOPED_TRACE(gri::ToString(format));
    const bool v2 = format == gri::Format::kV2;
    RobotClientOptions o;
    o.port = v2 ? (*server)->v2_port() : (*server)->official_port();
    o.timeout = kAnswerTimeout;
    Result<std::unique_ptr<RobotClient>> robot = RobotClient::Connect(o);
    ASSERT_TRUE(robot.ok()) << robot.status().ToString();
    gri::Request trigger;
    trigger.format = format;
    trigger.action = gri::kTriggerJobSync;
    trigger.job_id = 0;
    trigger.pose_format = 2;
    trigger.pose = {0, 0, 0, 0, 0, 0, 1};
    gri::Request status = trigger;
    status.action = gri::kGetJobStatus;
    status.pose_format = 0;
    // Job status: v2 data_1, official data_2.
    const auto job_status = [&](const gri::Response& r) { return r.data[v2 ? 0 : 1]; };

    rig.set_bin_in_view(false);
    const gri::Response refused = AskGri(**robot, trigger);
    EXPECT_EQ(refused.error_code, gri::WireErrorCode(format, gri::Code::kPipelineNotAvailable));
    const std::vector<std::string> reasons = rig.reasons();
    ASSERT_EQ(reasons.size(), ++failed);
    EXPECT_NE(reasons.back().find("bin not found (bin.detect: required)"), std::string::npos) << reasons.back();
    // The failure was reported with the trigger's answer: the job is inactive.
    EXPECT_EQ(job_status(AskGri(**robot, status)), static_cast<int32_t>(gri::JobStatus::kInactive));

    rig.set_bin_in_view(true);
    const gri::Response served = AskGri(**robot, trigger);
    EXPECT_EQ(served.error_code, gri::WireErrorCode(format, gri::Code::kOk));
    EXPECT_GT(served.pose[2], 0.0);  // a grasp above the floor (mm), not an empty pose
    EXPECT_EQ(job_status(AskGri(**robot, status)), static_cast<int32_t>(gri::JobStatus::kDone));
    EXPECT_EQ(rig.reasons().size(), failed);
  }
  (*server)->Stop();
}

}  // namespace
}  // namespace bp
