// TEST DOUBLE. A deterministic GraspPlanner for server and protocol tests:
// no camera, no perception. Each task follows a script (how many grasps, which
// outcome, delays, failures); grasp i of task t is at
//   X_BT = (0.5 + 0.01 i, -0.1 + 0.02 t, 0.1) m, rotated pi/2 about z,
// class i % 3, instance i. Never shipped: binpickd uses grasp/planner_factory.h.
#pragma once

#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <stdexcept>
#include <thread>
#include <utility>
#include <vector>

#include "grasp/planner.h"

namespace bp::testing {

class ScriptedPlanner final : public GraspPlanner {
 public:
  struct Script {
    int grasps = 3;
    std::optional<PlanResult::Outcome> outcome;  // default: kGrasps if grasps > 0 else kNoObjects
    int detections = -1;                         // default: grasps
    int64_t roi_points = 50000;
    int64_t largest_region_points = 40000;
    bool capture_fails = false;
    bool capture_throws = false;  // Capture() throws std::runtime_error
    bool plan_throws = false;     // Plan() throws std::runtime_error
    std::chrono::milliseconds capture_delay{0};
    std::chrono::milliseconds plan_delay{0};
    std::optional<double> precision_error_mm = 0.42;  // nullopt: target not found
    // Parts in the bin, or -1 for a bottomless bin. When set, each handed-out
    // grasp removes a part; a plan offers min(grasps, parts left), and an
    // empty bin reports no objects, no detections and no ROI points.
    int pile = -1;
    // Grasp i -> the instance ids whose hand-out makes it stale
    // (Grasp::stale_after: parts touching it); GraspQueue withdraws it then.
    std::map<int, std::vector<int>> stale_after;
    std::optional<FillLevel> fill;  // PlanResult::fill
    // Called inside Capture() (before it returns a scene), Plan() (before it
    // builds the result) and NotifyHandedOut() (after the hand-out is
    // recorded): a test makes them throw whatever it wants to inject.
    std::function<void()> in_capture, in_plan, in_handed_out;
  };

  void SetScript(int task_id, Script script) {
    std::lock_guard lock(mutex_);
    scripts_[task_id] = script;
  }
  // While held, Plan() blocks (after the capture was answered).
  void HoldPlans(bool hold) {
    {
      std::lock_guard lock(mutex_);
      hold_ = hold;
    }
    cv_.notify_all();
  }
  // While held, lets `n` more plans through (in the order they arrive).
  void ReleasePlans(int n) {
    {
      std::lock_guard lock(mutex_);
      permits_ += n;
    }
    cv_.notify_all();
  }

  static Pose GraspPose(int task_id, int i) {
    return MakePose(Mat3(Eigen::AngleAxisd(M_PI / 2, Vec3::UnitZ())),
                    Vec3(0.5 + 0.01 * i, -0.1 + 0.02 * task_id, 0.1));
  }

  Result<CaptureHandle> Capture(const PlanRequest& request) override {
    const Script s = ScriptFor(request.task.id);
    std::this_thread::sleep_for(s.capture_delay);
    {
      std::lock_guard lock(mutex_);
      ++captures_;
      last_config_ = request.camera_config_id;
      last_X_BF_ = request.X_BF;
    }
    if (s.capture_throws) throw std::runtime_error("scripted capture exception");
    if (s.in_capture) s.in_capture();
    if (s.capture_fails) return Status::Unavailable("scripted capture failure");
    return CaptureHandle(std::make_shared<Scene>());
  }

  Result<PlanResult> Plan(const PlanRequest& request, const CapturedScene&) override {
    const Script s = ScriptFor(request.task.id);
    {
      std::unique_lock lock(mutex_);
      cv_.wait(lock, [this] { return !hold_ || permits_ > 0; });
      if (hold_) --permits_;
    }
    std::this_thread::sleep_for(s.plan_delay);
    if (s.plan_throws) throw std::runtime_error("scripted detection exception");
    if (s.in_plan) s.in_plan();
    int grasps = s.grasps;
    int64_t roi_points = s.roi_points, largest = s.largest_region_points;
    if (s.pile >= 0) {
      const int left = s.pile - HandedOutFor(request.task.id);
      grasps = std::min(grasps, std::max(0, left));
      if (left <= 0) roi_points = largest = 0;
    }
    PlanResult r;
    r.outcome = s.outcome.value_or(grasps > 0 ? PlanResult::Outcome::kGrasps
                                              : PlanResult::Outcome::kNoObjects);
    r.detections = s.detections >= 0 ? s.detections : grasps;
    r.roi_points = roi_points;
    r.largest_region_points = largest;
    r.fill = s.fill;
    if (r.outcome == PlanResult::Outcome::kGrasps) {
      for (int i = 0; i < grasps; ++i) {
        Grasp g;
        g.X_BT = GraspPose(request.task.id, i);
        g.X_BT_pre = g.X_BT * MakePose(Mat3::Identity(), Vec3(0, 0, -0.08));
        g.X_BO = g.X_BT;
        g.instance_id = i;
        g.class_id = i % 3;
        g.score = 1.0 - 0.01 * i;
        if (auto it = s.stale_after.find(i); it != s.stale_after.end()) g.stale_after = it->second;
        r.grasps.push_back(g);
      }
    }
    std::lock_guard lock(mutex_);
    ++plans_;
    return r;
  }

  void NotifyHandedOut(const TaskSpec& task, const Grasp& grasp) override {
    {
      std::lock_guard lock(mutex_);
      handed_out_.emplace_back(task.id, grasp.instance_id);
    }
    cv_.notify_all();
    if (const Script s = ScriptFor(task.id); s.in_handed_out) s.in_handed_out();
  }
  // A grasp counts as handed out once its answer is written, which a
  // transport learns a moment after the robot may have read it (the pop
  // rule, docs/protocols.md): tests wait for the count before comparing.
  // @returns whether at least `n` were handed out within `timeout`.
  bool WaitForHandedOut(size_t n, std::chrono::milliseconds timeout = std::chrono::seconds(5)) const {
    std::unique_lock lock(mutex_);
    return cv_.wait_for(lock, timeout, [&] { return handed_out_.size() >= n; });
  }

  Status Teach(const TeachRequest& request) override {
    std::lock_guard lock(mutex_);
    taught_.push_back(request);
    return Status::Ok();
  }

  Result<double> CheckPrecision(const PlanRequest& request) override {
    const Script s = ScriptFor(request.task.id);
    if (!s.precision_error_mm) return Status::NotFound("scripted: precision target not found");
    return *s.precision_error_mm;
  }

  int captures() const { std::lock_guard lock(mutex_); return captures_; }
  int plans() const { std::lock_guard lock(mutex_); return plans_; }
  int last_config() const { std::lock_guard lock(mutex_); return last_config_; }
  // The robot pose of the last capture (nullopt: none, or it did not decode).
  std::optional<Pose> last_X_BF() const { std::lock_guard lock(mutex_); return last_X_BF_; }
  std::vector<std::pair<int, int>> handed_out() const { std::lock_guard lock(mutex_); return handed_out_; }
  std::vector<TeachRequest> taught() const { std::lock_guard lock(mutex_); return taught_; }

 private:
  struct Scene final : CapturedScene {
    std::string Describe() const override { return "scripted scene"; }
  };
  int HandedOutFor(int task_id) const {
    std::lock_guard lock(mutex_);
    int n = 0;
    for (const auto& [task, instance] : handed_out_) n += task == task_id;
    return n;
  }
  Script ScriptFor(int task_id) const {
    std::lock_guard lock(mutex_);
    auto it = scripts_.find(task_id);
    return it == scripts_.end() ? Script{} : it->second;
  }

  mutable std::mutex mutex_;
  mutable std::condition_variable cv_;
  std::map<int, Script> scripts_;
  bool hold_ = false;
  int permits_ = 0;  // plans let through while held
  int captures_ = 0, plans_ = 0, last_config_ = 0;
  std::optional<Pose> last_X_BF_;
  std::vector<std::pair<int, int>> handed_out_;
  std::vector<TeachRequest> taught_;
};

// A cell for protocol tests, built in code: UR robot, DaoAI `dialect`,
// camera configs 1 and 2, tasks 0 and 1 (pick), 2 (place), 3 (pick, empty-box
// threshold 2000 points by largest region), 5 (precision).
inline Cell MakeTestCell(DaoaiDialect dialect = DaoaiDialect::kVisionPilot) {
  Cell cell;
  cell.name = "test";
  cell.path = "<test>";
  CameraConfig c1, c2;
  c1.id = 1;
  c1.name = "vga";
  c2.id = 2;
  c2.name = "wuxga";
  cell.camera.configs = {c1, c2};
  cell.camera.default_config = 1;
  auto task = [](int id, TaskSpec::Kind kind) {
    TaskSpec t;
    t.id = id;
    t.kind = kind;
    t.name = "task" + std::to_string(id);
    return t;
  };
  cell.tasks = {task(0, TaskSpec::Kind::kPick), task(1, TaskSpec::Kind::kPick),
                task(2, TaskSpec::Kind::kPlace), task(3, TaskSpec::Kind::kPick),
                task(5, TaskSpec::Kind::kPrecision)};
  cell.robot.model = *FindRobotModel("ur");
  cell.robot.dialect = dialect;
  return cell;
}

}  // namespace bp::testing
