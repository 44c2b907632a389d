// The product GraspPlanner: capture from the cell's CaptureSource, perception,
// grasp candidates (cell + taught), FCL collision filtering and ranking
// (grasp/grasp_planning.h), per task kind:
//   pick (and pick_2d, precision): the queue of grasps, one per part;
//   in_hand:    the part in the gripper, looked for in the task's roi in the
//               tool frame at the robot's pose (X_BT, sent with the capture;
//               InvalidArgument without it): one "grasp" whose X_BT is the
//               part in the tool frame, X_TO = X_BT^-1 * X_BO; none (no
//               objects) when it stands more than 30 mm / 45 deg from the
//               part held (below): a pose estimate turned over, not a slip;
//   place_area: the task's fixture, looked for in its roi in the fixture's
//               taught frame: one "grasp" whose X_BT is its offset from the
//               taught pose, X_off = X_BP * X_BP_taught^-1 (so X_BP = X_off *
//               X_BP_taught), X_BP as related_X_B[0], and as implied_X_BT the
//               tool pose seed 003's program computes from it,
//               X_off * (X_BP_taught * X_PO) * X_TO^-1, with the part held;
//   place:      the same fixture; one grasp whose X_BT is the drop-off,
//               X_BP * X_PO * X_TO^-1 (seed 000's DROP_OFF_POSE), its
//               pre-pose backed off by the gripper's approach distance;
//               no objects when no part is held.
// The part held (X_TO) is what the last in_hand answer measured since the
// last pick, else the pick's own: the grasp against its detected part,
// X_BT^-1 * X_BO. A place or place_area answer releases it.
//
// State it owns: the capture source (guarded: the server never runs two
// captures at once, but NotifyHandedOut may come from another thread), the
// taught grasps (TeachStore, persisted), and per task the last plan's
// detections and their ground-truth instance ids (for simulated picks and
// teaching). Thread-safety: every member may be called concurrently.
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "core/cell.h"
#include "core/mesh.h"
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
  // Budget of a thorough retry in work units: the first
  // thorough_retry_estimates (view, class) pose estimates in start order,
  // the views most likely to hold a part going first
  // (Perception::RunThorough, PerceptionBudget::max_estimates), the same
  // ones on any machine at any load. 0: no count (the time cap alone).
  // docs/tuning.md, thorough_retry_estimates.
  int thorough_retry_estimates = 6;
  // Time cap of a thorough retry, ms > 0, a safety on top of the count, the
  // retry's grasp stage included for picks (that stage is assumed to take
  // what the normal plan's took): estimates it would not cover are not
  // started either. A plan whose retry left estimates out says so
  // (PlanDetail::retry_estimates_skipped, the message). docs/tuning.md,
  // thorough_retry_ms.
  double thorough_retry_ms = 1000.0;
  // The clock the retry's budget is read on, ms; empty: the steady clock.
  // Tests inject a deterministic one.
  std::function<double()> retry_clock_ms;
};

// Everything one Plan produced, for tools (`binpick clear`) and tests.
struct PlanDetail {
  PlanResult result;
  GraspPlan plan;
  PerceptionResult perception;
  bool thorough_retry = false;  // the plan comes from a thorough perception retry
  // A thorough retry's estimates its budget did not cover (retry used or
  // not); > 0: it ran out, and the plan's message says so.
  int retry_estimates_skipped = 0;
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
  // Pick tasks publish their head (PlanGrasps's on_head) once perception and
  // the obstacles are done; not from a thorough retry, nor for other kinds.
  Result<PlanResult> PlanWithHead(const PlanRequest& request, const CapturedScene& scene,
                                  const HeadReady& on_head) override;
  // Captures for in_hand and fixture tasks ask the source for that view
  // (CaptureRequest::View).
  // With a ground-truth frame: tells the source which true instance the
  // grasp's part is (the instance most of its support points show in the
  // label image, else the nearest true part of its class within 3 cm), so a
  // simulating source removes it. Remembers the part for teaching, and the
  // part held (see above).
  void NotifyHandedOut(const TaskSpec& task, const Grasp& grasp) override;
  // Stores X_OG = X_BO^-1 * X_BT for the part last handed out for the task
  // (else the first part of the task's last plan). NotFound when the task has
  // no detected part yet; the persistence error if the file cannot be written.
  Status Teach(const TeachRequest& request) override;

  // Plan with everything it produced. `scene` must come from Capture.
  Result<PlanDetail> PlanDetailed(const PlanRequest& request, const CapturedScene& scene,
                                  const HeadReady& on_head = {});

  const GraspPlanningModel& model() const { return *model_; }
  const TeachStore& teach_store() const { return *teach_; }
  // The ground-truth instance matched to `detection` of the task's last plan; -1 if none.
  int TruthInstanceOf(int task_id, int detection) const;

  // The part the robot holds, as binpick knows it.
  struct HeldPart {
    int class_id = 0;
    Pose X_TO = Pose::Identity();  // in the tool frame
    bool measured = false;         // by an in_hand answer; else the pick's own
  };
  std::optional<HeldPart> held() const;

 private:
  struct TaskState {
    std::vector<Detection> detections;   // last plan's (support dropped)
    std::vector<int> truth_instance;     // per detection, -1 if none
    std::optional<Pose> held_X_BO;       // part last handed out
    int held_class = -1;
  };
  BinPickingPlanner() = default;
  // Pick tasks: perception in the bin, grasps, a thorough retry; the grasp
  // stage's and the retry's wall times (ms; left alone when not run).
  void PlanPick(const PlanRequest& request, const Frame& frame, PlanDetail& detail, double* grasps_ms,
                double* retry_ms, const HeadReady& on_head) const;
  // Remembers the task's plan for simulated picks and teaching: its
  // detections, their true instances (`truth`), the first part of its queue.
  void Remember(int task_id, const PerceptionResult& per, std::vector<int> truth, const Grasp* first);
  // The budget of a thorough retry started at `started_ms` on the retry
  // clock that must leave `reserve_ms` of thorough_retry_ms for what
  // follows it.
  PerceptionBudget RetryBudget(double started_ms, double reserve_ms) const;
  double RetryClockMs() const;
  // in_hand, place and place_area tasks: perception in the task's region.
  Status PlanElsewhere(const PlanRequest& request, const Frame& frame, PlanDetail& detail) const;
  Cell cell_;
  BinPickingPlannerOptions options_;
  std::shared_ptr<const Perception> perception_;
  std::shared_ptr<const GraspPlanningModel> model_;
  std::unique_ptr<TeachStore> teach_;
  // The meshes (in T) of the grippers in_hand tasks use, by gripper name:
  // their points are dropped from an in_hand view (PerceptionRegion::clear_mesh_R).
  std::map<std::string, std::shared_ptr<const TriangleMesh>> tool_meshes_;
  std::mutex source_mutex_;
  std::unique_ptr<CaptureSource> source_;  // GUARDED_BY(source_mutex_)
  mutable std::mutex state_mutex_;
  std::map<int, TaskState> tasks_;         // GUARDED_BY(state_mutex_)
  std::optional<HeldPart> held_;           // GUARDED_BY(state_mutex_)
};

// The teach file BinPickingPlanner uses for `cell` with an empty option.
std::string DefaultTeachFile(const Cell& cell);

}  // namespace bp
