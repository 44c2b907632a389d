// DaoAI request semantics, independent of the transport: the socket server
// (comms/daoai_server.h) and the Modbus transport both feed decoded requests
// here. docs/protocols.md has the table of commands x versions this
// implements; every decision there is made here.
//
// Threading: HandleAsync never blocks and never runs detection on the calling
// (network) thread. Captures, detection, empty-box and precision checks,
// calibration steps and teaching run on a oneTBB arena (options.detection_threads).
// Captures are serialized (one camera). Each task has a GraspQueue replaced by
// each detection, in capture order.
//
// One detection in flight per task (docs/protocols.md "Capture floods"):
// capture requests (19, 20, GRI triggers) that arrive while the task's
// detection runs join the one pending after it (at most one; the latest
// robot pose wins; every RC 20 is answered from the capture that serves it).
// RC_DAOAI_PICK_POSE waits, without blocking, for the newest detection
// requested before it: at most the one running and the one pending. A
// pending detection that starts with nobody waiting for it (no pick, no RC
// 20: a flood of 19s) is planned on a thread of lower CPU priority, so the
// flood does not halve another robot's detection; a pick that starts
// waiting while such a plan runs starts the detection pending after it at
// once (the lower-priority plan is abandoned). Empty-box
// (40) and precision checks (50) are batched the same way per task.
//
// The first pose early: a pick plan's first grasp is queued the moment it
// passed every check (GraspPlanner::PlanWithHead, GraspQueue::PublishHead),
// and the pick pose that has waited longest for that detection (or the next
// one to arrive) is answered from it while the rest is planned; GRI
// triggers wait for the whole plan.
//
// The pop rule: a grasp leaves its task's queue only when the transport calls
// the Reply it was given, which it does right before writing the response on
// a connection still open. A robot that disconnects while waiting loses
// nothing; a pop whose write then fails counts as handed out (the grasp is
// gone; the planner was told through NotifyHandedOut).
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "comms/calibration_service.h"
#include "comms/daoai_message.h"
#include "comms/server_observer.h"
#include "core/cell.h"
#include "grasp/failed_picks.h"
#include "grasp/grasp_queue.h"
#include "grasp/planner.h"

namespace bp {

// Turns an answer into what the robot will read on a transport (e.g. the
// Modbus registers saturate the remaining count), or OutOfRange naming the
// field that cannot be sent. Pure; may run on any thread.
using WireRange = std::function<Result<daoai::Response>(const daoai::Response&)>;

// Per-connection state a transport keeps and passes with each request.
// Touched only during HandleAsync (the transport serializes its requests),
// except last_answer (below).
struct ClientContext {
  uint64_t id = 0;
  std::string peer;                 // "ip:port", for logs
  std::optional<Pose> X_BF;         // last robot pose received (position scaled to metres)
  std::chrono::system_clock::time_point pose_time{};  // when X_BF was received
  uint64_t requests = 0;            // requests handled on this connection
  int last_task_id = 0;             // task of the last 19/20/21/40/50/60
  std::optional<int> last_pick_task_id;  // task of the last 19/20/21 on a pick task (teach)
  bool warned_meta_1 = false;       // a meta_1 mismatch was logged once
  // The transport's value range, set by the transport before its first
  // request; empty: int32 fields as built (the DaoAI socket). Every answer
  // passes through it before it is written, and a pick pose before its grasp
  // leaves the queue.
  WireRange wire_range;
  // The last answer written on this connection, as the robot read it; set by
  // the transport after writing it, before the next request.
  std::optional<daoai::Response> last_answer;
  // The peer is allowed to change the cell (calibration, teach, camera
  // config): set by the transport from its config allowlist
  // (docs/reliability.md "Threat model"); refused requests get the
  // protocol's refusal code and a log line.
  bool may_change_cell = true;
  // The pop rule, completed (issue 39): a pick pose's Reply takes its grasp
  // off the queue. A transport that writes the response after the Reply ran
  // sets settle_after_write; the grasp then stays reserved here until the
  // transport calls settle(written): true hands it out
  // (GraspPlanner::NotifyHandedOut), false puts it back at the front of its
  // queue (unless a later detection replaced the queue). Without
  // settle_after_write, or when a transport leaves it unsettled until the
  // client's next request, the grasp counts as handed out.
  bool settle_after_write = false;
  std::function<void(bool written)> settle;
  // Per task, the last grasp handed out on this connection and not yet
  // reported failed (command 60 names it: docs/protocols.md "Failed-pick
  // feedback"). Touched on the transport's thread only.
  std::map<int, Grasp> last_grasps;
};

struct RequestHandlerOptions {
  int detection_threads = 2;  // oneTBB arena concurrency
};

// Totals since start (docs/status_page.md "Metrics"); any thread.
struct RequestHandlerStats {
  uint64_t captures_coalesced = 0;  // capture requests that joined a pending detection
  uint64_t background_detections = 0;  // re-detections nobody waited for, planned at a lower priority
  // Detections that failed with an error (their picks are answered
  // UNKNOWN_COMMAND, never "no objects"): the planner's plan returned one, or
  // anything in the detection's path threw (capture, plan, queue, start);
  // and planner exceptions when told of a grasp handed out.
  uint64_t planner_failures = 0;
  uint64_t observer_failures = 0;   // exceptions an observer let escape (contained)
  // Answers whose building threw, and requests whose handling threw
  // (HandleAsync; a GRI request or answer: CountAnswerFailure), answered
  // with the protocol's error instead.
  uint64_t answer_failures = 0;
  uint64_t jobs_refused = 0;        // calibration steps and teach poses refused: queue full
  uint64_t changes_refused = 0;     // state-changing requests from peers not allowed to
  uint64_t grasps_requeued = 0;     // popped, their answer not written: back in the queue
  uint64_t grasps_superseded = 0;   // popped, not written, the queue replaced meanwhile: dropped
  uint64_t grasps_discarded = 0;    // left in a queue a later detection replaced (never popped)
  uint64_t pick_failures = 0;       // failed picks reported (command 60), accepted
  uint64_t pick_failures_refused = 0;  // reports refused: no grasp to blame, bad reason, not a pick task
  // Pick poses answered from a plan's head before the plan was complete
  // (docs/protocols.md "The first pose early").
  uint64_t first_poses_early = 0;
};

class RequestHandler {
 public:
  // Builds the response at the moment the transport is about to write it (a
  // pick pose pops its grasp here). nullopt: the command has no response.
  // Called at most once, on the transport's thread.
  using Reply = std::function<std::optional<daoai::Response>()>;
  // Receives the Reply, either inside HandleAsync or later from a detection
  // worker thread. Not called if the handler shuts down first.
  using Completion = std::function<void(Reply)>;

  // `planner` must outlive nothing in particular: the handler shares it.
  // `calibration` may be null (a CountingCalibrationService is used).
  RequestHandler(Cell cell, std::shared_ptr<GraspPlanner> planner,
                 std::unique_ptr<CalibrationService> calibration,
                 RequestHandlerOptions options = {});
  ~RequestHandler();  // Shutdown()
  RequestHandler(const RequestHandler&) = delete;
  RequestHandler& operator=(const RequestHandler&) = delete;

  // Observers see every detection and every response (comms/server_observer.h).
  // Add them before the first request; they live as long as the handler.
  void AddObserver(std::shared_ptr<ServerObserver> observer);

  // Never throws: an exception in the request's handling is answered
  // UNKNOWN_COMMAND (payload_1 0, the robot's own pose where it moves to
  // the answer; nothing where it reads none), logged and counted
  // (answer_failures), unless the request was answered before it; the first
  // answer given wins (docs/reliability.md "Faults").
  void HandleAsync(const daoai::Request& request, ClientContext& client, Completion done);
  // Blocking convenience for transports with their own threads (Modbus) and
  // tests: HandleAsync, wait, call the Reply. Always returns: with the
  // response, or nullopt when the command has none, the handler dropped the
  // request (shutdown) or `abandon` (polled every 10 ms while waiting)
  // returned true; an abandoned Reply is never run, so nothing is popped.
  std::optional<daoai::Response> Handle(const daoai::Request& request, ClientContext& client,
                                        const std::function<bool()>& abandon = nullptr);

  // Waits for work in flight; pending completions are dropped. Idempotent.
  void Shutdown();

  const Cell& cell() const;
  int camera_config_id() const;       // current RC_SWITCH_CONFIG selection
  int QueueSize(int task_id) const;   // grasps left; -1 for an unknown task
  // The task's queued and withdrawn grasps (GraspQueue::contents); nullopt for an unknown task.
  std::optional<GraspQueue::Contents> QueueContents(int task_id) const;

  // Task-level operations for the other protocols (the GRI: comms/gri_handler.h).
  // They drive the same per-task detections and grasp queue as the DaoAI
  // commands: a grasp popped here is never handed out again by a pick pose.
  // Thread-safe. @returns NotFound for an unknown task.
  struct TaskSnapshot {
    int in_flight = 0;      // detections running or pending (0..2)
    uint64_t finished = 0;  // detections finished since start (failed captures included)
    // Outcome of the last finished detection; nullopt while one runs or before the first.
    std::optional<PlanResult::Outcome> outcome;
    int grasps_left = 0;
    // The last finished detection's fill level (issue 41; GRI data_4..6).
    std::optional<FillLevel> fill;
  };
  Result<TaskSnapshot> Snapshot(int task_id) const;
  // Capture and detect in the background (as RC_DAOAI_CAPTURE_AND_PROCESS_ASYNC).
  Status StartDetection(int task_id, const std::optional<Pose>& X_BF);
  // Runs `ready` once every detection of the task requested before this
  // call has finished (at most the running one and the one pending after
  // it): at once on the caller's thread when they have, else on the worker
  // finishing the last of them (how a DaoAI pick pose waits). Dropped if the
  // handler shuts down first.
  Status WhenDetected(int task_id, std::function<void()> ready);
  // Pops the next grasp, or with `sendable` the first one it accepts
  // (GraspQueue::PopFirst: the transport encodes and range-checks the answer
  // before the grasp leaves the queue; refused grasps stay queued). The
  // planner is told it was handed out at once, or, with `client` and
  // client->settle_after_write, when the transport settles it
  // (ClientContext::settle).
  using Sendable = std::function<bool(const Grasp&, int remaining)>;
  Result<GraspQueue::Popped> PopGrasp(int task_id, ClientContext* client = nullptr,
                                      const Sendable& sendable = nullptr);
  // Runs `job` with the calibration service after every calibration step
  // already posted, on the same sequence (the GRI's HEC actions). It ends any
  // DaoAI calibration mode (one calibration at a time). Dropped at shutdown.
  // @returns false (job not run, logged, counted) when 64 calibration and
  // teach jobs are already waiting.
  [[nodiscard]] bool RunCalibration(std::function<void(CalibrationService&)> job);

  RequestHandlerStats stats() const;
  // Counts an answer another protocol's handler (the GRI's) had to replace
  // with an error because building it threw (answer_failures). Any thread.
  void CountAnswerFailure();
  // The failed spots a pick task remembers now (grasp/failed_picks.h);
  // empty for other tasks and unknown ones. Any thread.
  std::vector<FailedPicks::Spot> FailedSpots(int task_id) const;

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace bp
