// The planner interface the server drives: capture, then detect and plan.
//
// The split exists for the DaoAI protocol: RC_DAOAI_CAPTURE_AND_PROCESS (20)
// must be answered as soon as the image is captured, while detection and
// planning continue in the background. So a request runs as
//
//   Result<CaptureHandle> scene = planner.Capture(request);  // fast: camera only
//   ... answer the robot ...
//   Result<PlanResult> plan = planner.Plan(request, **scene); // slow: perception
//
// "No objects", "no collision-free grasp" and "capture failed" are normal
// outcomes reported in PlanResult / as a Capture error, never exceptions.
//
// Thread-safety: the server calls Capture / Plan / the hooks from its
// detection workers (a oneTBB arena). Implementations must tolerate calls from
// different threads, but the server never runs two Capture calls at once (one
// camera); Plan calls for different tasks may overlap.
#pragma once

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "core/cell.h"
#include "core/pose.h"
#include "core/status.h"
#include "grasp/grasp.h"
#include "pipeline/bin_detection.h"
#include "pipeline/fill_level.h"

namespace bp {

// A part pose a failed pick refuted (failed-pick feedback, FailedPicks::
// Refuted): a last resort planned on it failed, which is evidence that the
// part does not lie so. In the bin frame W of the failed grasp's capture.
struct RefutedPose {
  int class_id = 0;
  Pose X_WO = Pose::Identity();
};

struct PlanRequest {
  TaskSpec task;                // the cell's task the robot named (payload_1)
  std::optional<Pose> X_BF;     // robot pose sent with the request (eye-in-hand needs it)
  int camera_config_id = 0;     // cell camera config to capture with; 0 = cell default
  // Pick tasks: an ambiguous detection at one of these poses is planned on
  // its other poses (grasp/failed_picks.h, ApplyRefutedPoses).
  std::vector<RefutedPose> refuted = {};
};

// What one capture produced, opaque to the server: the planner that made it
// knows its concrete type (e.g. a Frame). Immutable once returned.
class CapturedScene {
 public:
  virtual ~CapturedScene() = default;
  virtual std::string Describe() const = 0;  // for logs
};
using CaptureHandle = std::shared_ptr<const CapturedScene>;

// A part instance the perception found (with or without a grasp).
struct DetectedPart {
  int class_id = 0;
  Pose X_BO = Pose::Identity();  // part in robot base
  double score = 0.0;
};

// Wall time of one pipeline stage ("roi", "segment", "pose", "grasps", ...).
struct StageTime {
  std::string stage;
  double ms = 0.0;
};

struct PlanResult {
  enum class Outcome {
    kGrasps,            // objects detected, at least one collision-free grasp
    kNoObjects,         // nothing detected
    kNoCollisionFree,   // parts detected but no collision-free grasp
    kCaptureFailed,     // no image (set by the server when Capture fails)
    kPlannerFailed,     // the planner returned an error or threw (set by the server)
  };
  Outcome outcome = Outcome::kNoObjects;
  std::vector<Grasp> grasps;          // queue order: the first is handed out first
  // The detected parts no queued grasp stands for (every grasp refused, a
  // class the task does not pick, or screened out by the failed-pick
  // feedback), each with the detections touching it (within
  // GraspPlanningOptions::touch_distance at their estimated poses; ids as
  // Grasp::instance_id). They stay in the bin and may move when a part they
  // touch is picked: GraspQueue passes staleness on through them, and the
  // queued grasps list them in stale_after / touching (docs/protocols.md
  // "Stale grasps"). Parts touching nothing are left out.
  std::map<int, std::vector<int>> ungrasped_touching;
  int64_t roi_points = 0;             // valid points inside the task's ROI
  int64_t largest_region_points = 0;  // points of the largest connected region in the ROI
  // Pixels of the image the counts come from (width x height): scales the
  // empty-box threshold (EffectiveThreshold); 0 when unknown.
  int64_t image_pixels = 0;
  int detections = 0;                 // part instances detected (with or without grasps)
  std::vector<DetectedPart> parts;    // those instances (planners may leave it empty)
  std::vector<StageTime> stages;      // per-stage latency of this plan, in order
  std::string message;                // human-readable detail for logs
  // Issue 41: where the plan's perception found the bin (nullopt: the stage
  // did not run) and the bin's fill level (nullopt: not measured, e.g. a
  // task looking elsewhere than the bin).
  std::optional<BinDetection> bin;
  std::optional<FillLevel> fill;
};
std::string_view ToString(PlanResult::Outcome outcome);

// RC_SEND_POSE (30): the robot's tool pose at teach time, to be stored as a
// grasp relative to the last part detected for the task.
struct TeachRequest {
  TaskSpec task;
  Pose X_BT = Pose::Identity();
};

// A plan's first grasp, told before the rest of the plan is done
// (GraspPlanner::PlanWithHead).
struct PlanHead {
  Grasp grasp;  // the queue's first grasp, without related poses and stale neighbours
  // The remaining count the head is answered with: an upper bound on the
  // grasps left, the head included, once its hand-out withdrew the grasps
  // it makes stale. 1 when the plan queues nothing after that hand-out;
  // else at least 2, and `next` is a grasp the queue holds after it, so a
  // robot told "more than one left" finds one.
  int max_queue = 1;
  std::optional<Grasp> next;
};
using HeadReady = std::function<void(const PlanHead&)>;

class GraspPlanner {
 public:
  virtual ~GraspPlanner() = default;

  // Acquires the data for one request (camera exposure, transfer). @returns
  // Unavailable / Corruption / ... when no image could be captured.
  virtual Result<CaptureHandle> Capture(const PlanRequest& request) = 0;

  // Detects parts in `scene` and plans grasps for request.task. An OK result
  // with outcome kNoObjects / kNoCollisionFree is a normal answer; a non-OK
  // status means the planner itself failed (the server reports no objects).
  virtual Result<PlanResult> Plan(const PlanRequest& request, const CapturedScene& scene) = 0;

  // Plan, telling `on_head` (on the planning thread, at most once, before
  // returning) the grasp the result's queue will start with as soon as it
  // is known, so that a robot can be answered while the rest is planned
  // (docs/protocols.md "The first pose early"). The head carries what the
  // queued grasp will (X_BW included) but its related poses and stale
  // neighbours; the returned queue's first grasp is the same part with the
  // same grasp. A planner that cannot tell its head early plans as Plan.
  virtual Result<PlanResult> PlanWithHead(const PlanRequest& request, const CapturedScene& scene,
                                          const HeadReady& /*on_head*/) {
    return Plan(request, scene);
  }

  // A grasp was handed to a robot (its response is being written). Planners
  // simulating picks remove the part before the next capture.
  virtual void NotifyHandedOut(const TaskSpec& /*task*/, const Grasp& /*grasp*/) {}

  // RC_SEND_POSE hook. @returns Unavailable when the planner cannot teach.
  virtual Status Teach(const TeachRequest& /*request*/) {
    return Status::Unavailable("this planner does not support teaching");
  }

  // RC_PRECISION_CHECK hook: captures the precision target for `request.task`
  // and @returns the measured 3D error in millimetres, or a non-OK status when
  // the target was not found (answered PRECISION_CHECK_FAIL).
  virtual Result<double> CheckPrecision(const PlanRequest& /*request*/) {
    return Status::Unavailable("this planner does not support precision checks");
  }
};

}  // namespace bp
