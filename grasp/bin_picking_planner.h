// The product GraspPlanner: capture from the cell's CaptureSource, perception,
// grasp candidates (cell + taught), FCL collision filtering and ranking
// (grasp/grasp_planning.h), per task kind:
//   pick (and pick_2d, precision): the queue of grasps, one per part;
//   in_hand: one "grasp" whose X_BT is the part in the FLANGE frame,
//            X_FO = X_BF^-1 * X_BO, from the robot pose sent with the request
//            (InvalidArgument without it);
//   place:   one "grasp" whose X_BT is the place area's offset from its taught
//            reference, X_off = X_BP * place_reference^-1 (so X_BP = X_off *
//            place_reference), with X_BP (the detected place part) as related_X_B[0].
//
// State it owns: the capture source (guarded: the server never runs two
// captures at once, but NotifyHandedOut may come from another thread), the
// taught grasps (TeachStore, persisted), and per task the last plan's
// detections and their ground-truth instance ids (for simulated picks and
// teaching). Thread-safety: every member may be called concurrently.
#pragma once

#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "core/cell.h"
#include "grasp/grasp_planning.h"
#include "grasp/planner.h"
#include "grasp/teach_store.h"
#include "pipeline/capture_source.h"
#include "pipeline/frame.h"
#include "pipeline/perception.h"

namespace bp {

// What BinPickingPlanner::Capture returns: the frame itself.
class CapturedFrame final : public CapturedScene {
 public:
  explicit CapturedFrame(Frame frame) : frame_(std::move(frame)) {}
  std::string Describe() const override { return frame_.source; }
  const Frame& frame() const { return frame_; }

 private:
  Frame frame_;
};

struct BinPickingPlannerOptions {
  GraspPlanningOptions planning;
  // Taught grasps file. Empty: "<cell file without extension>.taught.yaml"
  // next to the cell file, or in memory only for the embedded default cell.
  // "-": in memory only.
  std::string teach_file;
  // Pick tasks: when a normal perception run leaves nothing to pick (no
  // detection, or none with a collision-free grasp) and the ROI holds a
  // connected region, run perception again on the same frame with
  // PerceptionEffort::kThorough and plan from that if it gives grasps. Costs
  // time only on the answers that would otherwise stop the robot.
  bool thorough_retry = true;
};

// Everything one Plan produced, for tools (`binpick clear`) and tests.
struct PlanDetail {
  PlanResult result;
  GraspPlan plan;
  PerceptionResult perception;
  bool thorough_retry = false;  // the plan comes from a thorough perception retry
};

class BinPickingPlanner final : public GraspPlanner {
 public:
  // Loads the taught grasps. @returns the model's or the teach file's error.
  static Result<std::unique_ptr<BinPickingPlanner>> Create(const Cell& cell,
                                                           std::shared_ptr<const Perception> perception,
                                                           std::unique_ptr<CaptureSource> source,
                                                           BinPickingPlannerOptions options = {});
  ~BinPickingPlanner() override;

  Result<CaptureHandle> Capture(const PlanRequest& request) override;
  Result<PlanResult> Plan(const PlanRequest& request, const CapturedScene& scene) override;
  // With a ground-truth frame: tells the source which true instance the
  // grasp's part is (the instance most of its support points show in the
  // label image, else the nearest true part of its class within 3 cm), so a
  // simulating source removes it. Remembers the part for teaching.
  void NotifyHandedOut(const TaskSpec& task, const Grasp& grasp) override;
  // Stores X_OG = X_BO^-1 * X_BT for the part last handed out for the task
  // (else the first part of the task's last plan). NotFound when the task has
  // no detected part yet; the persistence error if the file cannot be written.
  Status Teach(const TeachRequest& request) override;

  // Plan with everything it produced. `scene` must come from Capture.
  Result<PlanDetail> PlanDetailed(const PlanRequest& request, const CapturedScene& scene);

  const GraspPlanningModel& model() const { return *model_; }
  const TeachStore& teach_store() const { return *teach_; }
  // The ground-truth instance matched to `detection` of the task's last plan; -1 if none.
  int TruthInstanceOf(int task_id, int detection) const;

 private:
  struct TaskState {
    std::vector<Detection> detections;   // last plan's (support dropped)
    std::vector<int> truth_instance;     // per detection, -1 if none
    std::optional<Pose> held_X_BO;       // part last handed out
    int held_class = -1;
  };
  BinPickingPlanner() = default;
  Cell cell_;
  BinPickingPlannerOptions options_;
  std::shared_ptr<const Perception> perception_;
  std::shared_ptr<const GraspPlanningModel> model_;
  std::unique_ptr<TeachStore> teach_;
  std::mutex source_mutex_;
  std::unique_ptr<CaptureSource> source_;  // GUARDED_BY(source_mutex_)
  mutable std::mutex state_mutex_;
  std::map<int, TaskState> tasks_;         // GUARDED_BY(state_mutex_)
};

// The teach file BinPickingPlanner uses for `cell` with an empty option.
std::string DefaultTeachFile(const Cell& cell);

}  // namespace bp
