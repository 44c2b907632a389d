// RequestHandler without a transport (the path the Modbus transport takes),
// with the scripted test-double planner.
#include "comms/request_handler.h"

#include <mutex>
#include <vector>

#include <gtest/gtest.h>

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
