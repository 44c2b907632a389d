// The GRI server over real loopback sockets, in both wire formats, with the
// scripted (test double) planner. Golden response bytes are written by hand
// from the tables in docs/protocols.md; grasp poses come from ScriptedPlanner.
#include "comms/gri_server.h"

#include <gtest/gtest.h>

#include <cctype>
#include <cmath>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "comms/daoai_server.h"
#include "comms/robot_client.h"
#include "core/fault_points.h"
#include "tests/testing/hex.h"
#include "tests/testing/scripted_planner.h"

namespace bp {
namespace {

using gri::Format;
using testing::MakeTestCell;
using testing::ScriptedPlanner;
using namespace std::chrono_literals;

using testing::FromHex;

// ScriptedPlanner plus what the GRI needs and it does not do: `related`
// poses per grasp (1, 2, ... cm above the grasp), grasps moved 2 m further
// along x (`far`: beyond the official format's +-2147 mm) and the robot pose
// of the last capture.
class RelatedPlanner final : public GraspPlanner {
 public:
  explicit RelatedPlanner(std::shared_ptr<ScriptedPlanner> inner) : inner_(std::move(inner)) {}
  Result<CaptureHandle> Capture(const PlanRequest& request) override {
    {
      std::lock_guard lock(mutex_);
      last_X_BF_ = request.X_BF;
    }
    return inner_->Capture(request);
  }
  Result<PlanResult> Plan(const PlanRequest& request, const CapturedScene& scene) override {
    Result<PlanResult> plan = inner_->Plan(request, scene);
    if (plan.ok()) {
      for (int i : far) {
        if (i < static_cast<int>(plan->grasps.size())) {
          plan->grasps[static_cast<size_t>(i)].X_BT.translation().x() += 2.0;
        }
      }
      for (Grasp& g : plan->grasps) {
        for (int k = 1; k <= related; ++k) {
          g.related_X_B.push_back(g.X_BT * MakePose(Mat3::Identity(), Vec3(0, 0, 0.01 * k)));
        }
      }
    }
    return plan;
  }
  void NotifyHandedOut(const TaskSpec& task, const Grasp& grasp) override {
    inner_->NotifyHandedOut(task, grasp);
  }
  std::optional<Pose> last_X_BF() const {
    std::lock_guard lock(mutex_);
    return last_X_BF_;
  }
  int related = 0;
  std::set<int> far;  // indices in the plan; set before the detection

 private:
  std::shared_ptr<ScriptedPlanner> inner_;
  mutable std::mutex mutex_;
  std::optional<Pose> last_X_BF_;
};

class GriServerTest : public ::testing::TestWithParam<Format> {
 protected:
  void SetUp() override { Start(5000ms, 5000ms); }

  void Start(std::chrono::milliseconds processing_timeout, std::chrono::milliseconds read_timeout) {
    server_.reset();
    gri_.reset();
    handler_.reset();
    handler_ = std::make_unique<RequestHandler>(MakeTestCell(), planner_, nullptr);
    gri_ = std::make_unique<GriHandler>(*handler_);
    GriServerOptions o;
    o.v2_port = -1;
    o.official_port = -1;
    o.processing_timeout = processing_timeout;
    o.read_timeout = read_timeout;
    server_ = std::move(GriServer::Start(*gri_, o).value());
  }

  void TearDown() override {
    fault::DisarmAll();  // a failed fault test leaves nothing armed for the next
    server_.reset();
    handler_->Shutdown();
  }

  Format format() const { return GetParam(); }
  bool v2() const { return format() == Format::kV2; }
  int Port() const { return v2() ? server_->v2_port() : server_->official_port(); }

  std::unique_ptr<RobotClient> Connect(int port = 0) {
    RobotClientOptions o;
    o.port = port ? port : Port();
    o.timeout = 5000ms;
    return std::move(RobotClient::Connect(o).value());
  }

  gri::Request Make(uint8_t action, int job = 0, uint8_t pose_format = 2) const {
    gri::Request r;
    r.format = format();
    r.action = action;
    r.job_id = job;
    r.pose_format = pose_format;
    r.pose = {0, 0, 0, 0, 0, 0, 1};
    return r;
  }

  // Sends `request`, reads one response of its format.
  gri::Response Ask(RobotClient& robot, const gri::Request& request) {
    const std::vector<uint8_t> bytes = gri::EncodeRequest(request).value();
    EXPECT_TRUE(robot.SendBytes(bytes.data(), bytes.size()).ok());
    return Receive(robot, request.format);
  }
  gri::Response Receive(RobotClient& robot, Format f) {
    std::vector<uint8_t> in(gri::ResponseSize(f));
    const bp::Status s = robot.ReceiveBytes(in.data(), in.size());
    EXPECT_TRUE(s.ok()) << s.ToString();
    last_bytes_ = in;
    Result<gri::Response> r = gri::DecodeResponse(in);
    EXPECT_TRUE(r.ok()) << r.status().ToString();
    return r.ok() ? *r : gri::Response{};
  }
  gri::Response Ask(RobotClient& robot, uint8_t action, int job = 0, uint8_t pose_format = 2) {
    return Ask(robot, Make(action, job, pose_format));
  }

  int32_t Code(gri::Code c) const { return gri::WireErrorCode(format(), c); }
  // v2 data_1 / official data_2, and v2 data_2 / official data_3.
  int32_t Primary(const gri::Response& r) const { return r.data[v2() ? 0 : 1]; }
  int32_t Related(const gri::Response& r) const { return r.data[v2() ? 1 : 2]; }
  int32_t JobStatus(const gri::Response& r) const { return Primary(r); }

  static bool ClosedByServer(RobotClient& robot) {
    uint8_t byte = 0;
    const bp::Status s = robot.ReceiveBytes(&byte, 1);
    return !s.ok() && s.message().find("closed") != std::string::npos;
  }

  // Polls GET_JOB_STATUS until it is not RUNNING.
  int32_t WaitWhileRunning(RobotClient& robot, int job) {
    for (int i = 0; i < 500; ++i) {
      const gri::Response r = Ask(robot, gri::kGetJobStatus, job);
      if (JobStatus(r) != static_cast<int32_t>(gri::JobStatus::kRunning)) return JobStatus(r);
      std::this_thread::sleep_for(5ms);
    }
    return -1;
  }

  std::shared_ptr<ScriptedPlanner> scripted_ = std::make_shared<ScriptedPlanner>();
  std::shared_ptr<RelatedPlanner> planner_ = std::make_shared<RelatedPlanner>(scripted_);
  std::unique_ptr<RequestHandler> handler_;
  std::unique_ptr<GriHandler> gri_;
  std::unique_ptr<GriServer> server_;
  std::vector<uint8_t> last_bytes_;
};

constexpr int32_t kInactive = static_cast<int32_t>(gri::JobStatus::kInactive);
constexpr int32_t kRunning = static_cast<int32_t>(gri::JobStatus::kRunning);
constexpr int32_t kDone = static_cast<int32_t>(gri::JobStatus::kDone);
constexpr int32_t kFailed = static_cast<int32_t>(gri::JobStatus::kFailed);

TEST_P(GriServerTest, StatusReportsReady) {
  auto robot = Connect();
  const gri::Response r = Ask(*robot, gri::kStatus, 0, 0);
  EXPECT_EQ(r.error_code, 0);
  EXPECT_EQ(Primary(r), 1);
  EXPECT_EQ(r.action, gri::kStatus);
  if (!v2()) {
    EXPECT_EQ(r.data[0], 0);  // node return code
  }
}

// A robot with Nagle's algorithm on (no TCP_NODELAY) that writes the header
// and the body of a request separately holds the body until the header is
// acknowledged; without the server's immediate ACK each round waits for the
// kernel's delayed ACK (40 ms at least). Same generous bound as the DaoAI
// test (daoai_server_test.cc): fewer than half of 50 rounds at 30 ms or more.
TEST_P(GriServerTest, RequestWrittenHeaderThenBodyIsNotHeldByTheDelayedAck) {
  RobotClientOptions o;
  o.port = Port();
  o.timeout = 5000ms;
  o.tcp_nodelay = false;
  auto robot = std::move(RobotClient::Connect(o).value());
  const std::vector<uint8_t> bytes = gri::EncodeRequest(Make(gri::kStatus, 0, 0)).value();
  const size_t header = gri::HeaderSize(format());
  int held = 0;
  for (int i = 0; i < 50; ++i) {
    const auto t0 = std::chrono::steady_clock::now();
    ASSERT_TRUE(robot->SendBytes(bytes.data(), header).ok());
    ASSERT_TRUE(robot->SendBytes(bytes.data() + header, bytes.size() - header).ok());
    EXPECT_EQ(Primary(Receive(*robot, format())), 1);
    if (std::chrono::steady_clock::now() - t0 >= 30ms) ++held;
  }
  EXPECT_LT(held, 25) << held << " of 50 header-then-body requests took 30 ms or more";
}

TEST_P(GriServerTest, SyncTriggerReturnsTheFirstPoseThenTheRestUntilExhaustedAndInactive) {
  auto robot = Connect();
  gri::Response r = Ask(*robot, gri::kTriggerJobSync, 0);
  ASSERT_EQ(r.error_code, 0);
  EXPECT_NEAR(r.pose[0], 500, 1e-3);  // mm (pose format 2)
  EXPECT_NEAR(r.pose[1], -100, 1e-3);
  EXPECT_NEAR(r.pose[2], 100, 1e-3);
  EXPECT_NEAR(r.pose[5], std::sqrt(0.5), 1e-6);  // z of x, y, z, w
  EXPECT_NEAR(r.pose[6], std::sqrt(0.5), 1e-6);
  EXPECT_EQ(Primary(r), 2);
  EXPECT_EQ(Related(r), 1);  // the part's own pose
  EXPECT_EQ(JobStatus(Ask(*robot, gri::kGetJobStatus, 0)), kDone);

  r = Ask(*robot, gri::kGetNextPose, 0);
  EXPECT_EQ(r.error_code, 0);
  EXPECT_NEAR(r.pose[0], 510, 1e-3);
  EXPECT_EQ(Primary(r), 1);
  r = Ask(*robot, gri::kGetNextPose, 0);
  EXPECT_EQ(r.error_code, 0);
  EXPECT_NEAR(r.pose[0], 520, 1e-3);
  EXPECT_EQ(Primary(r), 0);
  // All results taken: back to INACTIVE, and nothing more.
  EXPECT_EQ(JobStatus(Ask(*robot, gri::kGetJobStatus, 0)), kInactive);
  EXPECT_EQ(Ask(*robot, gri::kGetNextPose, 0).error_code, Code(gri::Code::kNoPosesFound));
  EXPECT_TRUE(scripted_->WaitForHandedOut(3));
  EXPECT_EQ(scripted_->handed_out().size(), 3u);
}

TEST_P(GriServerTest, OfficialPoseAnswersCarryTheFillLevelInData4To6) {
  const double H = handler_->cell().bin.inner_size.z();
  ScriptedPlanner::Script s;
  FillLevel fill;
  fill.mean_height = 0.25 * H;
  fill.max_height = 0.8 * H;
  fill.occupied_fraction = 0.62;
  s.fill = fill;
  scripted_->SetScript(0, s);
  auto robot = Connect();
  const gri::Response trigger = Ask(*robot, gri::kTriggerJobSync, 0);
  ASSERT_EQ(trigger.error_code, 0);
  const gri::Response next = Ask(*robot, gri::kGetNextPose, 0);
  ASSERT_EQ(next.error_code, 0);
  for (const gri::Response& r : {trigger, next}) {
    if (v2()) {
      EXPECT_EQ(r.data[3], 0);  // v2: no room; data_4 / data_5 untouched
      EXPECT_EQ(r.data[4], 0);
    } else {
      EXPECT_EQ(r.data[3], 2500);  // percent of the inner height x 100
      EXPECT_EQ(r.data[4], 8000);
      EXPECT_EQ(r.data[5], 6200);  // percent of the floor x 100
    }
  }
  // Answers without a pose carry no fill level.
  EXPECT_EQ(Ask(*robot, gri::kGetJobStatus, 0).data[3], 0);
}

TEST_P(GriServerTest, SyncTriggerCapturesWithTheRobotPoseSent) {
  auto robot = Connect();
  gri::Request req = Make(gri::kTriggerJobSync, 0, 1);
  // Format 1: v2 metres, x, y, z, w; official millimetres, w, x, y, z.
  req.pose = v2() ? std::array<double, 7>{0.5, -0.25, 0.3, 0, 0, 0, 1}
                  : std::array<double, 7>{500, -250, 300, 1, 0, 0, 0};
  ASSERT_EQ(Ask(*robot, req).error_code, 0);
  const std::optional<Pose> X_BF = planner_->last_X_BF();
  ASSERT_TRUE(X_BF.has_value());
  EXPECT_TRUE(X_BF->translation().isApprox(Vec3(0.5, -0.25, 0.3), 1e-6));  // v2: float32
  EXPECT_TRUE(X_BF->linear().isApprox(Mat3::Identity(), 1e-9));
}

TEST_P(GriServerTest, AsyncTriggerAnswersAtOnceAndIsPolledUntilDone) {
  scripted_->HoldPlans(true);
  auto robot = Connect();
  EXPECT_EQ(Ask(*robot, gri::kTriggerJobAsync, 1).error_code, 0);
  EXPECT_EQ(JobStatus(Ask(*robot, gri::kGetJobStatus, 1)), kRunning);
  EXPECT_EQ(Ask(*robot, gri::kGetNextPose, 1).error_code, Code(gri::Code::kJobStillRunning));
  scripted_->HoldPlans(false);
  EXPECT_EQ(WaitWhileRunning(*robot, 1), kDone);
  const gri::Response r = Ask(*robot, gri::kGetNextPose, 1);
  EXPECT_EQ(r.error_code, 0);
  EXPECT_NEAR(r.pose[1], -80, 1e-3);  // task 1
  EXPECT_EQ(Primary(r), 2);
}

TEST_P(GriServerTest, RelatedPosesAreThePartsOtherGraspsThenThePart) {
  planner_->related = 2;
  auto robot = Connect();
  gri::Response r = Ask(*robot, gri::kTriggerJobSync, 0);
  ASSERT_EQ(r.error_code, 0);
  EXPECT_EQ(Related(r), 3);
  // Grasp 0 of task 0 at z = 100 mm; related grasps 1 and 2 cm along the
  // tool z axis (the base z axis here), then the part (scripted X_BO = X_BT).
  for (double z : {110.0, 120.0, 100.0}) {
    r = Ask(*robot, gri::kGetRelatedPose, 0);
    ASSERT_EQ(r.error_code, 0);
    EXPECT_NEAR(r.pose[2], z, 1e-3);
    EXPECT_EQ(Primary(r), 2);
  }
  EXPECT_EQ(Related(r), 0);
  EXPECT_EQ(Ask(*robot, gri::kGetRelatedPose, 0).error_code, Code(gri::Code::kNoRelatedPoses));
  // The next primary brings its own related poses.
  r = Ask(*robot, gri::kGetNextPose, 0);
  EXPECT_EQ(Related(r), 3);
  EXPECT_NEAR(Ask(*robot, gri::kGetRelatedPose, 0).pose[0], 510, 1e-3);
}

TEST_P(GriServerTest, NoObjectsAnswersNoPosesFoundAndTheJobIsInactive) {
  ScriptedPlanner::Script none;
  none.grasps = 0;
  scripted_->SetScript(0, none);
  auto robot = Connect();
  EXPECT_EQ(Ask(*robot, gri::kTriggerJobSync, 0).error_code, Code(gri::Code::kNoPosesFound));
  EXPECT_EQ(JobStatus(Ask(*robot, gri::kGetJobStatus, 0)), kInactive);
}

TEST_P(GriServerTest, FailedCaptureMakesTheJobFailedUntilReported) {
  ScriptedPlanner::Script broken;
  broken.capture_fails = true;
  scripted_->SetScript(1, broken);
  auto robot = Connect();
  EXPECT_EQ(Ask(*robot, gri::kTriggerJobAsync, 1).error_code, 0);
  EXPECT_EQ(WaitWhileRunning(*robot, 1), kFailed);
  EXPECT_EQ(Ask(*robot, gri::kGetNextPose, 1).error_code, Code(gri::Code::kPipelineNotAvailable));
  EXPECT_EQ(JobStatus(Ask(*robot, gri::kGetJobStatus, 1)), kInactive);
}

TEST_P(GriServerTest, HandEyeActionsOnACellWithoutCalibrationAreAConfigError) {
  auto robot = Connect();
  for (uint8_t action : {gri::kHecInit, gri::kHecSetPose, gri::kHecCalibrate}) {
    gri::Request req = Make(action, 0, 2);
    req.data = {0, action == gri::kHecSetPose ? 1 : 0, 0, 0};  // pipeline 0, slot 1
    EXPECT_EQ(Ask(*robot, req).error_code, Code(gri::Code::kHecConfigError));  // 17 / -14
  }
}

TEST_P(GriServerTest, RequestErrorsAreAnsweredAndTheConnectionStaysOpen) {
  auto robot = Connect();
  gri::Response r = Ask(*robot, gri::kGetNextPose, 42);
  EXPECT_EQ(r.error_code, Code(gri::Code::kJobDoesNotExist));
  EXPECT_EQ(r.job_id, 42);
  EXPECT_EQ(Ask(*robot, gri::kTriggerJobSync, 0, 0).error_code, Code(gri::Code::kInvalidRequest));

  std::vector<uint8_t> bytes = gri::EncodeRequest(Make(gri::kStatus)).value();
  const size_t version_at = v2() ? 1 : 4, format_at = v2() ? 3 : 6, action_at = v2() ? 4 : 7;
  auto send_corrupt = [&](size_t at, uint8_t value) {
    std::vector<uint8_t> b = bytes;
    b[at] = value;
    EXPECT_TRUE(robot->SendBytes(b.data(), b.size()).ok());
    return Receive(*robot, format());
  };
  EXPECT_EQ(send_corrupt(version_at, 7).error_code, Code(gri::Code::kUnknownProtocolVersion));
  EXPECT_EQ(send_corrupt(format_at, 11).error_code, Code(gri::Code::kInvalidRequest));
  r = send_corrupt(action_at, 10);
  EXPECT_EQ(r.error_code, Code(gri::Code::kInvalidAction));
  EXPECT_EQ(r.action, 10);
  EXPECT_EQ(Ask(*robot, gri::kStatus).error_code, 0);  // still in step
}

TEST_P(GriServerTest, UnframeableRequestsAreAnsweredThenTheConnectionIsClosed) {
  const std::vector<uint8_t> good = gri::EncodeRequest(Make(gri::kStatus)).value();
  const size_t length_at = v2() ? 2 : 5;
  struct Case {
    const char* name;
    std::vector<uint8_t> bytes;
    gri::Code code;
  };
  std::vector<Case> cases;
  cases.push_back({"first byte is no magic", {9, 2, 50, 2, 1}, gri::Code::kInvalidRequest});
  std::vector<uint8_t> b = good;
  b[length_at] = static_cast<uint8_t>(good.size() - 1);  // disagrees with the bytes sent
  cases.push_back({"length field disagrees", b, gri::Code::kInvalidRequestLength});
  b = good;
  b.resize(good.size() - 10);
  b[length_at] = static_cast<uint8_t>(b.size());
  cases.push_back({"short message", b, gri::Code::kInvalidRequestLength});
  b = good;
  b.resize(good.size() + 6);
  b[length_at] = static_cast<uint8_t>(b.size());
  cases.push_back({"long message", b, gri::Code::kInvalidRequestLength});
  if (!v2()) {
    b = good;
    b[1] = 'X';
    cases.push_back({"official magic GXI", b, gri::Code::kInvalidRequest});
  }
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    auto robot = Connect();
    ASSERT_TRUE(robot->SendBytes(c.bytes.data(), c.bytes.size()).ok());
    const gri::Response r = Receive(*robot, format());
    EXPECT_EQ(r.error_code, Code(c.code));
    EXPECT_TRUE(ClosedByServer(*robot));
  }
}

TEST_P(GriServerTest, HalfAMessageThenSilenceIsClosedByTheReadTimeout) {
  Start(5000ms, 200ms);
  auto robot = Connect();
  const std::vector<uint8_t> good = gri::EncodeRequest(Make(gri::kStatus)).value();
  ASSERT_TRUE(robot->SendBytes(good.data(), good.size() / 2).ok());
  EXPECT_TRUE(ClosedByServer(*robot));
}

TEST_P(GriServerTest, NoResultWithinTheProcessingTimeoutAnswersProcessingTimeout) {
  Start(150ms, 5000ms);
  scripted_->HoldPlans(true);
  auto robot = Connect();
  EXPECT_EQ(Ask(*robot, gri::kTriggerJobSync, 0).error_code, Code(gri::Code::kProcessingTimeout));
  scripted_->HoldPlans(false);
  // The late result is not handed to anyone: the robot can still fetch it all.
  EXPECT_EQ(WaitWhileRunning(*robot, 0), kDone);
  EXPECT_EQ(handler_->QueueSize(0), 3);
  EXPECT_NEAR(Ask(*robot, gri::kGetNextPose, 0).pose[0], 500, 1e-3);
}

TEST_P(GriServerTest, EachPortServesBothFormats) {
  // The other format's port: the first byte decides.
  auto robot = Connect(v2() ? server_->official_port() : server_->v2_port());
  const gri::Response r = Ask(*robot, gri::kStatus);
  EXPECT_EQ(r.format, format());
  EXPECT_EQ(r.error_code, 0);
}

TEST_P(GriServerTest, SyncTriggerResponseMatchesGoldenBytes) {
  // Job 1, first grasp (500, -80, 100) mm, rotated pi/2 about z; pose format 2.
  const char* kV2 =
      "02 02 37 02 02"                       // magic, version, length 55, format 2, action 2
      "01 00"                                // job 1, NO_ERROR
      "0000FA43 0000A0C2 0000C842"           // 500.0f, -80.0f, 100.0f
      "00000000 00000000 F304353F F304353F"  // quaternion x, y, z, w
      "02000000 01000000 00000000 00000000 00000000";  // 2 primary, 1 related left
  const char* kOfficial =
      "47524900 01 50 02 02"                 // "GRI\0", version 1, length 80, format 2, action 2
      "0100 0000"                            // job 1, success
      "0065CD1D 004C3BFB 00E1F505"           // 500e6, -80e6, 100e6
      "00000000 00000000 23CA0A00 23CA0A00"  // quaternion x, y, z, w x 1e6
      "00000000 02000000 01000000 00000000 00000000"  // node rc 0, 2 primary, 1 related
      "00000000 00000000 00000000 00000000 00000000";
  auto robot = Connect();
  Ask(*robot, gri::kTriggerJobSync, 1);
  EXPECT_EQ(last_bytes_, FromHex(v2() ? kV2 : kOfficial));
}

TEST_P(GriServerTest, DaoaiAndGriRobotsOnOneTaskShareItsQueue) {
  ScriptedPlanner::Script four;
  four.grasps = 4;
  scripted_->SetScript(0, four);
  DaoaiServerOptions daoai_options;
  daoai_options.port = 0;
  auto daoai = std::move(DaoaiServer::Start(*handler_, daoai_options).value());
  RobotClientOptions o;
  o.port = daoai->port();
  auto daoai_robot = std::move(RobotClient::Connect(o).value());
  auto gri_robot = Connect();

  std::vector<double> xs;
  gri::Response r = Ask(*gri_robot, gri::kTriggerJobSync, 0);
  ASSERT_EQ(r.error_code, 0);
  xs.push_back(r.pose[0] / 1000);
  Result<RobotReply> pick = daoai_robot->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(pick.ok());
  ASSERT_EQ(pick->status, daoai::kObjectsFound);
  xs.push_back(pick->X_BT->translation().x());
  r = Ask(*gri_robot, gri::kGetNextPose, 0);
  ASSERT_EQ(r.error_code, 0);
  EXPECT_EQ(Primary(r), 1);
  xs.push_back(r.pose[0] / 1000);
  pick = daoai_robot->Call(daoai::kPickPose, 0);
  ASSERT_TRUE(pick.ok());
  xs.push_back(pick->X_BT->translation().x());
  EXPECT_EQ(Ask(*gri_robot, gri::kGetNextPose, 0).error_code, Code(gri::Code::kNoPosesFound));

  for (size_t i = 0; i < xs.size(); ++i) EXPECT_NEAR(xs[i], 0.5 + 0.01 * i, 1e-6);
  EXPECT_TRUE(scripted_->WaitForHandedOut(4));
  std::set<int> instances;
  for (const auto& [task, instance] : scripted_->handed_out()) instances.insert(instance);
  EXPECT_EQ(instances, (std::set<int>{0, 1, 2, 3}));
  EXPECT_EQ(scripted_->handed_out().size(), 4u);
  daoai->Stop();
}

// Grasps 1 and 3 lie on parts touching part 0 (Grasp::stale_after): the
// first pose says 2 left (grasps 2 and 4), and the next poses are those.
TEST_P(GriServerTest, AfterAPickGraspsOnATouchingNeighbourAreWithdrawnAndTheRemainingCountSaysSo) {
  ScriptedPlanner::Script five;
  five.grasps = 5;
  five.stale_after = {{1, {0}}, {3, {0, 2}}};
  scripted_->SetScript(0, five);
  auto robot = Connect();
  std::vector<double> x_mm;
  std::vector<int32_t> left;
  gri::Response r = Ask(*robot, gri::kTriggerJobSync, 0);
  for (int i = 0; i < 3; ++i) {
    ASSERT_EQ(r.error_code, 0) << i;
    x_mm.push_back(std::round(r.pose[0]));
    left.push_back(Primary(r));
    if (i == 0) {
      // The related poses' answer reports the primary poses still queued too.
      const gri::Response related = Ask(*robot, gri::kGetRelatedPose, 0);
      EXPECT_EQ(Primary(related), 2);
    }
    if (i < 2) r = Ask(*robot, gri::kGetNextPose, 0);
  }
  EXPECT_EQ(x_mm, (std::vector<double>{500, 520, 540}));  // grasps 0, 2, 4
  EXPECT_EQ(left, (std::vector<int32_t>{2, 1, 0}));
  EXPECT_EQ(JobStatus(Ask(*robot, gri::kGetJobStatus, 0)), kInactive);
  EXPECT_EQ(Ask(*robot, gri::kGetNextPose, 0).error_code, Code(gri::Code::kNoPosesFound));
  EXPECT_EQ(scripted_->handed_out().size(), 3u);
}

// The pop rule (issue 39): an answer is encoded and range-checked before its
// grasp leaves the queue. Grasp 0 lies 2.5 m out, beyond the official
// format's +-2147 mm: an official robot gets grasps 1 and 2, then
// INTERNAL_ERROR while only grasp 0 is left, and grasp 0 stays queued (never
// taken and put back) for a v2 robot (float positions) on the same port.
TEST_P(GriServerTest, APoseThatDoesNotFitTheFormatStaysQueuedAndTheNextOneThatFitsIsSent) {
  if (v2()) GTEST_SKIP() << "v2 positions are float32: every finite pose fits";
  planner_->far = {0};
  auto robot = Connect();
  gri::Response r = Ask(*robot, gri::kTriggerJobSync, 0);
  ASSERT_EQ(r.error_code, 0);
  EXPECT_NEAR(r.pose[0], 510.0, 1e-3);  // grasp 1
  EXPECT_EQ(Primary(r), 2);  // grasps 0 and 2 still queued
  r = Ask(*robot, gri::kGetNextPose, 0);
  ASSERT_EQ(r.error_code, 0);
  EXPECT_NEAR(r.pose[0], 520.0, 1e-3);  // grasp 2
  r = Ask(*robot, gri::kGetNextPose, 0);
  EXPECT_EQ(r.error_code, Code(gri::Code::kInternalError));
  EXPECT_EQ(handler_->QueueSize(0), 1);
  EXPECT_EQ(handler_->stats().grasps_requeued, 0u);  // never taken, never put back

  gri::Request v2_next = Make(gri::kGetNextPose, 0);
  v2_next.format = Format::kV2;
  r = Ask(*robot, v2_next);
  ASSERT_EQ(r.error_code, 0);
  EXPECT_NEAR(r.pose[0], 2500.0, 1e-2);  // grasp 0 (pose format 2: millimetres)
  EXPECT_EQ(r.data[0], 0);            // v2 data_1: none left
  EXPECT_EQ(handler_->QueueSize(0), 0);
  ASSERT_TRUE(scripted_->WaitForHandedOut(3));
  std::multiset<int> instances;
  for (const auto& [task, instance] : scripted_->handed_out()) instances.insert(instance);
  EXPECT_EQ(instances, (std::multiset<int>{0, 1, 2}));  // each once
}

// Issue 39: an exception inside the GRI handler (HandleAsync) or while an
// answer is built and serialized, on the network thread, once reached Asio
// and ended the process. Now answered INTERNAL_ERROR, logged and counted;
// a pose whose serialization threw goes back to the front of its queue
// (the next GET_NEXT_POSE gets it), the connection stays open and in step,
// and another robot is served. Injected with core/fault_points.h.
TEST_P(GriServerTest, AnExceptionHandlingARequestOrSerializingItsAnswerIsAnsweredInternalErrorAndLosesNoPose) {
  auto robot = Connect();
  auto other = Connect();
  fault::Arm("gri.handle");
  EXPECT_EQ(Ask(*robot, gri::kTriggerJobSync, 0).error_code, Code(gri::Code::kInternalError));
  EXPECT_EQ(handler_->stats().answer_failures, 1u);
  EXPECT_EQ(Primary(Ask(*other, gri::kStatus, 0, 0)), 1);
  gri::Response r = Ask(*robot, gri::kTriggerJobSync, 0);
  ASSERT_EQ(r.error_code, 0);
  EXPECT_NEAR(r.pose[0], 500, 1e-3);
  fault::Arm("gri.serialize");
  r = Ask(*robot, gri::kGetNextPose, 0);
  EXPECT_EQ(r.error_code, Code(gri::Code::kInternalError));
  EXPECT_EQ(r.action, gri::kGetNextPose);
  EXPECT_EQ(handler_->stats().answer_failures, 2u);
  EXPECT_EQ(Primary(Ask(*other, gri::kStatus, 0, 0)), 1);
  r = Ask(*robot, gri::kGetNextPose, 0);
  ASSERT_EQ(r.error_code, 0);
  EXPECT_NEAR(r.pose[0], 510, 1e-3);  // the pose whose answer failed, again
  r = Ask(*robot, gri::kGetNextPose, 0);
  ASSERT_EQ(r.error_code, 0);
  EXPECT_NEAR(r.pose[0], 520, 1e-3);
  ASSERT_TRUE(scripted_->WaitForHandedOut(3));
  std::set<int> instances;
  for (const auto& [task, instance] : scripted_->handed_out()) instances.insert(instance);
  EXPECT_EQ(instances, (std::set<int>{0, 1, 2}));
  EXPECT_EQ(scripted_->handed_out().size(), 3u);
  EXPECT_EQ(handler_->stats().grasps_requeued, 1u);
}

INSTANTIATE_TEST_SUITE_P(Formats, GriServerTest, ::testing::Values(Format::kV2, Format::kOfficial),
                         [](const ::testing::TestParamInfo<Format>& info) {
                           return info.param == Format::kV2 ? "V2" : "Official";
                         });

}  // namespace
}  // namespace bp
