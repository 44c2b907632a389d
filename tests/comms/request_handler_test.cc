// RequestHandler without a transport (the path the Modbus transport takes),
// with the scripted test-double planner.
#include "comms/request_handler.h"

#include <sys/resource.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <condition_variable>
#include <functional>
#include <map>
#include <set>
#include <future>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <thread>
#include <utility>
#include <vector>

#include <gtest/gtest.h>

#include "core/conventions.h"
#include "core/fault_points.h"
#include "tests/testing/process_stats.h"
#include "tests/testing/scripted_planner.h"

namespace bp {
namespace {

using testing::MakeTestCell;
using testing::ScriptedPlanner;

daoai::Request Req(int32_t command, int32_t payload_1 = 0, int32_t meta_1 = 7) {
  daoai::Request r;
  r.position = {5000, -2500, 3000};
  r.orientation = {0, 0, 15708, 0};
  r.command = command;
  r.payload_1 = payload_1;
  r.meta_1 = meta_1;
  r.meta_2 = 2;
  return r;
}

TEST(RequestHandler, AnswersInTheConventionMeta1NamesWithTheCellsMeta1) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  // An ABB robot (meta_1 0, quaternion x y z w) talking to a UR cell.
  daoai::Request capture = Req(daoai::kCaptureAndProcess, 0, /*meta_1=*/0);
  capture.orientation = {0, 0, 7071, 7071};  // rotation pi/2 about z
  ASSERT_EQ(handler.Handle(capture, client)->status, daoai::kDetection);
  EXPECT_TRUE(client.warned_meta_1);
  ASSERT_TRUE(client.X_BF);
  EXPECT_NEAR(RotationAngle(client.X_BF->linear()), M_PI / 2, 1e-3);
  const auto pick = handler.Handle(Req(daoai::kPickPose, 0, /*meta_1=*/0), client);
  ASSERT_TRUE(pick);
  EXPECT_EQ(pick->status, daoai::kObjectsFound);
  EXPECT_EQ(pick->orientation, (std::array<int32_t, 4>{0, 0, 7071, 7071}));
  EXPECT_EQ(pick->meta_1, 7);  // the cell's robot: the ABB script will complain
}

TEST(RequestHandler, ScalesPositionsByTheCellsPositionUnit) {
  auto planner = std::make_shared<ScriptedPlanner>();
  Cell cell = MakeTestCell();
  cell.robot.position_scale = 0.001;  // the robot speaks millimetres
  RequestHandler handler(cell, planner, nullptr);
  ClientContext client;
  daoai::Request capture = Req(daoai::kCaptureAndProcess, 0);
  capture.position = {5000000, 0, 0};  // 500 mm
  ASSERT_EQ(handler.Handle(capture, client)->status, daoai::kDetection);
  EXPECT_NEAR(client.X_BF->translation().x(), 0.5, 1e-9);
  const auto pick = handler.Handle(Req(daoai::kPickPose, 0), client);
  EXPECT_EQ(pick->position, (std::array<int32_t, 3>{5000000, -1000000, 1000000}));
}

TEST(RequestHandler, GraspsOutsideTheWorkspaceNeverEnterTheQueue) {
  auto planner = std::make_shared<ScriptedPlanner>();
  Cell cell = MakeTestCell();
  // Scripted grasps stand at x = 0.50, 0.51, 0.52 m: the first inside.
  cell.robot.workspace = Eigen::AlignedBox3d(Vec3(-2, -2, -2), Vec3(0.505, 2, 2));
  ScriptedPlanner::Script script;
  script.grasps = 3;
  planner->SetScript(0, script);
  RequestHandler handler(cell, planner, nullptr);
  ClientContext client;
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
  const auto first = handler.Handle(Req(daoai::kPickPose, 0), client);
  ASSERT_TRUE(first);
  EXPECT_EQ(first->status, daoai::kObjectsFound);
  EXPECT_EQ(first->position[0], 5000);
  EXPECT_EQ(first->payload[0], 10000);  // the two outside are not counted: never queued
  const auto rest = handler.Handle(Req(daoai::kPickPose, 0), client);
  ASSERT_TRUE(rest);
  EXPECT_EQ(rest->status, daoai::kNoObjectFound);
  EXPECT_EQ(planner->handed_out().size(), 1u);
}

TEST(RequestHandler, APlanWithEveryGraspOutsideTheWorkspaceIsNoSafePoseWithTheRobotsOwnPose) {
  auto planner = std::make_shared<ScriptedPlanner>();
  Cell cell = MakeTestCell();
  cell.robot.workspace = Eigen::AlignedBox3d(Vec3(-2, -2, -2), Vec3(0.45, 2, 2));
  ScriptedPlanner::Script script;
  script.grasps = 3;
  planner->SetScript(0, script);
  RequestHandler handler(cell, planner, nullptr);
  ClientContext client;
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
  const auto answer = handler.Handle(Req(daoai::kPickPose, 0), client);
  ASSERT_TRUE(answer);
  EXPECT_EQ(answer->status, daoai::kNoCollisionFreePose);
  EXPECT_EQ(answer->position, (std::array<int32_t, 3>{5000, -2500, 3000}));  // where it is
  EXPECT_TRUE(planner->handed_out().empty());
}

// Proposes a next auto-calibration pose 1 m below the robot.
class SinkingCalibrationService final : public CalibrationService {
 public:
  Status Start(CalibrationKind, const Pose&) override { return Status::Ok(); }
  Result<CalibrationStep> Accumulate(CalibrationKind, const Pose& X_BF) override {
    CalibrationStep step;
    step.next_X_BF = MakePose(Mat3::Identity(), Vec3(0, 0, -1)) * X_BF;
    return step;
  }
  Status Finish(CalibrationKind) override { return Status::Ok(); }
};

TEST(RequestHandler, AnAutoCalibrationPoseOutsideTheWorkspaceIsNotSent) {
  Cell cell = MakeTestCell();
  cell.robot.workspace = Eigen::AlignedBox3d(Vec3(-2, -2, -0.2), Vec3(2, 2, 2));
  RequestHandler handler(cell, std::make_shared<ScriptedPlanner>(), std::make_unique<SinkingCalibrationService>());
  ClientContext client;
  ASSERT_EQ(handler.Handle(Req(daoai::kStartAutoCalibration), client)->status, daoai::kModeAutoCalibration);
  // The robot at z = 0.3 m; the proposed z = -0.7 m breaks z >= -0.2: not
  // sent; the calibration ends with DONE (the seed's loop leaves on it), the
  // robot's own pose in the answer.
  const auto next = handler.Handle(Req(daoai::kAutoAccumulatePose), client);
  ASSERT_TRUE(next);
  EXPECT_EQ(next->status, daoai::kDoneCalibration);
  EXPECT_EQ(next->position, (std::array<int32_t, 3>{5000, -2500, 3000}));
  // The calibration ended: a further accumulate is outside it.
  EXPECT_EQ(handler.Handle(Req(daoai::kAutoAccumulatePose), client)->status, daoai::kUnknownCommand);
}

TEST(RequestHandler, EmptyBoxRuleNeedsFewPointsAndNoDetections) {
  auto planner = std::make_shared<ScriptedPlanner>();
  Cell cell = MakeTestCell();
  cell.tasks[3].empty_box.threshold_points = 2000;
  cell.tasks[3].empty_box.mode = EmptyBoxRule::Mode::kLargestRegion;
  cell.tasks[1].empty_box.threshold_points = 2000;
  cell.tasks[1].empty_box.mode = EmptyBoxRule::Mode::kTotal;
  RequestHandler handler(cell, planner, nullptr);
  ClientContext client;
  auto check = [&](int task, int64_t roi, int64_t largest, int detections) {
    ScriptedPlanner::Script s;
    s.grasps = 0;
    s.detections = detections;
    s.roi_points = roi;
    s.largest_region_points = largest;
    planner->SetScript(task, s);
    return handler.Handle(Req(daoai::kCheckEmptyBox, task), client)->status;
  };
  // Largest region: scattered noise (many points, small regions) is empty.
  EXPECT_EQ(check(3, 5000, 1999, 0), daoai::kBoxEmpty);
  EXPECT_EQ(check(3, 5000, 2000, 0), daoai::kBoxNotEmpty);
  EXPECT_EQ(check(3, 5000, 2001, 0), daoai::kBoxNotEmpty);
  EXPECT_EQ(check(3, 10, 10, 1), daoai::kBoxNotEmpty);  // a detection is never empty
  EXPECT_EQ(check(3, 1999, 1999, 1), daoai::kBoxNotEmpty);
  // Total: every ROI point counts.
  EXPECT_EQ(check(1, 5000, 1999, 0), daoai::kBoxNotEmpty);
  EXPECT_EQ(check(1, 1999, 1999, 0), daoai::kBoxEmpty);
  EXPECT_EQ(check(1, 2000, 10, 0), daoai::kBoxNotEmpty);
  EXPECT_EQ(check(1, 2001, 10, 0), daoai::kBoxNotEmpty);
  // No image: not empty.
  ScriptedPlanner::Script broken;
  broken.capture_fails = true;
  planner->SetScript(1, broken);
  EXPECT_EQ(handler.Handle(Req(daoai::kCheckEmptyBox, 1), client)->status, daoai::kBoxNotEmpty);
}

TEST(RequestHandler, TheEmptyBoxAnswerCarriesTheFillLevelInPayload4To6) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  ScriptedPlanner::Script s;
  s.grasps = 0;
  s.detections = 2;
  FillLevel fill;
  fill.mean_height = 0.0312;
  fill.max_height = 0.0941;
  fill.occupied_fraction = 0.62;
  s.fill = fill;
  planner->SetScript(0, s);
  const std::optional<daoai::Response> r = handler.Handle(Req(daoai::kCheckEmptyBox, 0), client);
  ASSERT_TRUE(r.has_value());
  EXPECT_EQ(r->status, daoai::kBoxNotEmpty);
  // x MULT (10000); payload_1..3 stay 0 as before.
  EXPECT_EQ(r->payload, (std::array<int32_t, 6>{0, 0, 0, 312, 941, 6200}));
  // Without a measured fill level the answer is what it always was.
  s.fill.reset();
  planner->SetScript(0, s);
  EXPECT_EQ(handler.Handle(Req(daoai::kCheckEmptyBox, 0), client)->payload, (std::array<int32_t, 6>{}));
}

TEST(RequestHandler, CapturesWithTheSelectedCameraConfig) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
  EXPECT_EQ(planner->last_config(), 1);
  ASSERT_EQ(handler.Handle(Req(daoai::kSwitchConfig, 2), client)->status,
            daoai::kSwitchConfigSuccess);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
  EXPECT_EQ(planner->last_config(), 2);
}

TEST(RequestHandler, PoseUpdateRecordsThePoseWithoutAnswering) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  EXPECT_FALSE(handler.Handle(Req(daoai::kNoCommand), client).has_value());
  ASSERT_TRUE(client.X_BF);
  EXPECT_NEAR(client.X_BF->translation().y(), -0.25, 1e-9);
  EXPECT_EQ(client.requests, 1u);
  EXPECT_EQ(planner->captures(), 0);
}

TEST(RequestHandler, PickPoseWaitingForDetectionIsAnsweredWhenItFinishes) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  planner->HoldPlans(true);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), client)->status,
            daoai::kDetection);
  std::atomic<bool> answered{false};
  RequestHandler::Reply reply;
  handler.HandleAsync(Req(daoai::kPickPose, 0), client, [&](RequestHandler::Reply r) {
    reply = std::move(r);
    answered = true;
  });
  std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_FALSE(answered.load());
  planner->HoldPlans(false);
  for (int i = 0; i < 200 && !answered; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  ASSERT_TRUE(answered.load());
  EXPECT_EQ(handler.QueueSize(0), 3);  // nothing popped until the Reply runs
  EXPECT_EQ(reply()->status, daoai::kObjectsFound);
  EXPECT_EQ(handler.QueueSize(0), 2);
}

TEST(RequestHandler, AnUndecodablePoseIsNeverUsedNorReplacedByAStaleOne) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  EXPECT_FALSE(handler.Handle(Req(daoai::kNoCommand), client).has_value());  // a good pose
  // An ABB robot (quaternion fields) sending an all-zero quaternion.
  daoai::Request bad = Req(daoai::kSendPose, 0, /*meta_1=*/0);
  bad.orientation = {0, 0, 0, 0};
  EXPECT_FALSE(handler.Handle(bad, client).has_value());
  bad.command = daoai::kStartAutoCalibration;
  EXPECT_EQ(handler.Handle(bad, client)->status, daoai::kUnknownCommand);
  handler.Shutdown();
  EXPECT_TRUE(planner->taught().empty());
}

}  // namespace
}  // namespace bp

namespace bp {
namespace {

// Collects what the handler tells its observers.
class CollectingObserver final : public ServerObserver {
 public:
  void OnDetection(const DetectionEvent& e) override {
    std::lock_guard lock(mutex_);
    detections.push_back(e);
  }
  void OnAnswer(const AnswerEvent& e) override {
    std::lock_guard lock(mutex_);
    answers.push_back(e);
  }
  std::mutex mutex_;
  std::vector<DetectionEvent> detections;
  std::vector<AnswerEvent> answers;
};

TEST(RequestHandlerObserver, SeesEveryDetectionAndEveryResponseButNoSilentCommand) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  auto observer = std::make_shared<CollectingObserver>();
  handler.AddObserver(observer);
  ClientContext client;
  client.id = 7;
  client.peer = "10.0.0.2:5000";
  ScriptedPlanner::Script s;
  s.grasps = 2;
  planner->SetScript(0, s);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
  const auto pick = handler.Handle(Req(daoai::kPickPose, 0), client);
  ASSERT_TRUE(pick);
  EXPECT_FALSE(handler.Handle(Req(daoai::kNoCommand, 0), client));  // pose update: silent
  ScriptedPlanner::Script fail;
  fail.capture_fails = true;
  planner->SetScript(0, fail);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kCaptureFail);
  handler.Shutdown();

  std::lock_guard lock(observer->mutex_);
  ASSERT_EQ(observer->detections.size(), 2u);
  const DetectionEvent& ok = observer->detections[0];
  EXPECT_EQ(ok.task_id, 0);
  EXPECT_TRUE(ok.scene);
  ASSERT_TRUE(ok.plan);
  EXPECT_EQ(ok.plan->grasps.size(), 2u);
  EXPECT_TRUE(ok.plan_status.ok());
  const DetectionEvent& failed = observer->detections[1];
  EXPECT_FALSE(failed.scene);
  EXPECT_FALSE(failed.capture_status.ok());
  EXPECT_FALSE(failed.plan);

  ASSERT_EQ(observer->answers.size(), 3u);  // 20, 21, 20: not the pose update
  EXPECT_EQ(observer->answers[0].response.status, daoai::kDetection);
  EXPECT_EQ(observer->answers[1].request.command, daoai::kPickPose);
  EXPECT_EQ(observer->answers[1].response.position, pick->position);
  EXPECT_EQ(observer->answers[1].client_id, 7u);
  EXPECT_EQ(observer->answers[1].peer, "10.0.0.2:5000");
  ASSERT_TRUE(observer->answers[1].X_BF);
  EXPECT_NEAR(observer->answers[1].X_BF->translation().x(), 0.5, 1e-9);
  EXPECT_EQ(observer->answers[2].response.status, daoai::kCaptureFail);
}

}  // namespace
}  // namespace bp

namespace bp {
namespace {

using namespace std::chrono_literals;

// A completion that keeps the Reply for the test to run (as a transport does
// right before writing).
struct Pending {
  std::mutex mutex;
  std::optional<RequestHandler::Reply> reply;
  RequestHandler::Completion Completion() {
    return [this](RequestHandler::Reply r) {
      std::lock_guard lock(mutex);
      reply = std::move(r);
    };
  }
  bool answered() {
    std::lock_guard lock(mutex);
    return reply.has_value();
  }
  std::optional<daoai::Response> Run() {
    std::lock_guard lock(mutex);
    return (*reply)();
  }
};

bool Eventually(const std::function<bool()>& done, std::chrono::milliseconds timeout = 5000ms) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (!done()) {
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(1ms);
  }
  return true;
}

daoai::Request At(int32_t command, int32_t task, int32_t x) {
  daoai::Request r = Req(command, task);
  r.position[0] = x;
  return r;
}

// Issue 39: 50 captures on one task while its detection runs cost one more
// detection, not 50; that one uses the pose of the last request.
TEST(RequestHandlerCoalescing, ACaptureFloodRunsOneDetectionAtATimeAndTheLatestPoseWins) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  auto observer = std::make_shared<CollectingObserver>();
  handler.AddObserver(observer);
  ClientContext client;
  planner->HoldPlans(true);
  for (int i = 0; i < 50; ++i) {
    ASSERT_EQ(handler.Handle(At(daoai::kCaptureAndProcessAsync, 0, 1000 * i), client)->status,
              daoai::kDetection);
  }
  EXPECT_EQ(handler.Snapshot(0)->in_flight, 2);  // one running, one pending
  planner->HoldPlans(false);
  ASSERT_TRUE(Eventually([&] { return handler.Snapshot(0)->in_flight == 0; }));
  EXPECT_EQ(planner->captures(), 2);
  EXPECT_EQ(planner->plans(), 2);
  EXPECT_EQ(handler.stats().captures_coalesced, 48u);
  handler.Shutdown();
  std::lock_guard lock(observer->mutex_);
  ASSERT_EQ(observer->detections.size(), 2u);
  EXPECT_NEAR(observer->detections[0].request.X_BF->translation().x(), 0.0, 1e-9);
  EXPECT_NEAR(observer->detections[1].request.X_BF->translation().x(), 4.9, 1e-9);  // 49000 / MULT
}

// Every RC 20 that joined a pending detection is answered when that
// detection's capture is done, not before, and with its result.
TEST(RequestHandlerCoalescing, SyncCapturesThatJoinAPendingDetectionAreAnsweredByItsCapture) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  planner->HoldPlans(true);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
  std::vector<std::unique_ptr<Pending>> waiting;
  for (int i = 0; i < 3; ++i) {
    waiting.push_back(std::make_unique<Pending>());
    handler.HandleAsync(Req(daoai::kCaptureAndProcess, 0), client, waiting.back()->Completion());
  }
  std::this_thread::sleep_for(50ms);
  for (auto& w : waiting) EXPECT_FALSE(w->answered());
  EXPECT_EQ(planner->captures(), 1);
  ScriptedPlanner::Script broken;
  broken.capture_fails = true;
  planner->SetScript(0, broken);  // the shared capture fails: all three hear it
  planner->HoldPlans(false);
  for (auto& w : waiting) {
    ASSERT_TRUE(Eventually([&] { return w->answered(); }));
    EXPECT_EQ(w->Run()->status, daoai::kCaptureFail);
  }
  EXPECT_EQ(planner->captures(), 2);
}

// A pick waits for the newest detection requested before it (here the
// pending one), and a pick that arrived before that request is answered as
// soon as the detection it waits for is done.
TEST(RequestHandlerCoalescing, APickWaitsForTheNewestDetectionRequestedBeforeItAndNoLater) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  planner->HoldPlans(true);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), client)->status, daoai::kDetection);
  ASSERT_TRUE(Eventually([&] { return planner->captures() == 1; }));
  Pending first, second;
  handler.HandleAsync(Req(daoai::kPickPose, 0), client, first.Completion());
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), client)->status, daoai::kDetection);
  handler.HandleAsync(Req(daoai::kPickPose, 0), client, second.Completion());
  planner->ReleasePlans(1);  // the first detection ends; the pending one starts and is held
  ASSERT_TRUE(Eventually([&] { return first.answered(); }));
  ASSERT_TRUE(Eventually([&] { return planner->captures() == 2; }));
  EXPECT_FALSE(second.answered());
  EXPECT_EQ(planner->plans(), 1);
  const auto a = first.Run();
  EXPECT_EQ(a->status, daoai::kObjectsFound);
  EXPECT_EQ(a->payload[0], 30000);  // 3 grasps left, this one included
  planner->HoldPlans(false);
  ASSERT_TRUE(Eventually([&] { return second.answered(); }));
  const auto b = second.Run();
  EXPECT_EQ(b->status, daoai::kObjectsFound);
  EXPECT_EQ(b->payload[0], 30000);  // from the new detection's queue
}

// Issue 39 (re-capture race): a pick released by its detection is answered
// from it even when a new capture starts before the pick's reply is built.
TEST(RequestHandlerCoalescing, ARecaptureBeforeAReleasedPickIsAnsweredDoesNotEmptyItsQueue) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  planner->HoldPlans(true);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), client)->status, daoai::kDetection);
  Pending pick;
  handler.HandleAsync(Req(daoai::kPickPose, 0), client, pick.Completion());
  planner->ReleasePlans(1);
  ASSERT_TRUE(Eventually([&] { return pick.answered(); }));
  // Another robot re-captures before the transport builds the pick's answer.
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), client)->status, daoai::kDetection);
  ASSERT_TRUE(Eventually([&] { return planner->captures() == 2; }));
  const auto r = pick.Run();
  EXPECT_EQ(r->status, daoai::kObjectsFound);
  EXPECT_EQ(r->payload[0], 30000);
  planner->HoldPlans(false);
}

// The scripted planner, recording for each plan the nice value of the
// thread it ran on, with a gate per task: plans of a held task block until
// released (in arrival order).
class PriorityPlanner final : public GraspPlanner {
 public:
  struct PlanRun {
    int task = 0;
    int nice = 0;
  };
  Result<CaptureHandle> Capture(const PlanRequest& request) override { return scripted.Capture(request); }
  Result<PlanResult> Plan(const PlanRequest& request, const CapturedScene& scene) override {
    {
      std::unique_lock lock(mutex_);
      runs_.push_back({request.task.id, getpriority(PRIO_PROCESS, static_cast<id_t>(gettid()))});
      cv_.notify_all();
      const int nice = runs_.back().nice;
      cv_.wait(lock, [&] {
        return (held_.count(request.task.id) == 0 || permits_[request.task.id] > 0) &&
               !(hold_above_nice_ && nice > *hold_above_nice_);
      });
      if (held_.count(request.task.id)) --permits_[request.task.id];
    }
    return scripted.Plan(request, scene);
  }
  void Hold(int task) {
    std::lock_guard lock(mutex_);
    held_.insert(task);
  }
  void Release(int task, int plans) {
    std::lock_guard lock(mutex_);
    permits_[task] += plans;
    cv_.notify_all();
  }
  void Open(int task) {
    std::lock_guard lock(mutex_);
    held_.erase(task);
    cv_.notify_all();
  }
  // Holds every plan that runs at a nice above `nice` (the background
  // lane's), whatever its task, until OpenAboveNice().
  void HoldAboveNice(int nice) {
    std::lock_guard lock(mutex_);
    hold_above_nice_ = nice;
  }
  void OpenAboveNice() {
    std::lock_guard lock(mutex_);
    hold_above_nice_.reset();
    cv_.notify_all();
  }
  // Waits until `n` plans have started (5 s); a copy of them.
  std::vector<PlanRun> WaitForRuns(size_t n) {
    std::unique_lock lock(mutex_);
    cv_.wait_for(lock, 5s, [&] { return runs_.size() >= n; });
    return runs_;
  }
  ScriptedPlanner scripted;

 private:
  std::mutex mutex_;
  std::condition_variable cv_;
  std::vector<PlanRun> runs_;     // GUARDED_BY(mutex_)
  std::set<int> held_;            // GUARDED_BY(mutex_)
  std::map<int, int> permits_;    // GUARDED_BY(mutex_)
  std::optional<int> hold_above_nice_;  // GUARDED_BY(mutex_)
};

int OwnNice() { return getpriority(PRIO_PROCESS, static_cast<id_t>(gettid())); }

// Opens the gates of tasks 0-3 when a test ends (declared after the
// handler: a failed assertion must not leave its Shutdown waiting for a
// held plan).
struct OpenAtExit {
  PriorityPlanner& planner;
  ~OpenAtExit() {
    for (int task = 0; task < 4; ++task) planner.Open(task);
    planner.OpenAboveNice();
  }
};

// Issue 39 (capture flood): the re-detection a flood of 19s leaves pending
// is planned at a lower CPU priority, so it takes what another robot's
// detection leaves of the cores instead of half of them; a pending
// detection a robot waits for (a pick that arrived while the one before it
// ran) keeps the process's priority.
TEST(RequestHandlerBackground, ARedetectionNobodyWaitsForIsPlannedAtALowerPriority) {
  const int base = OwnNice();
  if (base >= 19) GTEST_SKIP() << "the test runs at nice 19 already";
  auto planner = std::make_shared<PriorityPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  const OpenAtExit open_at_exit{*planner};
  ClientContext flooder, robot;
  planner->Hold(0);
  for (int i = 0; i < 20; ++i) {
    ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), flooder)->status, daoai::kDetection);
  }
  planner->Open(0);
  ASSERT_TRUE(Eventually([&] { return handler.Snapshot(0)->in_flight == 0; }));
  std::vector<PriorityPlanner::PlanRun> runs = planner->WaitForRuns(2);
  ASSERT_EQ(runs.size(), 2u);
  EXPECT_EQ(runs[0].nice, base);                     // the first 19 found the task idle
  EXPECT_EQ(runs[1].nice, std::min(19, base + 10));  // the flood's re-detection
  EXPECT_EQ(handler.stats().background_detections, 1u);
  // A pick waits for the pending detection before it starts: it keeps the
  // process's priority, and the pick is answered from it.
  planner->Hold(0);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), robot)->status, daoai::kDetection);
  ASSERT_EQ(planner->WaitForRuns(3).size(), 3u);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), robot)->status, daoai::kDetection);
  Pending pick;
  handler.HandleAsync(Req(daoai::kPickPose, 0), robot, pick.Completion());
  planner->Open(0);
  ASSERT_TRUE(Eventually([&] { return pick.answered(); }));
  EXPECT_EQ(pick.Run()->status, daoai::kObjectsFound);
  runs = planner->WaitForRuns(4);
  ASSERT_EQ(runs.size(), 4u);
  EXPECT_EQ(runs[3].nice, base);
  EXPECT_EQ(handler.stats().background_detections, 1u);
  handler.Shutdown();
}

// While a flooded task's background plan runs (held here), another robot's
// capture and pick on its own task are served; and a background plan
// queued behind it (a second flooded task) that a pick starts waiting for
// runs on the arena at once instead of waiting for the lane.
TEST(RequestHandlerBackground, ABackgroundPlanHoldsUpNeitherAnotherRobotNorAPickThatWaitsForAQueuedOne) {
  auto planner = std::make_shared<PriorityPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  const OpenAtExit open_at_exit{*planner};
  ClientContext flooder, robot;
  // Task 0: a detection, a flood's re-detection behind it, held in its plan
  // on the background lane.
  planner->Hold(0);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), flooder)->status, daoai::kDetection);
  ASSERT_EQ(planner->WaitForRuns(1).size(), 1u);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), flooder)->status, daoai::kDetection);
  planner->Release(0, 1);
  ASSERT_EQ(planner->WaitForRuns(2).size(), 2u);
  ASSERT_EQ(handler.stats().background_detections, 1u);
  // Another robot on task 1: served meanwhile.
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 1), robot)->status, daoai::kDetection);
  const std::optional<daoai::Response> pick = handler.Handle(Req(daoai::kPickPose, 1), robot);
  ASSERT_TRUE(pick);
  EXPECT_EQ(pick->status, daoai::kObjectsFound);
  // Task 3 flooded too: its re-detection queues on the lane behind task 0's.
  planner->Hold(3);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 3), flooder)->status, daoai::kDetection);
  ASSERT_EQ(planner->WaitForRuns(4).size(), 4u);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 3), flooder)->status, daoai::kDetection);
  planner->Open(3);
  ASSERT_TRUE(Eventually([&] { return handler.stats().background_detections == 2; }));
  // A pick on task 3 takes its queued plan to the arena: answered while
  // task 0's background plan is still held.
  Pending pick3;
  handler.HandleAsync(Req(daoai::kPickPose, 3), robot, pick3.Completion());
  ASSERT_TRUE(Eventually([&] { return pick3.answered(); }));
  EXPECT_EQ(pick3.Run()->status, daoai::kObjectsFound);
  const std::vector<PriorityPlanner::PlanRun> runs = planner->WaitForRuns(5);
  ASSERT_EQ(runs.size(), 5u);
  EXPECT_EQ(runs[4].task, 3);
  EXPECT_EQ(runs[4].nice, OwnNice());
  EXPECT_EQ(handler.Snapshot(0)->in_flight, 1);  // still held
  planner->Open(0);
  ASSERT_TRUE(Eventually([&] { return handler.Snapshot(0)->in_flight == 0; }));
  handler.Shutdown();
}

// Issue 39 item 4: a pick on the flooded task that arrives while the task's
// re-detection is planned on the background lane (nice +10), with the
// flood's next detection pending after it, waited for that plan at nice +10
// and then for its own detection. Now the pending detection it waits for
// starts at once at the process's priority and the lane's plan is
// abandoned: the pick is answered while the lane's plan is still held, and
// that plan's result, when it comes, does not refill the queue.
TEST(RequestHandlerBackground, APickWaitingBehindABackgroundPlanStartsItsDetectionAtOnce) {
  const int base = OwnNice();
  if (base >= 19) GTEST_SKIP() << "the test runs at nice 19 already";
  auto planner = std::make_shared<PriorityPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  const OpenAtExit open_at_exit{*planner};
  ClientContext flooder, robot;
  planner->Hold(0);
  planner->HoldAboveNice(base);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), flooder)->status, daoai::kDetection);
  ASSERT_EQ(planner->WaitForRuns(1).size(), 1u);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), flooder)->status, daoai::kDetection);
  planner->Open(0);  // the first plan ends; the flood's re-detection goes to the lane, held there
  std::vector<PriorityPlanner::PlanRun> runs = planner->WaitForRuns(2);
  ASSERT_EQ(runs.size(), 2u);
  EXPECT_EQ(runs[1].nice, std::min(19, base + 10));
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), flooder)->status, daoai::kDetection);
  EXPECT_EQ(handler.Snapshot(0)->in_flight, 2);  // the lane's plan and the flood's next one
  Pending pick;
  handler.HandleAsync(Req(daoai::kPickPose, 0), robot, pick.Completion());
  ASSERT_TRUE(Eventually([&] { return pick.answered(); }));
  EXPECT_EQ(pick.Run()->status, daoai::kObjectsFound);
  runs = planner->WaitForRuns(3);
  ASSERT_EQ(runs.size(), 3u);
  EXPECT_EQ(runs[2].nice, base);
  EXPECT_EQ(handler.Snapshot(0)->in_flight, 0);  // the abandoned plan no longer counts
  const int left = handler.QueueSize(0);
  planner->OpenAboveNice();
  EXPECT_TRUE(Eventually([&] { return handler.Snapshot(0)->finished == 2; }));  // the first and the pick's
  std::this_thread::sleep_for(50ms);  // the abandoned plan's result, had it been kept, would be in by now
  EXPECT_EQ(handler.QueueSize(0), left);
  EXPECT_EQ(handler.Snapshot(0)->finished, 2u);
  // The task serves on: a capture and a pick.
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), robot)->status, daoai::kDetection);
  const std::optional<daoai::Response> next = handler.Handle(Req(daoai::kPickPose, 0), robot);
  ASSERT_TRUE(next);
  EXPECT_EQ(next->status, daoai::kObjectsFound);
  handler.Shutdown();
}

// Shutdown with a background plan queued on the lane drops it and returns.
TEST(RequestHandlerBackground, ShutdownWithABackgroundPlanQueuedReturns) {
  auto planner = std::make_shared<PriorityPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  const OpenAtExit open_at_exit{*planner};
  ClientContext flooder;
  // Task 0's re-detection held on the lane, task 3's queued behind it.
  size_t runs = 0;
  for (int task : {0, 3}) {
    planner->Hold(task);
    ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, task), flooder)->status, daoai::kDetection);
    ASSERT_EQ(planner->WaitForRuns(++runs).size(), runs);
    ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, task), flooder)->status, daoai::kDetection);
    planner->Release(task, 1);
    ASSERT_TRUE(Eventually([&] { return handler.stats().background_detections == (task == 0 ? 1u : 2u); }));
    if (task == 0) {
      ASSERT_EQ(planner->WaitForRuns(++runs).size(), runs);
    }
  }
  std::thread open([&] {
    std::this_thread::sleep_for(100ms);
    planner->Open(0);
    planner->Open(3);
  });
  handler.Shutdown();
  open.join();
  EXPECT_EQ(planner->WaitForRuns(0).size(), 3u);  // task 3's queued plan never ran
}

// Issue 39 item 3, fault injection (core/fault_points.h) into what was
// checked by reading only. The queue's refill throws (no memory): the
// detection fails as a whole, the pick waiting for it is answered -1 with
// payload_1 0 (not NO_OBJECT_FOUND), the task is not left in flight, and the
// next detection serves. When the failed plan cannot be queued either, the
// queue keeps the previous detection's grasps: the waiting pick is answered
// from them (it does not wait forever).
TEST(RequestHandlerFaults, AQueueRefillThatThrowsFailsItsDetectionAndTheNextOneServes) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  fault::Arm("grasp_queue.replace");
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
  std::optional<daoai::Response> pick = handler.Handle(Req(daoai::kPickPose, 0), client);
  ASSERT_TRUE(pick);
  EXPECT_EQ(pick->status, daoai::kUnknownCommand);
  EXPECT_EQ(pick->payload[0], 0);
  EXPECT_EQ(handler.stats().planner_failures, 1u);
  EXPECT_EQ(handler.Snapshot(0)->in_flight, 0);
  EXPECT_EQ(fault::Armed("grasp_queue.replace"), 0);

  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
  pick = handler.Handle(Req(daoai::kPickPose, 0), client);
  ASSERT_TRUE(pick);
  EXPECT_EQ(pick->status, daoai::kObjectsFound);  // 3 grasps, one taken: 2 left

  fault::Arm("grasp_queue.replace", 2);  // the plan's refill, then the failed plan's
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
  pick = handler.Handle(Req(daoai::kPickPose, 0), client);
  ASSERT_TRUE(pick);
  EXPECT_EQ(pick->status, daoai::kObjectsFound);  // the previous detection's second grasp
  EXPECT_EQ(handler.stats().planner_failures, 2u);
  EXPECT_EQ(handler.Snapshot(0)->in_flight, 0);
  fault::DisarmAll();
  handler.Shutdown();
}

// The background lane cannot take a flood's re-detection (no thread, no
// memory): it is planned at once, at the process's priority, and not
// counted as a background detection; the task serves on.
TEST(RequestHandlerFaults, ARedetectionTheBackgroundLaneCannotTakeIsPlannedAtOnce) {
  const int base = OwnNice();
  auto planner = std::make_shared<PriorityPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  const OpenAtExit open_at_exit{*planner};
  ClientContext flooder, robot;
  planner->Hold(0);
  for (int i = 0; i < 5; ++i) {
    ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), flooder)->status, daoai::kDetection);
  }
  fault::Arm("background_lane.post");
  planner->Open(0);
  ASSERT_TRUE(Eventually([&] { return handler.Snapshot(0)->in_flight == 0; }));
  const std::vector<PriorityPlanner::PlanRun> runs = planner->WaitForRuns(2);
  ASSERT_EQ(runs.size(), 2u);
  EXPECT_EQ(runs[1].nice, base);  // planned at once, not on the lane
  EXPECT_EQ(handler.stats().background_detections, 0u);
  EXPECT_EQ(fault::Armed("background_lane.post"), 0);
  const std::optional<daoai::Response> pick = handler.Handle(Req(daoai::kPickPose, 0), robot);
  ASSERT_TRUE(pick);
  EXPECT_EQ(pick->status, daoai::kObjectsFound);
  handler.Shutdown();
}

// The background lane's job throws before its plan: was (read, not tested)
// the lane's last-resort catch, which left the detection unfinished: the
// task in flight forever (every pick on it waiting) and Shutdown waiting
// for the job. Now the detection fails as a whole: a pick gets -1, the
// next detection serves, Shutdown returns.
TEST(RequestHandlerFaults, ABackgroundPlanThatThrowsFailsItsDetectionAndTheTaskServesAgain) {
  auto planner = std::make_shared<PriorityPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  const OpenAtExit open_at_exit{*planner};
  ClientContext flooder, robot;
  planner->Hold(0);
  for (int i = 0; i < 5; ++i) {
    ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), flooder)->status, daoai::kDetection);
  }
  fault::Arm("background_lane.plan");
  planner->Open(0);
  ASSERT_TRUE(Eventually([&] { return handler.Snapshot(0)->in_flight == 0; }));
  EXPECT_EQ(handler.stats().background_detections, 1u);
  EXPECT_EQ(handler.stats().planner_failures, 1u);
  EXPECT_EQ(planner->WaitForRuns(1).size(), 1u);  // the re-detection was never planned
  std::optional<daoai::Response> pick = handler.Handle(Req(daoai::kPickPose, 0), robot);
  ASSERT_TRUE(pick);
  EXPECT_EQ(pick->status, daoai::kUnknownCommand);  // its last detection failed
  EXPECT_EQ(pick->payload[0], 0);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), robot)->status, daoai::kDetection);
  pick = handler.Handle(Req(daoai::kPickPose, 0), robot);
  ASSERT_TRUE(pick);
  EXPECT_EQ(pick->status, daoai::kObjectsFound);
  handler.Shutdown();
}

// Empty-box checks of one task share one capture while one runs.
TEST(RequestHandlerCoalescing, EmptyBoxChecksThatArriveWhileOneRunsShareTheNextCapture) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  planner->HoldPlans(true);
  std::vector<std::unique_ptr<Pending>> checks;
  for (int i = 0; i < 10; ++i) {
    checks.push_back(std::make_unique<Pending>());
    handler.HandleAsync(Req(daoai::kCheckEmptyBox, 3), client, checks.back()->Completion());
  }
  planner->HoldPlans(false);
  for (auto& c : checks) {
    ASSERT_TRUE(Eventually([&] { return c->answered(); }));
    EXPECT_EQ(c->Run()->status, daoai::kBoxNotEmpty);
  }
  EXPECT_EQ(planner->captures(), 2);
}

// Issue 39: an observer that throws neither leaves the task in flight nor
// keeps the robot from its answer; it is counted.
class ThrowingObserver final : public ServerObserver {
 public:
  void OnDetection(const DetectionEvent&) override { throw std::runtime_error("observer bug"); }
  void OnAnswer(const AnswerEvent&) override { throw 42; }
};

TEST(RequestHandler, AnObserverThatThrowsIsContainedAndCounted) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  handler.AddObserver(std::make_shared<ThrowingObserver>());
  auto collecting = std::make_shared<CollectingObserver>();
  handler.AddObserver(collecting);
  ClientContext client;
  for (int round = 0; round < 2; ++round) {
    ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
    const auto pick = handler.Handle(Req(daoai::kPickPose, 0), client);
    ASSERT_TRUE(pick);
    EXPECT_EQ(pick->status, daoai::kObjectsFound);
  }
  EXPECT_EQ(handler.Snapshot(0)->in_flight, 0);
  EXPECT_EQ(handler.stats().observer_failures, 6u);  // 2 detections, 4 answers
  handler.Shutdown();
  std::lock_guard lock(collecting->mutex_);
  EXPECT_EQ(collecting->detections.size(), 2u);  // the next observer still hears everything
  EXPECT_EQ(collecting->answers.size(), 4u);
}

// Issue 39: a planner error is an error to the robot, not "no objects"
// (which a seed program takes as a reason to check for an empty bin), and
// the capture goes to the observers (the recorder keeps it for replay).
TEST(RequestHandler, APlannerErrorIsAnsweredAsAnErrorAndTheCaptureIsObserved) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  auto observer = std::make_shared<CollectingObserver>();
  handler.AddObserver(observer);
  ClientContext client;
  ScriptedPlanner::Script throws;
  throws.plan_throws = true;
  planner->SetScript(0, throws);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
  const auto pick = handler.Handle(Req(daoai::kPickPose, 0), client);
  EXPECT_EQ(pick->status, daoai::kUnknownCommand);
  EXPECT_EQ(pick->payload[0], 0);
  EXPECT_EQ(handler.stats().planner_failures, 1u);
  EXPECT_EQ(handler.Snapshot(0)->outcome, PlanResult::Outcome::kPlannerFailed);
  planner->SetScript(0, ScriptedPlanner::Script{});
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
  EXPECT_EQ(handler.Handle(Req(daoai::kPickPose, 0), client)->status, daoai::kObjectsFound);
  handler.Shutdown();
  std::lock_guard lock(observer->mutex_);
  ASSERT_FALSE(observer->detections.empty());
  const DetectionEvent& failed = observer->detections[0];
  EXPECT_TRUE(failed.scene);  // the frame, for the recorder
  EXPECT_FALSE(failed.plan);
  EXPECT_NE(failed.plan_status.message().find("scripted detection exception"), std::string::npos)
      << failed.plan_status.ToString();
}

// Issue 39: the robots waiting for a detection are answered however the
// others' answers fail: a waiter that throws (a transport's completion out
// of memory) neither leaves the ones after it waiting nor the task in flight.
TEST(RequestHandler, RobotsWaitingForADetectionAreAnsweredWhenAnotherWaiterThrows) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  planner->HoldPlans(true);
  ASSERT_TRUE(handler.StartDetection(0, std::nullopt).ok());
  std::atomic<int> answered{0};
  ASSERT_TRUE(handler.WhenDetected(0, [] { throw std::bad_alloc(); }).ok());
  ASSERT_TRUE(handler.WhenDetected(0, [&] { ++answered; }).ok());
  planner->HoldPlans(false);
  EXPECT_TRUE(testing::WaitUntil([&] { return answered == 1; }));
  EXPECT_TRUE(testing::WaitUntil([&] { return handler.Snapshot(0)->in_flight == 0; }));
  // The task detects and answers again.
  ASSERT_TRUE(handler.StartDetection(0, std::nullopt).ok());
  ASSERT_TRUE(handler.WhenDetected(0, [&] { ++answered; }).ok());
  EXPECT_TRUE(testing::WaitUntil([&] { return answered == 2; }));
  EXPECT_EQ(handler.QueueSize(0), 3);
}

// Issue 39: an answer whose encoding or range check throws is an error to
// the robot, and its grasp stays queued (nothing popped, nothing lost); the
// next answer that can be built is served.
TEST(RequestHandler, AnAnswerWhoseRangeCheckThrowsIsAnErrorAndItsGraspStaysQueued) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  bool throws = false;
  client.wire_range = [&throws](const daoai::Response& r) -> Result<daoai::Response> {
    if (throws) throw std::runtime_error("injected range check exception");
    return r;
  };
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
  throws = true;
  const auto refused = handler.Handle(Req(daoai::kPickPose, 0), client);
  ASSERT_TRUE(refused);
  EXPECT_EQ(refused->status, daoai::kUnknownCommand);
  EXPECT_EQ(handler.QueueSize(0), 3);
  EXPECT_TRUE(planner->handed_out().empty());
  throws = false;
  const auto pick = handler.Handle(Req(daoai::kPickPose, 0), client);
  ASSERT_TRUE(pick);
  EXPECT_EQ(pick->status, daoai::kObjectsFound);
  EXPECT_EQ(handler.QueueSize(0), 2);
  EXPECT_EQ(planner->handed_out(), (std::vector<std::pair<int, int>>{{0, 0}}));
}

// Issue 39: Handle() always returns: when its caller gives up (the Modbus
// master stopping) and when the handler drops the request (shutdown). A
// given-up pick pops nothing.
TEST(RequestHandler, HandleReturnsWhenAbandonedOrDroppedAndPopsNothing) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  planner->HoldPlans(true);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), client)->status, daoai::kDetection);
  const auto t0 = std::chrono::steady_clock::now();
  std::atomic<bool> stop{false};
  std::thread stopper([&] {
    std::this_thread::sleep_for(100ms);
    stop = true;
  });
  EXPECT_FALSE(handler.Handle(Req(daoai::kPickPose, 0), client, [&] { return stop.load(); }));
  stopper.join();
  EXPECT_LT(std::chrono::steady_clock::now() - t0, 3s);
  planner->ReleasePlans(1);
  ASSERT_TRUE(Eventually([&] { return handler.Snapshot(0)->in_flight == 0; }));
  EXPECT_EQ(handler.QueueSize(0), 3);  // the abandoned pick took nothing
  EXPECT_TRUE(planner->handed_out().empty());

  // A pick waiting for a detection that never starts (pending at shutdown).
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), client)->status, daoai::kDetection);
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcessAsync, 0), client)->status, daoai::kDetection);
  std::optional<daoai::Response> dropped = daoai::Response{};
  std::thread picker([&] { dropped = handler.Handle(Req(daoai::kPickPose, 0), client); });
  std::this_thread::sleep_for(50ms);
  std::thread shutdown([&] { handler.Shutdown(); });
  std::this_thread::sleep_for(50ms);
  planner->HoldPlans(false);  // the running detection ends; the pending one is dropped
  shutdown.join();
  picker.join();
  EXPECT_FALSE(dropped.has_value());
  EXPECT_EQ(planner->captures(), 2);
}

// Issue 39, the pop rule completed: with settle_after_write (every socket
// and Modbus transport) a popped grasp is handed out when its answer is
// written; an answer that was not written puts it back at the front, with
// its remaining count, unless a later detection replaced the queue.
TEST(RequestHandler, AReservedGraspGoesBackToTheFrontWhenItsAnswerIsNotWritten) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  client.settle_after_write = true;
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
  const auto first = handler.Handle(Req(daoai::kPickPose, 0), client);
  ASSERT_EQ(first->status, daoai::kObjectsFound);
  ASSERT_TRUE(client.settle);
  EXPECT_TRUE(planner->handed_out().empty());  // reserved, not handed out yet
  std::exchange(client.settle, nullptr)(false);  // the write failed
  EXPECT_EQ(handler.QueueSize(0), 3);
  const auto again = handler.Handle(Req(daoai::kPickPose, 0), client);
  EXPECT_EQ(again->position, first->position);
  EXPECT_EQ(again->payload[0], 30000);
  std::exchange(client.settle, nullptr)(true);  // written
  EXPECT_EQ(planner->handed_out(), (std::vector<std::pair<int, int>>{{0, 0}}));
  // Not written, and a new detection replaced the queue meanwhile: dropped.
  ASSERT_TRUE(handler.Handle(Req(daoai::kPickPose, 0), client).has_value());
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
  EXPECT_FALSE(client.settle) << "a new request settles a leftover as written";
  EXPECT_EQ(planner->handed_out().size(), 2u);
  ASSERT_TRUE(handler.Handle(Req(daoai::kPickPose, 0), client).has_value());
  ASSERT_TRUE(Eventually([&] { return handler.Snapshot(0)->in_flight == 0; }));
  ClientContext other;
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), other)->status, daoai::kDetection);
  ASSERT_TRUE(Eventually([&] { return handler.Snapshot(0)->in_flight == 0; }));
  std::exchange(client.settle, nullptr)(false);
  EXPECT_EQ(handler.QueueSize(0), 3);  // the new plan, untouched
  const RequestHandlerStats stats = handler.stats();
  EXPECT_EQ(stats.grasps_requeued, 1u);
  EXPECT_EQ(stats.grasps_superseded, 1u);
}

// The one pop rule (issues 38 and 39): a grasp whose answer does not fit the
// link is never taken; the one handed to the robot instead is reserved until
// its answer is written, and when it is not it goes back where it was, behind
// the grasp that did not fit, so every robot still sees the queue's order and
// no grasp is handed out twice.
TEST(RequestHandler, AnUnwrittenGraspGoesBackBehindTheGraspsThatDoNotFitTheLink) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext narrow;  // a link that cannot carry grasp 0 (x = 0.5 m: 5000)
  narrow.settle_after_write = true;
  narrow.wire_range = [](const daoai::Response& r) -> Result<daoai::Response> {
    if (r.status == daoai::kObjectsFound && r.position[0] == 5000) {
      return Status::OutOfRange("position x 5000");
    }
    return r;
  };
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), narrow)->status, daoai::kDetection);
  const auto pick = handler.Handle(Req(daoai::kPickPose, 0), narrow);
  ASSERT_EQ(pick->status, daoai::kObjectsFound);
  EXPECT_EQ(pick->position[0], 5100);  // grasp 1; grasp 0 stays queued
  EXPECT_EQ(pick->payload[0], 30000);
  EXPECT_EQ(handler.QueueSize(0), 2);
  ASSERT_TRUE(narrow.settle);
  std::exchange(narrow.settle, nullptr)(false);  // not written
  EXPECT_EQ(handler.QueueSize(0), 3);
  EXPECT_TRUE(planner->handed_out().empty());
  ClientContext wide;  // int32 fields: every grasp fits, handed out at once
  for (const int32_t x : {5000, 5100, 5200}) {
    const auto r = handler.Handle(Req(daoai::kPickPose, 0), wide);
    ASSERT_EQ(r->status, daoai::kObjectsFound);
    EXPECT_EQ(r->position[0], x);
  }
  EXPECT_EQ(planner->handed_out(), (std::vector<std::pair<int, int>>{{0, 0}, {0, 1}, {0, 2}}));
  EXPECT_EQ(handler.stats().grasps_requeued, 1u);
}

// Issue 39: a calibration session keeps at most kMaxCalibrationPoses views;
// a robot looping MANUAL_ACCUMULATE_POSE gets -1 (the seed's "restart the
// handshake") beyond them instead of growing the server.
TEST(RequestHandler, ACalibrationKeepsAtMostItsCapOfPoses) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  ASSERT_EQ(handler.Handle(Req(daoai::kStartManualCalibration), client)->status,
            daoai::kModeCalibration);
  for (size_t i = 0; i < kMaxCalibrationPoses; ++i) {
    ASSERT_EQ(handler.Handle(Req(daoai::kManualAccumulatePose), client)->status,
              daoai::kModeCalibration) << i;
  }
  EXPECT_EQ(handler.Handle(Req(daoai::kManualAccumulatePose), client)->status,
            daoai::kUnknownCommand);
  // A new session starts from zero.
  ASSERT_EQ(handler.Handle(Req(daoai::kStartManualCalibration), client)->status,
            daoai::kModeCalibration);
  EXPECT_EQ(handler.Handle(Req(daoai::kManualAccumulatePose), client)->status,
            daoai::kModeCalibration);
}

// Issue 39: calibration steps and teach poses wait in one bounded queue; a
// flood beyond it is refused, logged and counted, and answered.
TEST(RequestHandler, CalibrationAndTeachJobsBeyondTheQueueBoundAreRefusedAndCounted) {
  auto planner = std::make_shared<ScriptedPlanner>();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  std::promise<void> release;
  std::shared_future<void> gate = release.get_future().share();
  std::atomic<bool> blocking{false};
  ASSERT_TRUE(handler.RunCalibration([&](CalibrationService&) {
    blocking = true;
    gate.wait();
  }));
  ASSERT_TRUE(Eventually([&] { return blocking.load(); }));
  int posted = 0;
  while (handler.RunCalibration([](CalibrationService&) {})) ++posted;
  EXPECT_EQ(posted, 64);
  EXPECT_EQ(handler.stats().jobs_refused, 1u);
  EXPECT_FALSE(handler.Handle(Req(daoai::kSendPose, 0), client).has_value());  // teach: refused
  EXPECT_EQ(handler.Handle(Req(daoai::kStartManualCalibration, 0), client)->status,
            daoai::kUnknownCommand);
  EXPECT_EQ(handler.stats().jobs_refused, 3u);
  release.set_value();
  handler.Shutdown();
  EXPECT_TRUE(planner->taught().empty());
}

// ---- the first pose early (docs/protocols.md "The first pose early") -------

// Plans `n` grasps (ScriptedPlanner's poses; parts 1 and 3 touch part 0)
// and publishes grasp 0 as its head with the bound n + 2, each step behind
// a gate the test opens: the head, then the rest of the plan.
class HeadFirstPlanner final : public GraspPlanner {
 public:
  explicit HeadFirstPlanner(int n) : n_(n) {}
  Result<CaptureHandle> Capture(const PlanRequest& request) override { return scripted_.Capture(request); }
  Result<PlanResult> Plan(const PlanRequest& request, const CapturedScene& scene) override {
    return PlanWithHead(request, scene, {});
  }
  Result<PlanResult> PlanWithHead(const PlanRequest& request, const CapturedScene&, const HeadReady& on_head) override {
    PlanResult r;
    r.outcome = PlanResult::Outcome::kGrasps;
    for (int i = 0; i < n_; ++i) {
      Grasp g;
      g.X_BT = g.X_BT_pre = ScriptedPlanner::GraspPose(request.task.id, i);
      g.X_BO = g.X_BT;
      g.instance_id = i;
      g.class_id = i % 3;
      r.grasps.push_back(g);
    }
    if (n_ > 1) r.grasps[1].stale_after = {0};
    if (n_ > 3) r.grasps[3].stale_after = {0, 2};
    r.detections = n_;
    Wait(head_open_);
    if (on_head) on_head(PlanHead{r.grasps[0], n_ + 2, r.grasps[2]});
    Wait(rest_open_);
    return r;
  }
  void OpenHead() { Open(head_open_); }
  void OpenRest() { Open(rest_open_); }

 private:
  void Wait(const bool& gate) {
    std::unique_lock lock(mutex_);
    cv_.wait(lock, [&] { return gate; });
  }
  void Open(bool& gate) {
    std::lock_guard lock(mutex_);
    gate = true;
    cv_.notify_all();
  }
  const int n_;
  ScriptedPlanner scripted_;
  std::mutex mutex_;
  std::condition_variable cv_;
  bool head_open_ = false;  // GUARDED_BY(mutex_)
  bool rest_open_ = false;  // GUARDED_BY(mutex_)
};

// The scripted grasp a pick pose answer carries (x = 0.5 + 0.01 i m).
int InstanceOf(const daoai::Response& r) { return static_cast<int>(std::lround((r.position[0] - 5000) / 100.0)); }

// Answers the pick poses of task 0 until NO_OBJECT_FOUND: (instance, remaining).
std::vector<std::pair<int, int>> PickAll(RequestHandler& handler, ClientContext& client) {
  std::vector<std::pair<int, int>> out;
  for (int k = 0; k < 20; ++k) {
    const auto r = handler.Handle(Req(daoai::kPickPose, 0), client);
    if (!r || r->status != daoai::kObjectsFound) break;
    out.emplace_back(InstanceOf(*r), static_cast<int>(std::lround(FromFixed(r->payload[0]))));
  }
  return out;
}

// A pick that waits for the detection is answered from the head the moment
// the planner publishes it, while the rest is still planned; the full
// queue then serves the others, without the head's part and the parts it
// made stale, with remaining counts that never rise.
TEST(RequestHandlerFirstPose, APickWaitingForTheDetectionGetsTheHeadBeforeThePlanIsComplete) {
  auto planner = std::make_shared<HeadFirstPlanner>(5);
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext client;
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), client)->status, daoai::kDetection);
  std::promise<RequestHandler::Reply> answered;
  handler.HandleAsync(Req(daoai::kPickPose, 0), client,
                      [&answered](RequestHandler::Reply reply) { answered.set_value(std::move(reply)); });
  auto future = answered.get_future();
  EXPECT_EQ(future.wait_for(std::chrono::milliseconds(50)), std::future_status::timeout);
  planner->OpenHead();
  ASSERT_EQ(future.wait_for(std::chrono::seconds(10)), std::future_status::ready);
  const std::optional<daoai::Response> head = future.get()();
  ASSERT_TRUE(head);
  EXPECT_EQ(head->status, daoai::kObjectsFound);
  EXPECT_EQ(InstanceOf(*head), 0);
  EXPECT_EQ(head->payload[0], *ToFixed(7));  // the plan's bound: an upper bound while it fills
  EXPECT_EQ(handler.Snapshot(0)->in_flight, 1);  // the rest is still being planned
  planner->OpenRest();
  const auto rest = PickAll(handler, client);
  EXPECT_EQ(rest, (std::vector<std::pair<int, int>>{{2, 2}, {4, 1}}));
  EXPECT_EQ(handler.stats().first_poses_early, 1u);
  EXPECT_EQ(handler.QueueContents(0)->withdrawn, (std::vector<int>{1, 3}));
}

// A pick that arrives after the head was published takes it at once; a
// second pick waiting meanwhile gets the full plan's next grasp, never the
// head again; a GRI-style wait (WhenDetected) waits for the whole plan.
TEST(RequestHandlerFirstPose, APickArrivingWhileTheQueueFillsTakesTheHeadAndTheNextWaitsForTheRest) {
  auto planner = std::make_shared<HeadFirstPlanner>(5);
  planner->OpenHead();
  RequestHandler handler(MakeTestCell(), planner, nullptr);
  ClientContext a, b;
  ASSERT_EQ(handler.Handle(Req(daoai::kCaptureAndProcess, 0), a)->status, daoai::kDetection);
  for (int k = 0; k < 1000 && handler.QueueSize(0) != 1; ++k) std::this_thread::sleep_for(std::chrono::milliseconds(5));
  ASSERT_EQ(handler.QueueSize(0), 1);  // the head, published
  std::atomic<bool> detected{false};
  ASSERT_TRUE(handler.WhenDetected(0, [&detected] { detected = true; }).ok());
  const auto head = handler.Handle(Req(daoai::kPickPose, 0), a);
  ASSERT_TRUE(head);
  EXPECT_EQ(head->status, daoai::kObjectsFound);
  EXPECT_EQ(InstanceOf(*head), 0);
  std::promise<RequestHandler::Reply> second;
  handler.HandleAsync(Req(daoai::kPickPose, 0), b,
                      [&second](RequestHandler::Reply reply) { second.set_value(std::move(reply)); });
  auto future = second.get_future();
  EXPECT_EQ(future.wait_for(std::chrono::milliseconds(50)), std::future_status::timeout);
  EXPECT_FALSE(detected);
  planner->OpenRest();
  ASSERT_EQ(future.wait_for(std::chrono::seconds(10)), std::future_status::ready);
  const std::optional<daoai::Response> next = future.get()();
  ASSERT_TRUE(next);
  EXPECT_EQ(InstanceOf(*next), 2);
  EXPECT_EQ(next->payload[0], *ToFixed(2));
  EXPECT_TRUE(detected);
  EXPECT_EQ(PickAll(handler, a), (std::vector<std::pair<int, int>>{{4, 1}}));
}

}  // namespace
}  // namespace bp
