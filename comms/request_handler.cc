#include "comms/request_handler.h"

#include <spdlog/spdlog.h>
#include <sys/resource.h>
#include <tbb/task_arena.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <condition_variable>
#include <cmath>
#include <cstring>
#include <deque>
#include <future>
#include <map>
#include <mutex>
#include <thread>
#include <utility>
#include <vector>

#include "comms/internal/exception_text.h"
#include "core/conventions.h"
#include "core/fault_points.h"
#include "core/sanitizers.h"
#include "grasp/empty_box.h"
#include "grasp/grasp_queue.h"
#include "grasp/robot_targets.h"

namespace bp {
namespace {

using daoai::Request;
using daoai::Response;
using Reply = RequestHandler::Reply;
using Completion = RequestHandler::Completion;
using internal::ExceptionText;

Reply NoResponse() {
  return [] { return std::optional<Response>(); };
}

Reply Respond(Response r) {
  return [r] { return std::optional<Response>(r); };
}

bool IsPickTask(const TaskSpec& t) {
  return t.kind == TaskSpec::Kind::kPick || t.kind == TaskSpec::Kind::kPick2D;
}

// What seed 000's script holds in daoai_payload_1 after reading `answer`
// (`daoai_payload_1=daoai_data[8]/mult`) and sends back unless it sets it
// (send_robot_data: `robot_data[8] = daoai_payload_1`, truncated to an int).
int32_t StalePayload1(const Response& answer) {
  return static_cast<int32_t>(answer.payload[0] / kMult);
}

bool NeedsTask(int32_t command) {
  switch (command) {
    case daoai::kCaptureAndProcessAsync:
    case daoai::kCaptureAndProcess:
    case daoai::kPickPose:
    case daoai::kCheckEmptyBox:
    case daoai::kPrecisionCheck:
    case daoai::kReportPickFailure:
      return true;
    default:
      return false;
  }
}

// Commands that change the cell's state for every robot: calibration steps
// (a solve rewrites the hand-eye file), teach (appends to the taught-grasp
// file), camera config. Only peers in the config allowlist may send them.
bool ChangesTheCell(int32_t command) {
  return daoai::IsCalibrationCommand(command) || command == daoai::kSendPose ||
         command == daoai::kSwitchConfig;
}

// The robot reads an answer to `command` (false: it reads none, and one
// written anyway would shift every later answer): teach (30), and seed
// 000's guidance accumulate (10) and stop manual calibration (2).
bool ReadsAnAnswer(int32_t command, bool v1) {
  return !(command == daoai::kSendPose ||
           (!v1 && (command == daoai::kGuidanceCalibration || command == daoai::kStopManualCalibration)));
}

// How one request is read and answered: the pose encoding (the convention
// meta_1 names, the cell's position unit), the cell's dialect, and the
// request's meta_2, which every answer echoes.
struct WireFormat {
  OrientationConvention convention = OrientationConvention::kAxisAngle;
  double position_scale = 1.0;  // metres per wire unit (before MULT)
  DaoaiDialect dialect = DaoaiDialect::kVisionPilot;
  int32_t meta_2 = 2;
  // The robot's own pose, the request's pose fields as sent. Set for the
  // commands whose answer a seed program moves to (MovesTo): their answers
  // carry it unless they carry a planned pose, so no answer ever sends the
  // robot to a pose binpick did not mean (docs/protocols.md "Poses the robot
  // moves to"). It fits the transport: it came through it.
  std::optional<std::pair<std::array<int32_t, 3>, std::array<int32_t, 4>>> own_pose;
  WireRange range;  // the transport's (ClientContext::wire_range); empty: int32
  bool v1() const { return dialect == DaoaiDialect::kSocketV1; }
};

// Commands whose answer pose a seed program moves to: seed 000's
// `calibra_pose≔daoai_tcp_pose; MoveL calibra_pose` after 4 / 7 (and the 2D
// loop after 11 / 12), `pick_pose = daoai_tcp_pose` after 21; and seed 004's
// guidance answers (12 / 13 / 32 to 10), whose robot program the seed does
// not print ("Vision would calculate and output the next recommended pose"):
// a program that moves to the answer's pose stays where it is.
bool MovesTo(int32_t command) {
  switch (command) {
    case daoai::kStartAutoCalibration:
    case daoai::kAutoAccumulatePose:
    case daoai::kGuidanceCalibration:
    case daoai::kStart2DAutoCalibration:
    case daoai::kAutoAccumulate2DPose:
    case daoai::kPickPose:
      return true;
    default:
      return false;
  }
}

// Consecutive failed views (board or marker not found) after which an auto
// calibration (7, 12) ends with DONE (33 / 34), the status the seed's loop
// stops on; it solves with the views it has, or keeps the previous
// calibration when they are too few.
constexpr int kMaxFailedViewsInARow = 3;

Result<Pose> DecodePose(const Request& r, const WireFormat& f) {
  Vec3 t;
  for (int i = 0; i < 3; ++i) t[i] = FromFixed(r.position[i]) * f.position_scale;
  std::array<double, 4> fields{};
  for (int i = 0; i < 4; ++i) fields[i] = FromFixed(r.orientation[i]);
  Result<Mat3> R = DecodeOrientation(fields, f.convention);
  if (!R.ok()) return R.status();
  return MakePose(*R, t);
}

// Fills position and orientation of `out` with X (range-checked).
Status EncodePose(const Pose& X, const WireFormat& f, Response& out) {
  for (int i = 0; i < 3; ++i) {
    Result<int32_t> v = ToFixed(X.translation()[i] / f.position_scale);
    if (!v.ok()) return v.status();
    out.position[i] = *v;
  }
  const std::array<double, 4> fields = EncodeOrientation(X.linear(), f.convention);
  for (int i = 0; i < 4; ++i) {
    Result<int32_t> v = ToFixed(fields[i]);
    if (!v.ok()) return v.status();
    out.orientation[i] = *v;
  }
  return Status::Ok();
}

// Runs jobs one after another, in submission order, on the arena. At most
// kMaxSerialJobs wait: a robot that floods teach poses (answered at once,
// stored later) cannot grow the queue without bound.
class SerialJobs {
 public:
  static constexpr size_t kMaxSerialJobs = 64;
  explicit SerialJobs(std::function<void(std::function<void()>)> spawn) : spawn_(std::move(spawn)) {}
  // @returns false (job not run) when kMaxSerialJobs are already waiting.
  [[nodiscard]] bool Post(std::function<void()> job) {
    bool start = false;
    {
      std::lock_guard lock(mutex_);
      if (jobs_.size() >= kMaxSerialJobs) return false;
      jobs_.push_back(std::move(job));
      if (!running_) running_ = start = true;
    }
    if (start) spawn_([this] { Drain(); });
    return true;
  }

 private:
  void Drain() {
    for (;;) {
      std::function<void()> job;
      {
        std::lock_guard lock(mutex_);
        if (jobs_.empty()) {
          running_ = false;
          return;
        }
        job = std::move(jobs_.front());
        jobs_.pop_front();
      }
      // A job that throws (it must not: each answers its own errors) must
      // not end the sequence with running_ set: every later job would wait.
      try {
        job();
      } catch (...) {
        spdlog::error("daoai: a calibration or teach job threw: {}", ExceptionText());
      }
    }
  }
  std::function<void(std::function<void()>)> spawn_;
  std::mutex mutex_;
  std::deque<std::function<void()>> jobs_;  // GUARDED_BY(mutex_)
  bool running_ = false;                    // GUARDED_BY(mutex_)
};

// Runs jobs one at a time, in order, on a thread of its own at a lower CPU
// priority (the process's nice + kNice, at most 19) and without oneTBB
// workers (a serial arena: the job's parallel loops run on this thread
// alone). It plans the re-detections nobody waits for (a capture flood's,
// docs/protocols.md "Capture floods"): a robot's detection on the arena then
// gets the cores at the process's priority, and the flooded task's plan
// what is left, instead of each getting half. Linux nice is per thread;
// raising it needs no privilege and lowering it back would, so this thread
// keeps it for life and runs nothing else. Started at the first Post.
class BackgroundLane {
 public:
  // CFS weight 110 against 1024 at nice 0: against one busy thread of the
  // process's priority this thread gets about a tenth of the core.
  static constexpr int kNice = 10;
  ~BackgroundLane() { Stop(); }
  void Post(std::function<void()> job) {
    fault::Hit("background_lane.post");  // tests: the lane cannot take a job (no thread, no memory)
    std::lock_guard lock(mutex_);
    if (!thread_.joinable()) thread_ = std::thread([this] { Run(); });
    jobs_.push_back(std::move(job));
    cv_.notify_one();
  }
  // Runs the jobs posted so far, then joins the thread. No Post after it.
  void Stop() {
    std::thread thread;
    {
      std::lock_guard lock(mutex_);
      stop_ = true;
      thread.swap(thread_);
    }
    cv_.notify_one();
    if (thread.joinable()) thread.join();
  }

 private:
  void Run() {
    const pid_t tid = gettid();
    errno = 0;
    const int nice = getpriority(PRIO_PROCESS, static_cast<id_t>(tid));
    if (errno != 0 || setpriority(PRIO_PROCESS, static_cast<id_t>(tid), std::min(19, nice + kNice)) != 0) {
      spdlog::warn("daoai: the background detection thread keeps the process's priority: {}",
                   std::strerror(errno));
    }
    tbb::task_arena serial(1, /*reserved_for_masters=*/1);
    for (;;) {
      std::function<void()> job;
      {
        std::unique_lock lock(mutex_);
        cv_.wait(lock, [this] { return stop_ || !jobs_.empty(); });
        if (jobs_.empty()) return;
        job = std::move(jobs_.front());
        jobs_.pop_front();
      }
      // Jobs contain their own exceptions; one that escapes must not end the
      // thread (std::terminate) or the jobs behind it.
      try {
        serial.execute(job);
      } catch (...) {
        spdlog::error("daoai: a background detection job threw: {}", ExceptionText());
      }
    }
  }
  std::mutex mutex_;
  std::condition_variable cv_;
  std::deque<std::function<void()>> jobs_;  // GUARDED_BY(mutex_)
  bool stop_ = false;                       // GUARDED_BY(mutex_)
  std::thread thread_;                      // GUARDED_BY(mutex_)
};

// A detection requested while the task's detection runs: it starts when
// that one finishes. Capture requests that arrive meanwhile join it (the
// latest robot pose wins), so a flood of captures costs one detection at a
// time and every requester is answered from a capture made after its
// request.
// (At namespace scope: clang 14 does not see a nested struct with member
// initializers as default-constructible inside its enclosing class, and
// TaskState holds an optional of it.)
struct PendingDetection {
  uint64_t seq = 0;  // the task's capture sequence number
  PlanRequest request;
  std::vector<std::function<void(bool)>> on_captured;  // RC 20 answers, in order
  // Set when it starts after the task's previous detection with no RC 20 in
  // on_captured and no pick waiting: its plan goes to the BackgroundLane
  // unless a robot waits for it by the time the capture is done.
  bool background = false;
};

// A robot waiting for a detection: `ready` answers it. A pick pose
// (takes_head) may be answered from the plan's head before the plan is
// complete (docs/protocols.md "The first pose early"); a GRI trigger waits
// for the whole plan.
struct Waiter {
  std::function<void()> ready;
  bool takes_head = false;
  void operator()() const { ready(); }
};

// A detection whose capture is done, on its way to the plan.
struct CapturedDetection {
  uint64_t seq = 0;
  PlanRequest request;
  CaptureHandle scene;
  DetectionEvent event;  // capture fields filled in
  std::chrono::steady_clock::time_point t0;  // capture start
};

}  // namespace

class RequestHandler::Impl {
 public:
  // Empty-box checks (40) or precision checks (50) of one task: one runs at
  // a time; requests that arrive meanwhile share the next one.
  struct CheckLane {
    bool running = false;
    std::optional<PlanRequest> pending;  // the latest request's
    std::vector<Completion> pending_done;
  };
  struct TaskState {
    TaskSpec spec;
    GraspQueue queue;
    std::mutex mutex;
    bool running = false;                     // GUARDED_BY(mutex): a detection is on the arena
    std::optional<PendingDetection> pending;  // GUARDED_BY(mutex): the one after it
    uint64_t requested_seq = 0;  // GUARDED_BY(mutex): newest detection requested
    uint64_t finished_seq = 0;   // GUARDED_BY(mutex): last finished (they finish in order)
    uint64_t finished = 0;       // GUARDED_BY(mutex): detections finished since start
    // GUARDED_BY(mutex): pick poses (and GRI triggers) waiting, by the
    // sequence number of the detection they wait for.
    std::multimap<uint64_t, Waiter> waiters;
    // GUARDED_BY(mutex): detection N published its head early (the queue
    // holds it) and no waiting robot took it: the next pick pose that
    // waits for N takes it at once (0: none).
    uint64_t head_open_seq = 0;
    // GUARDED_BY(mutex): a captured detection whose plan waits on the
    // BackgroundLane, not started; the first pick that waits takes it to the
    // arena (a plan already running on the lane finishes there).
    std::shared_ptr<CapturedDetection> queued_background;
    // GUARDED_BY(mutex): the detection whose plan runs on the BackgroundLane
    // now (0: none), and one a robot's wait abandoned (0: none): a pick that
    // waits for the detection pending after it starts that one at once on
    // the arena instead of waiting for the lane's plan at nice +10 (docs/
    // reliability.md "Capture flood and soak"). An abandoned plan finishes
    // on the lane and its result is dropped: it neither refills the queue
    // nor counts as finished; the detection after it releases its waiters.
    uint64_t lane_seq = 0;
    uint64_t abandoned_seq = 0;
    CheckLane empty_box, precision;  // GUARDED_BY(mutex)
    // Pick tasks: the failed spots (internally locked; the queue's screen).
    std::unique_ptr<FailedPicks> failed;
    // GUARDED_BY(mutex): the last grasp handed out on any transport and not
    // reported failed since: what a report from a connection that was
    // handed none blames (a GRI robot's DaoAI side, a robot that reconnected).
    std::optional<Grasp> last_handed_out;
  };

  Impl(Cell cell, std::shared_ptr<GraspPlanner> planner,
       std::unique_ptr<CalibrationService> calibration, RequestHandlerOptions options)
      : cell_(std::move(cell)),
        planner_(std::move(planner)),
        calibration_(calibration ? std::move(calibration)
                                 : std::make_unique<CountingCalibrationService>()),
        arena_(std::max(1, options.detection_threads), /*reserved_for_masters=*/0),
        serial_([this](std::function<void()> f) { Spawn(std::move(f)); }) {
    camera_config_id_ = cell_.camera.default_config;
    for (const TaskSpec& t : cell_.tasks) {
      auto state = std::make_unique<TaskState>();
      state->spec = t;
      if (t.kind == TaskSpec::Kind::kPick) {
        state->failed = std::make_unique<FailedPicks>(t.failed_picks, cell_.bin.X_BW);
        state->queue.SetScreen(
            [failed = state->failed.get()](std::deque<Grasp>& grasps) { return failed->Screen(grasps); },
            [failed = state->failed.get()](const Grasp& g) {
              return failed->Judge(g) == FailedPicks::Verdict::kServe;
            });
      }
      tasks_.emplace(t.id, std::move(state));
    }
  }

  ~Impl() { Shutdown(); }

  void Shutdown() {
    if (stopping_.exchange(true)) return;
    {
      std::unique_lock lock(pending_mutex_);
      pending_cv_.wait(lock, [this] { return pending_ == 0; });
    }
    background_.Stop();
    for (auto& [id, t] : tasks_) {
      std::multimap<uint64_t, Waiter> waiters;
      std::optional<PendingDetection> pending;
      {
        std::lock_guard lock(t->mutex);
        waiters.swap(t->waiters);
        pending.swap(t->pending);
      }
      // Destroyed outside the lock: a dropped completion wakes a blocked Handle().
    }
  }

  // HandleAsync with nothing escaping into the caller's (the transport's
  // network) thread (issue 39): an exception HandleAsync lets out (no
  // memory, a bug) is logged, counted (answer_failures) and answered
  // UNKNOWN_COMMAND with payload_1 0 and, where the robot moves to the
  // answer, its own pose (nothing where it reads no answer), unless the
  // request was answered before the exception. The first answer given
  // wins: one the request left to come later (an RC 20's capture, a
  // waiting pick's Reply) is then dropped, so a dropped pick pops nothing.
  void HandleContained(const Request& req, ClientContext& client, Completion done) noexcept;
  void HandleAsync(const Request& req, ClientContext& client, Completion done);
  // The answer HandleContained gives a request whose handling threw.
  Response ErrorAnswer(const Request& req) const {
    Response r = Base(daoai::kUnknownCommand, req.meta_2);
    if (MovesTo(req.command)) {
      r.position = req.position;
      r.orientation = req.orientation;
    }
    return r;
  }
  void CountAnswerFailure() const { answer_failures_.fetch_add(1, std::memory_order_relaxed); }
  // The steps of HandleAsync.
  bool ReadHeader(const Request& req, ClientContext& client, WireFormat& f, const Completion& done) const;
  std::optional<Pose> RecordPose(const Request& req, const WireFormat& f, ClientContext& client,
                                 AnswerEvent* answer_event) const;
  bool ResolveTask(const Request& req, ClientContext& client, const WireFormat& f, const Completion& done,
                   TaskState** out);
  void TeachPose(const Request& req, const ClientContext& client, const std::optional<Pose>& X_BF, Completion done);
  void Dispatch(const Request& req, ClientContext& client, const WireFormat& f, const std::optional<Pose>& X_BF,
                TaskState* task, Completion done);

  void AddObserver(std::shared_ptr<ServerObserver> observer) {
    observers_.push_back(std::move(observer));
  }

  const Cell& cell() const { return cell_; }
  int camera_config_id() const { return camera_config_id_.load(); }
  int QueueSize(int task_id) const {
    auto it = tasks_.find(task_id);
    return it == tasks_.end() ? -1 : it->second->queue.size();
  }

  TaskState* FindTask(int task_id) const {
    auto it = tasks_.find(task_id);
    return it == tasks_.end() ? nullptr : it->second.get();
  }
  Result<TaskSnapshot> Snapshot(int task_id) const;
  Status StartDetection(int task_id, const std::optional<Pose>& X_BF);
  Status WhenDetected(int task_id, std::function<void()> ready);
  Result<GraspQueue::Popped> PopGrasp(int task_id, ClientContext* client,
                                      const RequestHandler::Sendable& sendable);
  bool RunCalibration(std::function<void(CalibrationService&)> job) {
    const bool posted = serial_.Post([this, job = std::move(job)] {
      calibration_mode_.reset();
      job(*calibration_);
    });
    if (!posted) CountRefusedJob("a GRI hand-eye step");
    return posted;
  }
  RequestHandlerStats stats() const {
    RequestHandlerStats s;
    s.captures_coalesced = captures_coalesced_.load(std::memory_order_relaxed);
    s.background_detections = background_detections_.load(std::memory_order_relaxed);
    s.planner_failures = planner_failures_.load(std::memory_order_relaxed);
    s.observer_failures = observer_failures_.load(std::memory_order_relaxed);
    s.answer_failures = answer_failures_.load(std::memory_order_relaxed);
    s.jobs_refused = jobs_refused_.load(std::memory_order_relaxed);
    s.changes_refused = changes_refused_.load(std::memory_order_relaxed);
    s.grasps_requeued = grasps_requeued_.load(std::memory_order_relaxed);
    s.grasps_superseded = grasps_superseded_.load(std::memory_order_relaxed);
    s.grasps_discarded = grasps_discarded_.load(std::memory_order_relaxed);
    s.pick_failures = pick_failures_.load(std::memory_order_relaxed);
    s.pick_failures_refused = pick_failures_refused_.load(std::memory_order_relaxed);
    s.first_poses_early = first_poses_early_.load(std::memory_order_relaxed);
    return s;
  }
  std::vector<FailedPicks::Spot> FailedSpots(int task_id) const {
    const TaskState* t = FindTask(task_id);
    return t && t->failed ? t->failed->Spots() : std::vector<FailedPicks::Spot>{};
  }

 private:
  // Runs a planner call, turning an exception into Internal: a detection
  // that throws must still finish (answer the capture, release waiting
  // picks), never leave the task in flight forever.
  // `threw` (optional) tells an exception from an error the call returned.
  template <typename F>
  static auto Guard(const char* what, F&& f, bool* threw = nullptr) -> decltype(f()) {
    try {
      return f();
    } catch (...) {
      if (threw) *threw = true;
      return Status::Internal(std::string(what) + " threw: " + ExceptionText());
    }
  }

  // Runs f on the arena (never on the caller's thread). Exceptions must not
  // escape f: they are caught and logged here as a last resort. Throws
  // (std::bad_alloc, std::system_error) when the job cannot be queued; then
  // f never runs and nothing is left counted.
  void Spawn(std::function<void()> f) {
    // Owned by `run`, which runs exactly once and deletes it before it
    // counts itself done, or by the catch below when it cannot be queued.
    // Not a shared_ptr in the functor: the arena destroys its copy of the
    // functor only after the functor returns, so a process exiting right
    // after Shutdown could still hold the job there (LSan reported it leaked).
    auto* job = new std::function<void()>(std::move(f));
    auto run = [this, job] {
      try {
        (*job)();
      } catch (...) {
        spdlog::error("daoai: detection worker failed: {}", ExceptionText());
      }
      delete job;  // its captures too, before Shutdown may return
      std::lock_guard lock(pending_mutex_);
      --pending_;
      pending_cv_.notify_all();
    };
    {
      std::lock_guard lock(pending_mutex_);
      ++pending_;
    }
    try {
#if BP_UNDER_TSAN
      // The system's libtbb is not instrumented, so ThreadSanitizer cannot see
      // the hand-off through the arena and reports every task as a race. Under
      // TSan, run each job on its own thread instead (same ordering guarantees:
      // none beyond the mutexes above).
      std::thread(std::move(run)).detach();
#else
      arena_.enqueue(std::move(run));
#endif
    } catch (...) {
      delete job;  // never queued: run never runs
      std::lock_guard lock(pending_mutex_);
      --pending_;
      pending_cv_.notify_all();
      throw;
    }
  }

  // A status-only answer: meta_1 is the cell's robot type, meta_2 the
  // request's version (echoed: the seeds' scripts raise a popup when it
  // differs from their own).
  Response Base(int32_t status, const WireFormat& f) const {
    Response r = Base(status, f.meta_2);
    if (f.own_pose) {
      r.position = f.own_pose->first;
      r.orientation = f.own_pose->second;
    }
    return r;
  }
  Response Base(int32_t status, int32_t meta_2) const {
    Response r;
    r.status = status;
    r.meta_1 = static_cast<int32_t>(cell_.robot.model.type);
    r.meta_2 = meta_2;
    return r;
  }

  // `X_BF`: the pose of this request (never a stale one from an earlier message).
  PlanRequest MakePlanRequest(const TaskState& t, const std::optional<Pose>& X_BF) const {
    PlanRequest p;
    p.task = t.spec;
    p.X_BF = X_BF;
    p.camera_config_id = camera_config_id_.load();
    if (t.failed) p.refuted = t.failed->Refuted();  // failed last resorts (grasp/failed_picks.h)
    return p;
  }

  // Starts a detection of `t`, or joins the one pending after the running
  // one (docs/protocols.md "Capture floods"). @returns the sequence number of
  // the detection that serves this request.
  uint64_t RequestDetection(TaskState& t, PlanRequest request, std::function<void(bool)> on_captured);
  // Captures (on the calling arena thread), then plans here, or on the
  // BackgroundLane when d.background and nobody waits for it by then.
  // RunDetection and PlanDetection never throw: whatever throws in a
  // detection's path ends it through FailDetection.
  void RunDetection(TaskState& t, const PendingDetection& d);
  void PlanDetection(TaskState& t, const CapturedDetection& c);
  // Queues `job`'s plan on the BackgroundLane; false (not queued) when a
  // robot waits for the task already, or the lane cannot take it. Never throws.
  bool PostBackground(TaskState& t, const std::shared_ptr<CapturedDetection>& job);
  // Releases the picks waiting for detection `seq` and starts the pending
  // one. Never throws: a robot waiting for a detection is always answered.
  void FinishDetection(TaskState& t, uint64_t seq) noexcept;
  // Spawns RunDetection(d), or fails d (FailDetection) when it cannot be queued.
  void StartDetectionJob(TaskState& t, PendingDetection d);
  // What a detection had done when something in its path threw.
  struct DetectionProgress {
    bool answered = false;  // its RC 20s were answered
    bool queued = false;    // its result replaced the task's queue
  };
  // Ends detection `seq` of `t` after an exception in its path (`stage`:
  // where; `error`: what): its picks are answered as a failed plan
  // (UNKNOWN_COMMAND, never "no objects"), its RC 20s CAPTURE_FAIL unless
  // answered, observers get `event` with the error and `scene` (the
  // recorder keeps the frame for replay), logged and counted
  // (planner_failures). Never throws.
  void FailDetection(TaskState& t, uint64_t seq, const DetectionEvent* event, CaptureHandle scene,
                     const std::vector<std::function<void(bool)>>* on_captured, DetectionProgress progress,
                     const char* stage, const char* error) noexcept;
  // Calls each RC 20 answer; one that throws does not stop the others.
  static void AnswerCaptured(const std::vector<std::function<void(bool)>>& answers, bool ok) noexcept;
  // Keeps `ready` (moved from) until the newest detection of `t` requested
  // so far has finished; @returns false, `ready` untouched, when it has, or
  // when `takes_head` (a pick pose) and that detection's head, published
  // early, waits for a robot (head_open_seq): this one takes it.
  bool WaitForDetection(TaskState& t, std::function<void()>& ready, bool takes_head = false);
  // The planner's head of detection `c` (GraspPlanner::PlanWithHead), on the
  // planning thread: queued (GraspQueue::PublishHead) when it passes the
  // workspace gate and the screen, then handed to the robot that has waited
  // longest for this detection with a pick pose, else kept for the next
  // one (head_open_seq). Never throws.
  void PublishHead(TaskState& t, const CapturedDetection& c, const PlanHead& head) noexcept;
  // Runs `check` for a batch of 40s or 50s of one task (CheckLane).
  struct Check {
    const char* what = "";  // for the log: "empty-box check"
    // Answered when the check throws (never "empty": no evidence).
    int32_t failed = daoai::kUnknownCommand;
    std::function<Response(const PlanRequest&)> run;
  };
  struct CheckJob {
    PlanRequest request;
    std::vector<Completion> done;
    Check check;
  };
  void PostCheck(TaskState& t, CheckLane TaskState::*lane, PlanRequest request, Completion done,
                 Check check);
  // Spawns RunCheck; when it cannot be queued, answers the batch
  // check.failed (logged) and goes on with the lane's next batch.
  void StartCheck(TaskState& t, CheckLane TaskState::*lane, PlanRequest request,
                  std::vector<Completion> done, Check check);
  void RunCheck(TaskState& t, CheckLane TaskState::*lane, const CheckJob& job);
  // Answers `done` with `reply` and starts the lane's pending batch.
  void FinishCheck(TaskState& t, CheckLane TaskState::*lane, const Check& check, const Reply& reply,
                   const std::vector<Completion>& done);
  // A check answers a batch of requests with one response (built with the
  // cell's protocol version); each requester's completion gives it its own
  // request's meta_2 back.
  static Completion EchoMeta2(const WireFormat& f, Completion done) {
    return [meta_2 = f.meta_2, done = std::move(done)](Reply reply) {
      if (!reply) {
        done(std::move(reply));
        return;
      }
      done([meta_2, reply = std::move(reply)]() -> std::optional<Response> {
        std::optional<Response> r = reply();
        if (r) r->meta_2 = meta_2;
        return r;
      });
    };
  }
  Response EmptyBoxCheck(TaskState& t, const PlanRequest& plan_request);
  Response PrecisionCheck(const PlanRequest& plan_request);
  void CountRefusedJob(const char* what) {
    const uint64_t n = jobs_refused_.fetch_add(1, std::memory_order_relaxed) + 1;
    spdlog::warn("daoai: {} refused: {} calibration and teach jobs are already waiting ({} refused "
                 "since start)", what, SerialJobs::kMaxSerialJobs, n);
  }
  Reply PickReply(TaskState& t, WireFormat f, ClientContext* client);
  // A popped grasp: handed out now, or reserved on `client` until its
  // transport settles it (ClientContext::settle).
  void HandOut(TaskState& t, const GraspQueue::Popped& p, ClientContext* client);
  // A reserved grasp's answer was written (handed out) or not (put back
  // with the grasps withdrawn with it: GraspQueue::Restore). Never throws
  // (it runs on a transport's thread).
  void Settle(TaskState& t, const GraspQueue::Popped& p, bool written) noexcept;
  // GraspPlanner::NotifyHandedOut; an exception is logged and counted, and
  // the grasp counts as handed out (the robot has it).
  void TellHandedOut(const TaskState& t, const Grasp& g) noexcept;
  // Teach (30): the pick task payload_1 names, unless payload_1 is only what
  // the last answer left in the script's daoai_payload_1 (seed 000's
  // daoai_teach_pose never sets it: often a remaining count) and the
  // connection has picked on a task; then, or when payload_1 names no pick
  // task, the connection's last pick task. nullptr: neither.
  const TaskState* TeachTask(const Request& req, const ClientContext& client) const {
    const TaskState* named = FindTask(req.payload_1);
    if (named && !IsPickTask(named->spec)) named = nullptr;
    const TaskState* last = client.last_pick_task_id ? FindTask(*client.last_pick_task_id) : nullptr;
    const bool stale = client.last_answer && req.payload_1 == StalePayload1(*client.last_answer);
    if (named && !(stale && last)) return named;
    return last;
  }
  // Every answer `done` is given passes through the transport's range: an
  // answer that does not fit becomes UNKNOWN_COMMAND (with the robot's own
  // pose where it moves to), logged. Observers see what the robot reads.
  Completion InRange(const Request& req, const WireFormat& f, Completion done) const;
  // Every Reply `done` is given is run inside a catch: one that throws (a
  // bug, no memory) is answered UNKNOWN_COMMAND (the robot's own pose where
  // it moves to), logged and counted (answer_failures), instead of escaping
  // into the transport's thread. Observers see that answer.
  Completion Contained(const Request& req, const WireFormat& f, Completion done) const {
    return [this, command = req.command, f, done = std::move(done)](Reply reply) {
      if (!reply) {
        done(std::move(reply));
        return;
      }
      done([this, command, f, reply = std::move(reply)]() -> std::optional<Response> {
        try {
          return reply();
        } catch (...) {
          const uint64_t n = answer_failures_.fetch_add(1, std::memory_order_relaxed) + 1;
          spdlog::error("daoai: building the answer to command {} threw ({}); answering UNKNOWN_COMMAND "
                        "({} since start)", command, ExceptionText(), n);
          return Base(daoai::kUnknownCommand, f);
        }
      });
    };
  }
  // One view of an auto calibration (7, or 12 for 2D), on the calibration
  // sequence: the mode status with the next planned pose (a failed view is
  // skipped), DONE (33 / 34) when the plan is complete or after
  // kMaxFailedViewsInARow failed views in a row.
  void AutoView(CalibrationKind kind, const Pose& X_BF,
                const std::function<void(int32_t, const std::optional<Pose>&)>& answer);
  void RefuseChange(const Request& req, const ClientContext& client, const WireFormat& f,
                    Completion done);
  // Command 60: the last grasp of `t` handed to this robot failed
  // (grasp/failed_picks.h; docs/protocols.md "Failed-pick feedback").
  void ReportPickFailure(const Request& req, ClientContext& client, const WireFormat& f, TaskState& t,
                         Completion done);
  // The grasp a report from `client` on `t` blames, taken (a second report
  // needs another hand-out); nullopt: none.
  std::optional<Grasp> TakeLastGrasp(ClientContext& client, TaskState& t);
  // Remembers a grasp the robot received (the one a report would blame).
  void Received(TaskState& t, const Grasp& g, ClientContext* client) {
    if (!t.failed) return;
    if (client) client->last_grasps[t.spec.id] = g;
    std::lock_guard lock(t.mutex);
    t.last_handed_out = g;
  }
  void Calibrate(const Request& req, const std::optional<Pose>& X_BF, const WireFormat& f,
                 Completion done);
  // One calibration command on the calibration sequence (Calibrate's job).
  void RunCalibrationCommand(int32_t command, const Pose& X_BF, const WireFormat& f, const Completion& done);
  // Starts a calibration of `kind` with the robot at X_BF and enters its
  // mode; false (logged, no mode) when the service refuses.
  bool StartCalibration(CalibrationKind kind, const Pose& X_BF);
  // Accumulates the view at X_BF in `kind`, finishing it (and leaving the
  // mode) on its last view; nullopt (logged) when the view is not used.
  std::optional<CalibrationStep> AccumulateCalibration(CalibrationKind kind, const Pose& X_BF);

  Cell cell_;
  std::shared_ptr<GraspPlanner> planner_;
  std::unique_ptr<CalibrationService> calibration_;  // used from serial_ jobs only
  std::map<int, std::unique_ptr<TaskState>> tasks_;  // fixed after construction
  std::atomic<int> camera_config_id_{1};
  std::mutex capture_mutex_;  // one capture at a time (one camera)
  std::atomic<bool> stopping_{false};

  // Calibration mode (seed 000 DAOAI_MODE_*): touched by serial_ jobs only.
  std::optional<CalibrationKind> calibration_mode_;
  int failed_views_in_a_row_ = 0;  // of the auto calibration in progress (7 / 12)

  // Work spawned on the arena and not finished yet; Shutdown waits for 0.
  std::mutex pending_mutex_;
  std::condition_variable pending_cv_;
  int pending_ = 0;  // GUARDED_BY(pending_mutex_)
  tbb::task_arena arena_;
  SerialJobs serial_;  // calibration steps and teaching, in request order
  BackgroundLane background_;  // plans of re-detections nobody waits for
  std::vector<std::shared_ptr<ServerObserver>> observers_;  // fixed before serving
  std::atomic<uint64_t> captures_coalesced_{0};
  std::atomic<uint64_t> background_detections_{0};
  std::atomic<uint64_t> planner_failures_{0};
  mutable std::atomic<uint64_t> observer_failures_{0};
  mutable std::atomic<uint64_t> answer_failures_{0};
  std::atomic<uint64_t> jobs_refused_{0};
  std::atomic<uint64_t> changes_refused_{0};
  std::atomic<uint64_t> grasps_requeued_{0};
  std::atomic<uint64_t> grasps_superseded_{0};
  std::atomic<uint64_t> grasps_discarded_{0};
  std::atomic<uint64_t> pick_failures_{0};
  std::atomic<uint64_t> pick_failures_refused_{0};
  std::atomic<uint64_t> first_poses_early_{0};

  // Calls `notify` on every observer. An observer that throws (it must not)
  // is logged and counted, and the others and the caller carry on: a
  // detection always finishes, an answer is always written.
  template <typename F>
  void Notify(const char* what, F&& notify) const {
    for (const auto& o : observers_) {
      std::string error;
      try {
        notify(*o);
        continue;
      } catch (const std::exception& e) {
        error = e.what();
      } catch (...) {
        error = "an exception that is not a std::exception";
      }
      const uint64_t n = observer_failures_.fetch_add(1, std::memory_order_relaxed) + 1;
      // The first, then one in a thousand: an observer that always throws
      // must not flood the log.
      if (n == 1 || n % 1000 == 0) {
        spdlog::error("daoai: an observer's {} threw ({}); ignored ({} observer exceptions since "
                      "start)", what, error, n);
      }
    }
  }
  void NotifyDetection(const DetectionEvent& e) const {
    Notify("OnDetection", [&](ServerObserver& o) { o.OnDetection(e); });
  }
  // Wraps `done` so that observers see the response its Reply builds.
  Completion Observed(const Request& req, const ClientContext& client,
                      std::shared_ptr<AnswerEvent>& event, Completion done) const {
    if (observers_.empty()) return done;
    event = std::make_shared<AnswerEvent>();
    event->client_id = client.id;
    event->peer = client.peer;
    event->X_BF = client.X_BF;
    event->request = req;
    return [this, event, done = std::move(done)](Reply reply) {
      if (!reply) {
        done(std::move(reply));
        return;
      }
      done([this, event, reply = std::move(reply)]() -> std::optional<Response> {
        std::optional<Response> r = reply();
        if (r) {
          AnswerEvent e = *event;
          e.response = *r;
          e.time = std::chrono::system_clock::now();
          Notify("OnAnswer", [&](ServerObserver& o) { o.OnAnswer(e); });
        }
        return r;
      });
    };
  }
};

uint64_t RequestHandler::Impl::RequestDetection(TaskState& t, PlanRequest request,
                                                std::function<void(bool)> on_captured) {
  PendingDetection start;
  {
    std::lock_guard lock(t.mutex);
    if (t.running) {
      if (t.pending) {
        captures_coalesced_.fetch_add(1, std::memory_order_relaxed);
      } else {
        t.pending.emplace();
        t.pending->seq = ++t.requested_seq;
      }
      t.pending->request = std::move(request);  // the latest robot pose wins
      if (on_captured) t.pending->on_captured.push_back(std::move(on_captured));
      return t.pending->seq;
    }
    t.running = true;
    start.seq = ++t.requested_seq;
  }
  start.request = std::move(request);
  if (on_captured) start.on_captured.push_back(std::move(on_captured));
  const uint64_t seq = start.seq;
  StartDetectionJob(t, std::move(start));
  return seq;
}

void RequestHandler::Impl::StartDetectionJob(TaskState& t, PendingDetection d) {
  std::shared_ptr<PendingDetection> job;
  try {
    job = std::make_shared<PendingDetection>(std::move(d));
    Spawn([this, &t, job] { RunDetection(t, *job); });
  } catch (...) {
    // Not started (no memory, no thread): it fails as a whole, so that the
    // task is not left running forever.
    const PendingDetection& failed = job ? *job : d;
    FailDetection(t, failed.seq, nullptr, nullptr, &failed.on_captured, {}, "start", ExceptionText());
  }
}

void RequestHandler::Impl::AnswerCaptured(const std::vector<std::function<void(bool)>>& answers,
                                          bool ok) noexcept {
  for (const auto& answer : answers) {
    try {
      answer(ok);
    } catch (...) {
      spdlog::error("daoai: answering a capture request threw: {}", ExceptionText());
    }
  }
}

void RequestHandler::Impl::RunDetection(TaskState& t, const PendingDetection& d) {
  DetectionProgress progress;
  std::shared_ptr<CapturedDetection> job;
  try {
    job = std::make_shared<CapturedDetection>();
    CapturedDetection& c = *job;
    c.seq = d.seq;
    c.request = d.request;
    c.t0 = std::chrono::steady_clock::now();
    DetectionEvent& event = c.event;
    event.task_id = t.spec.id;
    event.request = d.request;
    event.time = std::chrono::system_clock::now();
    Result<CaptureHandle> scene = Status::Unavailable("not captured");
    bool threw = false;
    {
      std::lock_guard lock(capture_mutex_);
      scene = Guard("capture", [&] { return planner_->Capture(d.request); }, &threw);
    }
    event.capture_ms =
        std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - c.t0).count();
    if (!scene.ok() || !*scene) {
      event.capture_status = scene.ok() ? Status::Internal("planner returned no scene") : scene.status();
      event.plan_status = event.capture_status;
      PlanResult failed;
      failed.outcome = PlanResult::Outcome::kCaptureFailed;
      if (threw) {
        // Not a camera that answered "no image": an error, so the task's
        // picks are answered as a failed plan, not as an empty bin.
        failed.outcome = PlanResult::Outcome::kPlannerFailed;
        const uint64_t n = planner_failures_.fetch_add(1, std::memory_order_relaxed) + 1;
        spdlog::error("daoai: task {} capture failed: {}; answering its picks UNKNOWN_COMMAND until the "
                      "next detection ({} failed detections since start)",
                      t.spec.id, event.capture_status.ToString(), n);
      } else {
        spdlog::warn("daoai: task {} capture failed: {}", t.spec.id, event.capture_status.ToString());
      }
      t.queue.Replace(std::move(failed), d.seq);
      progress.queued = true;
      NotifyDetection(event);
      progress.answered = true;
      AnswerCaptured(d.on_captured, false);
      FinishDetection(t, d.seq);
      return;
    }
    c.scene = std::move(*scene);
    progress.answered = true;
    AnswerCaptured(d.on_captured, true);
    // A capture of the task: failed spots age (released `captures` after their last failure).
    if (t.failed) t.failed->OnCapture();
  } catch (...) {
    // The event with the frame, when there is one (the recorder keeps it for replay).
    FailDetection(t, d.seq, job ? &job->event : nullptr, job ? job->scene : nullptr, &d.on_captured,
                  progress, "capture", ExceptionText());
    return;
  }
  // The capture ran here, at the process's priority: it holds the camera,
  // which a robot's detection may be waiting for. Neither call throws.
  if (d.background && PostBackground(t, job)) return;
  PlanDetection(t, *job);
}

bool RequestHandler::Impl::PostBackground(TaskState& t, const std::shared_ptr<CapturedDetection>& job) {
  {
    std::lock_guard lock(t.mutex);
    if (!t.waiters.empty()) return false;  // a robot waits for it already
    t.queued_background = job;  // until the lane or a robot's WaitForDetection takes it
  }
  {
    std::lock_guard lock(pending_mutex_);
    ++pending_;  // taken while the posting job still counts: Shutdown waits for it
  }
  auto plan = [this, &t, job] {
    bool mine = false;
    try {
      {
        std::lock_guard lock(t.mutex);
        if (t.queued_background == job) {
          t.queued_background.reset();
          t.lane_seq = job->seq;
          mine = true;
        }
      }
      // Not mine: a robot's pick took it to the arena. At shutdown it is
      // dropped (nobody waits for it; Shutdown drops any later waiter).
      if (mine && !stopping_) {
        fault::Hit("background_lane.plan");  // tests: the lane's job throws before its plan
        PlanDetection(t, *job);  // never throws
      }
    } catch (...) {
      // Whatever threw here must not leave the task in flight (its pending
      // detection never started, every later pick waiting) nor Shutdown
      // waiting for this job: the detection fails as a whole.
      if (mine) {
        DetectionProgress progress;
        progress.answered = true;  // its RC 20s were answered at the capture
        FailDetection(t, job->seq, &job->event, job->scene, nullptr, progress, "background plan",
                      ExceptionText());
      } else {
        spdlog::error("daoai: task {}: the background lane's job threw: {}", t.spec.id, ExceptionText());
      }
    }
    std::lock_guard lock(pending_mutex_);
    --pending_;
    pending_cv_.notify_all();
  };
  // Counted before the lane can run it (a reader that sees its plan done
  // sees it counted).
  background_detections_.fetch_add(1, std::memory_order_relaxed);
  try {
    background_.Post(std::move(plan));
  } catch (...) {
    background_detections_.fetch_sub(1, std::memory_order_relaxed);
    // The lane cannot take it (no thread, no memory): planned here, unless
    // a robot's pick took it to the arena meanwhile.
    spdlog::error("daoai: task {}: the background lane refused a plan ({}); planning it at once",
                  t.spec.id, ExceptionText());
    bool mine = false;
    {
      std::lock_guard lock(t.mutex);
      if (t.queued_background == job) {
        t.queued_background.reset();
        mine = true;
      }
    }
    {
      std::lock_guard lock(pending_mutex_);
      --pending_;
      pending_cv_.notify_all();
    }
    return !mine;  // true: taken by a robot, nothing left to do here
  }
  return true;
}

void RequestHandler::Impl::PlanDetection(TaskState& t, const CapturedDetection& c) {
  DetectionProgress progress;
  progress.answered = true;
  try {
    DetectionEvent event = c.event;
    const PlanRequest& plan_request = c.request;
    const auto t1 = std::chrono::steady_clock::now();
    const HeadReady on_head = [this, &t, &c](const PlanHead& head) { PublishHead(t, c, head); };
    Result<PlanResult> plan =
        Guard("detection", [&] { return planner_->PlanWithHead(plan_request, *c.scene, on_head); });
    PlanResult result;
    if (plan.ok()) {
      result = std::move(*plan);
    } else {
      // Not "no objects": the robot must not conclude the bin is empty. The
      // observers get the capture with the error (the recorder keeps the
      // frame for `binpick replay`).
      planner_failures_.fetch_add(1, std::memory_order_relaxed);
      spdlog::error("daoai: task {} planning failed ({}); answering its picks UNKNOWN_COMMAND until "
                    "the next detection; the capture goes to the recorder for replay",
                    t.spec.id, plan.status().ToString());
      result.outcome = PlanResult::Outcome::kPlannerFailed;
    }
    // A grasp that would send the robot outside its workspace never enters
    // the queue (grasp/robot_targets.h; the link's range is checked later,
    // at the pop: docs/protocols.md "Poses the robot moves to").
    DropUnreachable(cell_, t.spec, result);
    const auto t2 = std::chrono::steady_clock::now();
    const auto ms = std::chrono::duration<double, std::milli>(t2 - c.t0);
    spdlog::info("daoai: task {} detection: {} grasps, {} detections, outcome {} in {:.1f} ms",
                 t.spec.id, result.grasps.size(), result.detections, ToString(result.outcome),
                 ms.count());
    if (!observers_.empty()) {
      event.scene = c.scene;
      event.plan_status = plan.status();
      if (plan.ok()) event.plan = result;
      // The plan alone: a background plan's wait for the lane is not in it.
      event.plan_ms = std::chrono::duration<double, std::milli>(t2 - t1).count();
    }
    {
      std::lock_guard lock(t.mutex);
      if (t.abandoned_seq == c.seq) {
        // A robot's wait started the detection after it: that one refills.
        t.abandoned_seq = 0;
        if (t.lane_seq == c.seq) t.lane_seq = 0;
        spdlog::info("daoai: task {}: the background plan of detection {} was abandoned for the one after "
                     "it (a robot waits for that); its result is dropped", t.spec.id, c.seq);
        return;
      }
    }
    // The parts this capture shows keep their collision spots (grasp/failed_picks.h).
    if (t.failed) t.failed->Seen(result.parts, result.bin ? std::optional<Pose>(result.bin->X_BW) : std::nullopt);
    int discarded = 0;
    t.queue.Replace(std::move(result), c.seq, &discarded);
    progress.queued = true;
    if (discarded > 0) {
      // The robots asked for a new capture with grasps left: by design, but
      // counted (binpick_grasps_discarded_total).
      grasps_discarded_.fetch_add(static_cast<uint64_t>(discarded), std::memory_order_relaxed);
      spdlog::debug("daoai: task {}: {} grasps of the previous detection were never handed out",
                    t.spec.id, discarded);
    }
    // After the refill (an observer reading the queue sees the new one),
    // before waiting picks are answered (their answers follow the detection;
    // a pick answered from the plan's head early came before it).
    if (!observers_.empty()) NotifyDetection(event);
  } catch (...) {
    if (!progress.queued) {
      FailDetection(t, c.seq, &c.event, c.scene, nullptr, progress, "plan", ExceptionText());
      return;
    }
    // Queued: the robots get the plan; only its notice was lost.
    spdlog::error("daoai: task {} detection: {} after the refill", t.spec.id, ExceptionText());
  }
  FinishDetection(t, c.seq);
}

void RequestHandler::Impl::FailDetection(TaskState& t, uint64_t seq, const DetectionEvent* event,
                                         CaptureHandle scene,
                                         const std::vector<std::function<void(bool)>>* on_captured,
                                         DetectionProgress progress, const char* stage,
                                         const char* error) noexcept {
  const uint64_t n = planner_failures_.fetch_add(1, std::memory_order_relaxed) + 1;
  spdlog::error("daoai: task {} detection failed at its {} ({}); answering its picks UNKNOWN_COMMAND "
                "until the next detection{} ({} failed detections since start)", t.spec.id, stage,
                error, scene ? "; the capture goes to the recorder for replay" : "", n);
  try {
    if (!progress.queued) {
      PlanResult failed;
      failed.outcome = PlanResult::Outcome::kPlannerFailed;
      t.queue.Replace(std::move(failed), seq);
    }
  } catch (...) {
    spdlog::error("daoai: task {}: its queue keeps the previous detection's grasps: {}", t.spec.id,
                  ExceptionText());
  }
  if (event && !observers_.empty()) {
    try {
      DetectionEvent e = *event;
      e.scene = scene;
      e.plan.reset();
      e.plan_status = Status::Internal(std::string(stage) + " threw: " + error);
      if (e.capture_status.ok() && !e.scene) e.capture_status = e.plan_status;
      NotifyDetection(e);
    } catch (...) {
      spdlog::error("daoai: task {}: the failed detection's event is lost: {}", t.spec.id, ExceptionText());
    }
  }
  if (!progress.answered && on_captured) AnswerCaptured(*on_captured, false);
  FinishDetection(t, seq);
}

void RequestHandler::Impl::FinishDetection(TaskState& t, uint64_t seq) noexcept {
  // The released waiters are moved node by node (no allocation: nothing
  // here throws between marking the detection finished and answering them).
  std::multimap<uint64_t, Waiter> ready;
  std::optional<PendingDetection> next;
  {
    std::lock_guard lock(t.mutex);
    if (t.lane_seq == seq) t.lane_seq = 0;
    if (t.head_open_seq <= seq) t.head_open_seq = 0;
    if (t.abandoned_seq == seq) {
      // Abandoned while it refilled or failed: the detection after it runs
      // and finishes the task's sequence (running, pending, waiters).
      t.abandoned_seq = 0;
      return;
    }
    ++t.finished;
    t.finished_seq = seq;
    while (!t.waiters.empty() && t.waiters.begin()->first <= seq) {
      ready.insert(t.waiters.extract(t.waiters.begin()));
    }
    if (t.pending && !stopping_) {
      next.swap(t.pending);
      // Requested while this one ran (a re-capture): nobody waits for it
      // yet (the waiters for `seq` and before are released above).
      next->background = next->on_captured.empty() && t.waiters.empty();
    } else {
      t.running = false;
    }
  }
  // The next detection goes onto the arena before the answers are sent, so
  // it starts as early as it can.
  if (next) StartDetectionJob(t, std::move(*next));
  for (auto& [waited_for, answer] : ready) {
    try {
      answer();
    } catch (...) {
      spdlog::error("daoai: task {}: answering a robot waiting for detection {} threw: {}", t.spec.id,
                    waited_for, ExceptionText());
    }
  }
}

bool RequestHandler::Impl::WaitForDetection(TaskState& t, std::function<void()>& ready, bool takes_head) {
  std::shared_ptr<CapturedDetection> promoted;
  std::optional<PendingDetection> next;
  uint64_t abandoned = 0;
  {
    std::lock_guard lock(t.mutex);
    if (t.requested_seq <= t.finished_seq) return false;
    if (takes_head && t.head_open_seq == t.requested_seq) {
      t.head_open_seq = 0;  // this robot's: answered at once
      first_poses_early_.fetch_add(1, std::memory_order_relaxed);
      return false;
    }
    t.waiters.emplace(t.requested_seq, Waiter{std::move(ready), takes_head});
    promoted.swap(t.queued_background);
    // The running detection's plan is on the lane (nice +10) and the robot
    // waits for the one pending after it: that one starts now, at the
    // process's priority, and the lane's plan is abandoned (TaskState).
    if (t.lane_seq != 0 && t.abandoned_seq == 0 && t.pending && !stopping_) {
      t.abandoned_seq = abandoned = t.lane_seq;
      next.swap(t.pending);
    }
  }
  if (next) {
    spdlog::info("daoai: task {}: a robot waits for detection {}: started at once instead of after the "
                 "background plan of detection {}", t.spec.id, next->seq, abandoned);
    StartDetectionJob(t, std::move(*next));  // never throws
  }
  // A plan queued on the background lane (behind another task's) is now
  // awaited: it runs on the arena at once, at the process's priority.
  if (promoted) {
    try {
      Spawn([this, &t, promoted] { PlanDetection(t, *promoted); });
    } catch (...) {
      DetectionProgress progress;
      progress.answered = true;
      FailDetection(t, promoted->seq, &promoted->event, promoted->scene, nullptr, progress, "plan",
                    ExceptionText());
    }
  }
  return true;
}

void RequestHandler::Impl::PublishHead(TaskState& t, const CapturedDetection& c, const PlanHead& head) noexcept {
  try {
    if (stopping_) return;
    {
      std::lock_guard lock(t.mutex);
      if (t.abandoned_seq == c.seq) return;  // its plan is dropped: so is its head
    }
    // The gate the full plan passes (PlanDetection): a head (or next) it
    // would drop is not what the full queue holds; the robots wait for it.
    PlanResult gated;
    gated.outcome = PlanResult::Outcome::kGrasps;
    gated.grasps.push_back(head.grasp);
    if (head.next) gated.grasps.push_back(*head.next);
    if (DropUnreachable(cell_, t.spec, gated) > 0) return;
    int discarded = 0;
    if (!t.queue.PublishHead(head.grasp, head.max_queue, c.seq, &discarded, head.next ? &*head.next : nullptr)) {
      return;
    }
    if (discarded > 0) grasps_discarded_.fetch_add(static_cast<uint64_t>(discarded), std::memory_order_relaxed);
    std::function<void()> ready;
    {
      std::lock_guard lock(t.mutex);
      for (auto it = t.waiters.begin(); it != t.waiters.end() && it->first <= c.seq; ++it) {
        if (it->second.takes_head) {
          ready = std::move(it->second.ready);
          t.waiters.erase(it);
          break;
        }
      }
      if (!ready) t.head_open_seq = c.seq;
    }
    spdlog::debug("daoai: task {} detection {}: head (part {}) queued early, {}", t.spec.id, c.seq,
                  head.grasp.instance_id, ready ? "answering the robot waiting longest" : "for the next pick pose");
    if (ready) {
      first_poses_early_.fetch_add(1, std::memory_order_relaxed);
      ready();
    }
  } catch (...) {
    // The full plan still fills the queue and answers the waiting robots.
    spdlog::error("daoai: task {}: publishing the first grasp early threw: {}", t.spec.id, ExceptionText());
  }
}

void RequestHandler::Impl::HandOut(TaskState& t, const GraspQueue::Popped& p,
                                   ClientContext* client) {
  if (client == nullptr || !client->settle_after_write) {
    Received(t, *p.grasp, client);
    TellHandedOut(t, *p.grasp);
    return;
  }
  if (client->settle) std::exchange(client->settle, nullptr)(true);  // left unsettled
  client->settle = [this, &t, p, client](bool written) {
    // Runs on the transport's thread (a write's completion): nothing may
    // escape it.
    try {
      if (written) Received(t, *p.grasp, client);
    } catch (...) {
      spdlog::error("daoai: task {}: remembering the grasp handed out threw: {}", t.spec.id,
                    ExceptionText());
    }
    Settle(t, p, written);
  };
}

void RequestHandler::Impl::TellHandedOut(const TaskState& t, const Grasp& g) noexcept {
  try {
    planner_->NotifyHandedOut(t.spec, g);
  } catch (...) {
    // The robot has the grasp whatever the planner's bookkeeping did.
    const uint64_t n = planner_failures_.fetch_add(1, std::memory_order_relaxed) + 1;
    spdlog::error("daoai: task {}: the planner threw when told of the grasp on instance {} handed out "
                  "({}); it counts as handed out ({} planner failures since start)", t.spec.id,
                  g.instance_id, ExceptionText(), n);
  }
}

void RequestHandler::Impl::Settle(TaskState& t, const GraspQueue::Popped& p, bool written) noexcept {
  if (written) {
    TellHandedOut(t, *p.grasp);
    return;
  }
  const int instance = p.grasp->instance_id;
  const size_t withdrawn = p.withdrawn.size();
  bool restored = false;
  try {
    restored = t.queue.Restore(p);
  } catch (...) {
    spdlog::error("daoai: task {}: putting the grasp back threw: {}", t.spec.id, ExceptionText());
  }
  if (restored) {
    const uint64_t n = grasps_requeued_.fetch_add(1, std::memory_order_relaxed) + 1;
    spdlog::warn("daoai: task {}: the answer carrying the grasp on instance {} was not written; "
                 "the grasp (and the {} withdrawn with it) is back in the queue where it was ({} "
                 "since start)", t.spec.id, instance, withdrawn, n);
  } else {
    const uint64_t n = grasps_superseded_.fetch_add(1, std::memory_order_relaxed) + 1;
    spdlog::warn("daoai: task {}: the answer carrying the grasp on instance {} was not written "
                 "and a later detection replaced the queue: dropped ({} since start)",
                 t.spec.id, instance, n);
  }
}

Reply RequestHandler::Impl::PickReply(TaskState& t, WireFormat f, ClientContext* client) {
  return [this, &t, f, client]() -> std::optional<Response> {
    // The answer for a grasp, as the robot will read it; OutOfRange when a
    // field does not fit the wire (int32, or the transport's range).
    // DROP_OFF_POSE only where seed 000 defines it (its place task); seed
    // 003's in_hand and place_area answers are OBJECTS_FOUND (docs/protocols.md "Task kinds").
    const int32_t found =
        t.spec.kind == TaskSpec::Kind::kPlace ? daoai::kDropOffPose : daoai::kObjectsFound;
    auto answer_for = [&](const Grasp& g, int remaining) -> Result<Response> {
      Response r = Base(found, f);
      if (Status s = EncodePose(g.X_BT, f, r); !s.ok()) return s;
      const Result<int32_t> left = ToFixed(remaining);
      if (!left.ok()) return left.status();
      const Result<int32_t> klass = ToFixed(g.class_id);
      if (!klass.ok()) return klass.status();
      r.payload[0] = *left;
      r.payload[1] = *klass;
      return f.range ? f.range(r) : Result<Response>(r);
    };
    // Encoded and range-checked before the grasp leaves the queue: a grasp
    // that cannot be sent stays queued (another robot, or a later plan, may
    // use it); the next one that can is handed out.
    std::optional<Response> answer;
    Status refusal;
    const GraspQueue::Popped p = t.queue.PopFirst([&](const Grasp& g, int remaining) {
      // An encoder or range check that throws refuses the grasp like one
      // that does not fit: it stays queued (the queue is untouched until
      // this returns true).
      Result<Response> r = Guard("encoding the answer", [&] { return answer_for(g, remaining); });
      if (!r.ok()) {
        if (refusal.ok()) refusal = r.status();
        return false;
      }
      answer = *r;
      return true;
    });
    if (p.refused > 0) {
      spdlog::error("daoai: task {}: {} grasp(s) cannot be sent to this robot ({}); they stay queued",
                    t.spec.id, p.refused, refusal.ToString());
    }
    if (p.grasp) {
      try {
        HandOut(t, p, client);
      } catch (...) {
        // Popped, not handed out (no memory for its reservation): back in
        // the queue, and the robot is answered with an error.
        spdlog::error("daoai: task {}: handing out a grasp threw: {}", t.spec.id, ExceptionText());
        Settle(t, p, /*written=*/false);
        return Base(daoai::kUnknownCommand, f);
      }
      return answer;
    }
    if (p.refused > 0) return Base(daoai::kUnknownCommand, f);  // every seed program stops on it
    // Nothing to hand out: say why, in the dialect's vocabulary.
    int32_t status = daoai::kNoObjectFound;
    if (p.outcome == PlanResult::Outcome::kPlannerFailed) {
      // An error, not "no objects": payload_1 0 ends seed 000's
      // daoai_get_picking_pose() (returns False) without the robot taking
      // the bin for empty.
      status = daoai::kUnknownCommand;
    } else if (!p.outcome || *p.outcome == PlanResult::Outcome::kCaptureFailed) {
      status = f.v1() ? daoai::kNoImageCaptured : daoai::kNoObjectFound;
    } else if (*p.outcome == PlanResult::Outcome::kNoCollisionFree) {
      status = f.v1() ? daoai::kNoObjectFound : daoai::kNoCollisionFreePose;
    }
    return Base(status, f);
  };
}

RequestHandler::Completion RequestHandler::Impl::InRange(const Request& req, const WireFormat& f,
                                                         Completion done) const {
  if (!f.range) return done;
  return [this, command = req.command, f, done = std::move(done)](Reply reply) {
    if (!reply) {
      done(std::move(reply));
      return;
    }
    done([this, command, f, reply = std::move(reply)]() -> std::optional<Response> {
      std::optional<Response> r = reply();
      if (!r) return r;
      Result<Response> sent = Guard("the link's range check", [&] { return f.range(*r); });
      if (sent.ok()) return *sent;
      spdlog::error("daoai: the answer to command {} does not fit this robot's link ({}); "
                    "answering UNKNOWN_COMMAND", command, sent.status().ToString());
      Response refused = Base(daoai::kUnknownCommand, f);  // the robot's own pose where it moves to
      refused.meta_2 = r->meta_2;
      // Its fields came from the robot through this link, so they fit; but
      // never leave the robot without an answer.
      Result<Response> fallback = Guard("the link's range check", [&] { return f.range(refused); });
      return fallback.ok() ? *fallback : Base(daoai::kUnknownCommand, r->meta_2);
    });
  };
}

void RequestHandler::Impl::AutoView(CalibrationKind kind, const Pose& X_BF,
                                    const std::function<void(int32_t, const std::optional<Pose>&)>& answer) {
  const bool two_d = kind == CalibrationKind::kAuto2D;
  const int32_t mode = two_d ? daoai::kMode2DAutoCalibration : daoai::kModeAutoCalibration;
  const int32_t finished = two_d ? daoai::kDone2DAutoCalibration : daoai::kDoneCalibration;
  if (calibration_mode_ != kind) {
    spdlog::warn("daoai: {} accumulate outside its auto calibration", two_d ? "2D" : "3D");
    answer(daoai::kUnknownCommand, std::nullopt);
    return;
  }
  const Result<CalibrationStep> step = calibration_->Accumulate(kind, X_BF);
  const bool failed = !step.ok() || !step->good;
  failed_views_in_a_row_ = failed ? failed_views_in_a_row_ + 1 : 0;
  if (!step.ok()) {
    spdlog::warn("daoai: calibration view not used ({} in a row): {}", failed_views_in_a_row_,
                 step.status().ToString());
  }
  const bool complete = step.ok() && step->done;
  // A planned view the robot cannot reach is never sent (docs/protocols.md
  // "Poses the robot moves to"): the calibration ends there as after failed
  // views, with DONE, the one status the seed's loop leaves on.
  const std::optional<Pose> next = step.ok() && !complete ? step->next_X_BF : std::nullopt;
  const Status reachable = next ? CheckWorkspace(cell_.robot, *next) : Status::Ok();
  if (complete || failed_views_in_a_row_ >= kMaxFailedViewsInARow || !reachable.ok()) {
    if (!reachable.ok()) {
      spdlog::error("daoai: the calibration's next planned view is not sent: {}; ending the "
                    "calibration with the views it has", reachable.message());
    } else if (!complete) {
      spdlog::error("daoai: {} calibration views in a row failed; ending the calibration with the "
                    "views it has", failed_views_in_a_row_);
    }
    const Status s = calibration_->Finish(kind);
    if (!s.ok()) spdlog::error("daoai: calibration failed: {}", s.ToString());
    calibration_mode_.reset();
    answer(finished, std::nullopt);
    return;
  }
  // A failed view is skipped: the next planned pose, or the robot's own
  // when nothing is planned yet (the start view: it tries again there).
  answer(mode, next);
}

void RequestHandler::Impl::Calibrate(const Request& req, const std::optional<Pose>& pose,
                                     const WireFormat& f, Completion done) {
  const int32_t command = req.command;
  if (!pose && command != daoai::kStopManualCalibration) {
    // A calibration step without a usable robot pose would poison the data.
    spdlog::warn("daoai: calibration command {} with an undecodable robot pose; rejected", command);
    if (command == daoai::kGuidanceCalibration) {
      done(f.v1() ? Respond(Base(daoai::kGuidanceBad, f)) : NoResponse());
    } else {
      done(Respond(Base(daoai::kUnknownCommand, f)));
    }
    return;
  }
  const Pose X_BF = pose.value_or(Pose::Identity());
  auto shared_done = std::make_shared<Completion>(std::move(done));
  const bool posted = serial_.Post([this, command, X_BF, f, shared_done] {
    // Called at most once: a step that throws after answering is not
    // answered twice.
    const Completion done = [shared_done](Reply reply) {
      if (Completion d = std::exchange(*shared_done, nullptr)) d(std::move(reply));
    };
    try {
      RunCalibrationCommand(command, X_BF, f, done);
    } catch (...) {
      // The calibration service threw (it must not): the calibration ends;
      // the robot restarts the handshake on the error.
      const uint64_t n = answer_failures_.fetch_add(1, std::memory_order_relaxed) + 1;
      spdlog::error("daoai: calibration command {} threw ({}); the calibration ends ({} answers failed "
                    "since start)", command, ExceptionText(), n);
      calibration_mode_.reset();
      done(ReadsAnAnswer(command, f.v1()) ? Respond(Base(daoai::kUnknownCommand, f)) : NoResponse());
    }
  });
  if (!posted) {
    CountRefusedJob("a calibration step");
    (*shared_done)(Respond(Base(daoai::kUnknownCommand, f)));
  }
}

void RequestHandler::Impl::RunCalibrationCommand(int32_t command, const Pose& X_BF, const WireFormat& f,
                                           const Completion& done) {
  // A planned pose, or (none given, or it does not fit the link) the
  // robot's own where the robot moves to the answer (Base).
  auto answer = [&](int32_t status, const std::optional<Pose>& planned = std::nullopt) {
    Response r = Base(status, f);
    if (planned) {
      Response with = r;
      Status s = EncodePose(*planned, f, with);
      if (s.ok() && f.range) s = f.range(with).status();
      if (s.ok()) {
        r = with;
      } else {
        spdlog::error("daoai: planned calibration pose does not fit the link ({}); answering the "
                      "robot's own pose", s.ToString());
      }
    }
    done(Respond(r));
  };
  auto start = [&](CalibrationKind kind) { return StartCalibration(kind, X_BF); };
  auto accumulate = [&](CalibrationKind kind) { return AccumulateCalibration(kind, X_BF); };
  switch (command) {
    case daoai::kStartManualCalibration:
      answer(start(CalibrationKind::kManual) ? daoai::kModeCalibration : daoai::kUnknownCommand);
      return;
    case daoai::kManualAccumulatePose: {
      // Not in manual mode: the robot restarts the handshake on any other status.
      if (calibration_mode_ != CalibrationKind::kManual) {
        spdlog::warn("daoai: manual accumulate outside manual calibration");
        answer(daoai::kUnknownCommand);
        return;
      }
      const auto step = accumulate(CalibrationKind::kManual);
      answer(!step ? daoai::kUnknownCommand
                   : step->done ? daoai::kDoneCalibration : daoai::kModeCalibration);
      return;
    }
    case daoai::kStopManualCalibration: {
      if (calibration_mode_ == CalibrationKind::kManual) {
        const Status s = calibration_->Finish(CalibrationKind::kManual);
        if (!s.ok()) spdlog::error("daoai: manual calibration failed: {}", s.ToString());
      } else {
        spdlog::warn("daoai: stop manual calibration outside manual calibration");
      }
      calibration_mode_.reset();
      // Seed 004 acknowledges with UNKNOWN_COMMAND; seed 000's
      // daoai_stop_manual_calibration reads no answer.
      if (f.v1()) {
        answer(daoai::kUnknownCommand);
      } else {
        done(NoResponse());
      }
      return;
    }
    case daoai::kStartAutoCalibration:
      // The robot stays where it is (its own pose) for the first view.
      answer(start(CalibrationKind::kAuto) ? daoai::kModeAutoCalibration : daoai::kUnknownCommand);
      return;
    case daoai::kAutoAccumulatePose:
      AutoView(CalibrationKind::kAuto, X_BF, answer);
      return;
    case daoai::kGuidanceCalibration: {
      // Each request is one pose; the first starts a guidance calibration.
      if (calibration_mode_ != CalibrationKind::kGuidance && !start(CalibrationKind::kGuidance)) {
        if (f.v1()) answer(daoai::kGuidanceBad); else done(NoResponse());
        return;
      }
      const auto step = accumulate(CalibrationKind::kGuidance);
      if (!f.v1()) {
        done(NoResponse());  // seed 000: daoai_guidance_accumulate_calibration reads no answer
        return;
      }
      answer(!step || !step->good ? daoai::kGuidanceBad
             : step->done         ? daoai::kDoneGuidanceCalibration
                                  : daoai::kGuidanceGood);
      return;
    }
    case daoai::kStart2DAutoCalibration:
      answer(start(CalibrationKind::kAuto2D) ? daoai::kMode2DAutoCalibration : daoai::kUnknownCommand);
      return;
    case daoai::kAutoAccumulate2DPose:
      AutoView(CalibrationKind::kAuto2D, X_BF, answer);
      return;
    default:
      answer(daoai::kUnknownCommand);
  }
}

bool RequestHandler::Impl::StartCalibration(CalibrationKind kind, const Pose& X_BF) {
  failed_views_in_a_row_ = 0;
  const Status s = calibration_->Start(kind, X_BF);
  if (!s.ok()) {
    spdlog::error("daoai: calibration start failed: {}", s.ToString());
    calibration_mode_.reset();
    return false;
  }
  calibration_mode_ = kind;
  return true;
}

std::optional<CalibrationStep> RequestHandler::Impl::AccumulateCalibration(CalibrationKind kind, const Pose& X_BF) {
  Result<CalibrationStep> step = calibration_->Accumulate(kind, X_BF);
  if (!step.ok()) {
    spdlog::warn("daoai: calibration pose not accumulated: {}", step.status().ToString());
    return std::nullopt;
  }
  if (step->done) {
    const Status s = calibration_->Finish(kind);
    if (!s.ok()) spdlog::error("daoai: calibration failed: {}", s.ToString());
    calibration_mode_.reset();
  }
  return *step;
}

Response RequestHandler::Impl::EmptyBoxCheck(TaskState& t, const PlanRequest& plan_request) {
  const auto t0 = std::chrono::steady_clock::now();
  DetectionEvent event;
  event.task_id = t.spec.id;
  event.request = plan_request;
  event.time = std::chrono::system_clock::now();
  event.queued = false;  // the empty-box check leaves the queue alone
  Result<CaptureHandle> scene = Status::Unavailable("not captured");
  {
    std::lock_guard lock(capture_mutex_);
    scene = Guard("capture", [&] { return planner_->Capture(plan_request); });
  }
  const auto t1 = std::chrono::steady_clock::now();
  event.capture_ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
  if (scene.ok() && *scene) event.scene = *scene;
  event.capture_status = !scene.ok() ? scene.status()
                         : *scene    ? Status::Ok()
                                     : Status::Internal("planner returned no scene");
  if (!event.capture_status.ok()) {
    event.plan_status = event.capture_status;
    NotifyDetection(event);
  }
  if (!scene.ok() || !*scene) {
    // No image, no evidence that the box is empty: say not empty.
    spdlog::warn("daoai: task {} empty-box check could not capture: {}; answering "
                 "BOX_NOT_EMPTY", t.spec.id, scene.status().ToString());
    return Base(daoai::kBoxNotEmpty, cell_.robot.protocol_version);
  }
  Result<PlanResult> plan = Guard("detection", [&] { return planner_->Plan(plan_request, **scene); });
  if (!observers_.empty()) {
    event.plan_status = plan.status();
    if (plan.ok()) event.plan = *plan;
    event.plan_ms = std::chrono::duration<double, std::milli>(
                        std::chrono::steady_clock::now() - t1).count();
    NotifyDetection(event);
  }
  if (!plan.ok()) {
    spdlog::warn("daoai: task {} empty-box check failed: {}; answering BOX_NOT_EMPTY",
                 t.spec.id, plan.status().ToString());
    return Base(daoai::kBoxNotEmpty, cell_.robot.protocol_version);
  }
  const EmptyBoxRule& rule = t.spec.empty_box;
  const int64_t points = EmptyBoxPoints(rule, plan->roi_points, plan->largest_region_points);
  const bool empty = IsBoxEmpty(rule, *plan);
  spdlog::info("daoai: task {} empty-box check: {} points (threshold {} at {} pixels), {} "
               "detections: {}", t.spec.id, points, EffectiveThreshold(rule, plan->image_pixels),
               plan->image_pixels, plan->detections, empty ? "EMPTY" : "NOT EMPTY");
  Response r = Base(empty ? daoai::kBoxEmpty : daoai::kBoxNotEmpty, cell_.robot.protocol_version);
  // binpick extension (docs/protocols.md "Empty box (40)"): the fill level
  // in payload_4..6 (x MULT): mean and max height over the floor (m) and
  // the occupied share of the floor (0..1). The seeds read the status only.
  if (const std::optional<FillLevel>& fill = plan->fill) {
    const double fields[3] = {fill->mean_height, fill->max_height, fill->occupied_fraction};
    for (int i = 0; i < 3; ++i) {
      if (const Result<int32_t> v = ToFixed(fields[i]); v.ok()) r.payload[3 + i] = *v;
    }
  }
  return r;
}

Response RequestHandler::Impl::PrecisionCheck(const PlanRequest& plan_request) {
  Result<double> error_mm = Status::Unavailable("not run");
  {
    std::lock_guard lock(capture_mutex_);
    error_mm = Guard("precision check", [&] { return planner_->CheckPrecision(plan_request); });
  }
  Result<int32_t> fixed = error_mm.ok() ? ToFixed(*error_mm) : Result<int32_t>(error_mm.status());
  if (!fixed.ok()) {
    spdlog::warn("daoai: task {} precision check failed: {}", plan_request.task.id,
                 fixed.status().ToString());
    return Base(daoai::kPrecisionCheckFail, cell_.robot.protocol_version);
  }
  Response r = Base(daoai::kPrecisionCheckSuccess, cell_.robot.protocol_version);
  r.payload[0] = *fixed;
  return r;
}

void RequestHandler::Impl::PostCheck(TaskState& t, CheckLane TaskState::*lane, PlanRequest request,
                                     Completion done, Check check) {
  {
    std::lock_guard lock(t.mutex);
    CheckLane& l = t.*lane;
    if (l.running) {
      l.pending = std::move(request);  // the latest robot pose wins
      l.pending_done.push_back(std::move(done));
      return;
    }
    l.running = true;
  }
  std::vector<Completion> batch;
  batch.push_back(std::move(done));
  StartCheck(t, lane, std::move(request), std::move(batch), std::move(check));
}

void RequestHandler::Impl::StartCheck(TaskState& t, CheckLane TaskState::*lane, PlanRequest request,
                                      std::vector<Completion> done, Check check) {
  std::shared_ptr<CheckJob> job;
  try {
    job = std::make_shared<CheckJob>();
    job->request = std::move(request);
    job->done = std::move(done);
    job->check = check;
    Spawn([this, &t, lane, job] { RunCheck(t, lane, *job); });
  } catch (...) {
    planner_failures_.fetch_add(1, std::memory_order_relaxed);
    spdlog::error("daoai: task {}: the {} could not be started ({}); answering {}", t.spec.id, check.what,
                  ExceptionText(), check.failed);
    FinishCheck(t, lane, check, Respond(Base(check.failed, cell_.robot.protocol_version)),
                job ? job->done : done);
  }
}

void RequestHandler::Impl::RunCheck(TaskState& t, CheckLane TaskState::*lane, const CheckJob& job) {
  Reply reply;
  try {
    reply = Respond(job.check.run(job.request));
  } catch (...) {
    const uint64_t n = planner_failures_.fetch_add(1, std::memory_order_relaxed) + 1;
    spdlog::error("daoai: task {}: the {} threw ({}); answering {} ({} failed detections since start)",
                  t.spec.id, job.check.what, ExceptionText(), job.check.failed, n);
    reply = Respond(Base(job.check.failed, cell_.robot.protocol_version));
  }
  FinishCheck(t, lane, job.check, reply, job.done);
}

void RequestHandler::Impl::FinishCheck(TaskState& t, CheckLane TaskState::*lane, const Check& check,
                                       const Reply& reply, const std::vector<Completion>& done) {
  std::optional<PlanRequest> next;
  std::vector<Completion> next_done;  // dropped unanswered when shutting down
  {
    std::lock_guard lock(t.mutex);
    CheckLane& l = t.*lane;
    next.swap(l.pending);
    next_done.swap(l.pending_done);
    if (!next || stopping_) {
      l.running = false;
      next.reset();
    }
  }
  if (next) StartCheck(t, lane, std::move(*next), std::move(next_done), check);
  for (const Completion& d : done) {
    try {
      d(reply);
    } catch (...) {
      spdlog::error("daoai: task {}: answering a {} threw: {}", t.spec.id, check.what, ExceptionText());
    }
  }
}

void RequestHandler::Impl::RefuseChange(const Request& req, const ClientContext& client,
                                        const WireFormat& f, Completion done) {
  changes_refused_.fetch_add(1, std::memory_order_relaxed);
  // The command's own failure where it has one; no answer where the robot
  // reads none (a reply it does not read would shift every later one).
  const bool answered = ReadsAnAnswer(req.command, f.v1());
  const int32_t status = req.command == daoai::kSwitchConfig        ? daoai::kSwitchConfigFail
                         : req.command == daoai::kGuidanceCalibration ? daoai::kGuidanceBad
                                                                      : daoai::kUnknownCommand;
  spdlog::warn("daoai: {} may not change the cell (not in the config allowlist): command {} "
               "refused{}", client.peer, req.command,
               answered ? ", answered " + std::to_string(status) : std::string(", not answered"));
  done(answered ? Respond(Base(status, f)) : NoResponse());
}

void RequestHandler::Impl::HandleContained(const Request& req, ClientContext& client,
                                           Completion done) noexcept {
  std::shared_ptr<std::atomic<bool>> answered;
  try {
    answered = std::make_shared<std::atomic<bool>>(false);
    HandleAsync(req, client, [answered, done](Reply reply) {
      if (!answered->exchange(true)) done(std::move(reply));
    });
    return;
  } catch (...) {
    const uint64_t n = answer_failures_.fetch_add(1, std::memory_order_relaxed) + 1;
    spdlog::error("daoai: handling command {} from {} threw ({}); {} ({} answer failures since start)",
                  req.command, client.peer, ExceptionText(),
                  answered && answered->load() ? "it was answered already" : "answering UNKNOWN_COMMAND", n);
  }
  if (answered && answered->exchange(true)) return;  // answered before it threw
  try {
    done(ReadsAnAnswer(req.command, cell_.robot.dialect == DaoaiDialect::kSocketV1)
             ? Respond(ErrorAnswer(req))
             : NoResponse());
  } catch (...) {
    spdlog::error("daoai: answering command {} from {} after its handling threw threw too: {}", req.command,
                  client.peer, ExceptionText());
  }
}

void RequestHandler::Impl::HandleAsync(const Request& req, ClientContext& client,
                                       Completion done) {
  ++client.requests;
  // A reservation the transport never settled: the robot asks again, so it
  // had its answer (the rule before settle_after_write existed).
  if (client.settle) std::exchange(client.settle, nullptr)(true);
  if (stopping_) return;  // shutting down: completions are dropped
  std::shared_ptr<AnswerEvent> answer_event;
  done = Observed(req, client, answer_event, std::move(done));
  WireFormat f;
  f.dialect = cell_.robot.dialect;
  f.position_scale = cell_.robot.position_scale;
  f.range = client.wire_range;
  if (MovesTo(req.command)) f.own_pose.emplace(req.position, req.orientation);
  done = InRange(req, f, std::move(done));
  done = Contained(req, f, std::move(done));

  if (!ReadHeader(req, client, f, done)) return;
  const std::optional<Pose> X_BF = RecordPose(req, f, client, answer_event.get());
  TaskState* task = nullptr;
  if (!ResolveTask(req, client, f, done, &task)) return;
  if (ChangesTheCell(req.command) && !client.may_change_cell) {
    RefuseChange(req, client, f, std::move(done));
    return;
  }

  fault::Hit("daoai.handle");  // tests: throws inside HandleAsync, its answer not given yet
  Dispatch(req, client, f, X_BF, task, std::move(done));
  fault::Hit("daoai.handled");  // tests: throws after the request was answered or its work started
}

std::optional<Grasp> RequestHandler::Impl::TakeLastGrasp(ClientContext& client, TaskState& t) {
  std::optional<Grasp> g;
  if (auto it = client.last_grasps.find(t.spec.id); it != client.last_grasps.end()) {
    g = std::move(it->second);
    client.last_grasps.erase(it);
  }
  std::lock_guard lock(t.mutex);
  if (!g) {
    g = std::move(t.last_handed_out);
  } else if (t.last_handed_out && t.last_handed_out->instance_id == g->instance_id &&
             t.last_handed_out->X_BT.isApprox(g->X_BT)) {
    t.last_handed_out.reset();  // the same hand-out: blamed once
  }
  return g;
}

void RequestHandler::Impl::ReportPickFailure(const Request& req, ClientContext& client, const WireFormat& f,
                                             TaskState& t, Completion done) {
  auto refuse = [&](const std::string& why) {
    const uint64_t n = pick_failures_refused_.fetch_add(1, std::memory_order_relaxed) + 1;
    spdlog::warn("daoai: {} reported a failed pick on task {} (reason {}): {}; answering UNKNOWN_COMMAND ({} "
                 "refused since start)", client.peer, t.spec.id, req.payload_2, why, n);
    done(Respond(Base(daoai::kUnknownCommand, f)));
  };
  PickFailure reason = PickFailure::kUnspecified;
  if (!t.failed) return refuse("task " + std::to_string(t.spec.id) + " is not a pick task");
  if (!PickFailureFromWire(req.payload_2, &reason)) {
    return refuse("payload_2 must be 0 (unspecified), 1 (vacuum not built) or 2 (slipped)");
  }
  const std::optional<Grasp> g = TakeLastGrasp(client, t);
  if (!g) return refuse("no grasp of the task was handed out since the last report");
  const FailedPicks::Recorded recorded = t.failed->Report(*g, reason);
  const int withdrawn = t.queue.Rescreen();
  pick_failures_.fetch_add(1, std::memory_order_relaxed);
  spdlog::info("daoai: {} reports grasp {} on part {} (class {}) of task {} failed ({}): failure {} on that spot{}; "
               "{} queued grasp(s) withdrawn", client.peer, g->name, g->instance_id, g->class_id, t.spec.id,
               ToString(reason), recorded.failures, recorded.refused ? ", no more picks there" : "", withdrawn);
  if (!observers_.empty()) {
    PickFailureEvent e;
    e.task_id = t.spec.id;
    e.client_id = client.id;
    e.peer = client.peer;
    e.grasp = *g;
    e.reason = reason;
    e.failures_on_spot = recorded.failures;
    e.refused = recorded.refused;
    e.withdrawn = withdrawn;
    e.time = std::chrono::system_clock::now();
    Notify("OnPickFailure", [&](ServerObserver& o) { o.OnPickFailure(e); });
  }
  Response r = Base(daoai::kPickFailureNoted, f);
  r.payload[0] = recorded.refused ? static_cast<int32_t>(kMult) : 0;
  done(Respond(r));
}

// The message's header: meta_2 (echoed) and meta_1 (the orientation
// convention) into `f`. @returns false when the request is answered
// UNKNOWN_COMMAND for it (`done` called).
bool RequestHandler::Impl::ReadHeader(const Request& req, ClientContext& client, WireFormat& f,
                                      const Completion& done) const {
  // meta_2 is 1 or 2 (both seeds' programs send 1, seed 000's text says 2)
  // and is echoed; anything else is garbage (or a misaligned stream): answer
  // UNKNOWN_COMMAND. The rules follow the cell's dialect, not meta_2.
  if (req.meta_2 != 1 && req.meta_2 != 2) {
    spdlog::warn("daoai: {} sent protocol version (meta_2) {} (command {}); expected 1 or 2; "
                 "answering UNKNOWN_COMMAND", client.peer, req.meta_2, req.command);
    f.meta_2 = cell_.robot.protocol_version;
    done(Respond(Base(daoai::kUnknownCommand, f)));
    return false;
  }
  f.meta_2 = req.meta_2;
  // meta_1 selects the orientation convention of both directions.
  const std::optional<RobotModel> model = FindRobotModel(static_cast<RobotType>(req.meta_1));
  if (!model) {
    spdlog::warn("daoai: {} sent unknown robot type (meta_1) {} (command {}); answering "
                 "UNKNOWN_COMMAND", client.peer, req.meta_1, req.command);
    done(Respond(Base(daoai::kUnknownCommand, f)));
    return false;
  }
  if (model->type != cell_.robot.model.type && !client.warned_meta_1) {
    client.warned_meta_1 = true;
    spdlog::warn("daoai: {} says it is a {} robot (meta_1 {}) but the cell is configured for {} "
                 "(meta_1 {}); answering in the {} convention with the cell's meta_1",
                 client.peer, ToString(model->type), req.meta_1, ToString(cell_.robot.model.type),
                 static_cast<int>(cell_.robot.model.type), ToString(model->convention));
  }
  f.convention = model->convention;
  // meta_1 99 ("other") says only that the robot has no id of its own; the
  // cell names which one it is (Adept, Kawasaki, Comau, Syntec, Turin).
  if (model->type == RobotType::kOther && cell_.robot.model.type == RobotType::kOther) {
    f.convention = cell_.robot.model.convention;
  }
  return true;
}

// Every message carries the robot pose: recorded on `client` (status page,
// liveness, eye-in-hand captures, calibration, teaching) when it decodes.
std::optional<Pose> RequestHandler::Impl::RecordPose(const Request& req, const WireFormat& f, ClientContext& client,
                                                     AnswerEvent* answer_event) const {
  std::optional<Pose> X_BF;
  if (Result<Pose> decoded = DecodePose(req, f); decoded.ok()) {
    X_BF = *decoded;
    client.X_BF = X_BF;
    client.pose_time = std::chrono::system_clock::now();
    if (answer_event) answer_event->X_BF = X_BF;
  } else {
    spdlog::debug("daoai: {} sent an undecodable pose: {}", client.peer,
                  decoded.status().ToString());
  }
  return X_BF;
}

// The task payload_1 names, for the commands that need one (null for the
// others); remembered on `client`. @returns false when the task is unknown
// (answered UNKNOWN_COMMAND: `done` called).
bool RequestHandler::Impl::ResolveTask(const Request& req, ClientContext& client, const WireFormat& f,
                                       const Completion& done, TaskState** out) {
  *out = nullptr;
  if (NeedsTask(req.command)) {
    auto it = tasks_.find(req.payload_1);
    if (it == tasks_.end()) {
      spdlog::warn("daoai: {} named unknown task id {} (payload_1) with command {}; answering "
                   "UNKNOWN_COMMAND", client.peer, req.payload_1, req.command);
      done(Respond(Base(daoai::kUnknownCommand, f)));
      return false;
    }
    TaskState* task = it->second.get();
    client.last_task_id = task->spec.id;
    if (IsPickTask(task->spec) && (req.command == daoai::kCaptureAndProcessAsync ||
                                   req.command == daoai::kCaptureAndProcess ||
                                   req.command == daoai::kPickPose)) {
      client.last_pick_task_id = task->spec.id;
    }
    *out = task;
  }
  return true;
}

// Teach (30): no response. The pose is the robot's tool pose (what it
// sends); the planner stores it on the calibration and teach sequence.
void RequestHandler::Impl::TeachPose(const Request& req, const ClientContext& client, const std::optional<Pose>& X_BF,
                                     Completion done) {
  if (!X_BF) {
    spdlog::warn("daoai: {} sent a teach pose that could not be decoded; ignored", client.peer);
    done(NoResponse());
    return;
  }
  const TaskState* taught = TeachTask(req, client);
  if (taught == nullptr) {
    spdlog::warn("daoai: {} sent a teach pose, but payload_1 {} names no pick task and the "
                 "connection has picked on none; ignored", client.peer, req.payload_1);
    done(NoResponse());
    return;
  }
  TeachRequest teach{taught->spec, *X_BF};
  done(NoResponse());
  const bool posted = serial_.Post([this, teach] {
    const Status s = Guard("teach", [&] { return planner_->Teach(teach); });
    if (s.ok()) {
      spdlog::info("daoai: taught a grasp for task {}", teach.task.id);
    } else {
      spdlog::warn("daoai: teach for task {} not stored: {}", teach.task.id, s.ToString());
    }
  });
  if (!posted) CountRefusedJob("a teach pose");
}

// Answers a request whose header, pose and task HandleAsync has read.
void RequestHandler::Impl::Dispatch(const Request& req, ClientContext& client, const WireFormat& f,
                                    const std::optional<Pose>& X_BF, TaskState* task, Completion done) {
  switch (req.command) {
    case daoai::kNoCommand:
      done(NoResponse());
      return;

    case daoai::kStartManualCalibration:
    case daoai::kStopManualCalibration:
    case daoai::kManualAccumulatePose:
    case daoai::kStartAutoCalibration:
    case daoai::kAutoAccumulatePose:
    case daoai::kGuidanceCalibration:
    case daoai::kStart2DAutoCalibration:
    case daoai::kAutoAccumulate2DPose:
      Calibrate(req, X_BF, f, std::move(done));
      return;

    case daoai::kCaptureAndProcessAsync:
      // Answer at once; capture and detect in the background.
      done(Respond(Base(daoai::kDetection, f)));
      RequestDetection(*task, MakePlanRequest(*task, X_BF), nullptr);
      return;

    case daoai::kCaptureAndProcess: {
      // Answer when the image is captured, not when detection ends.
      auto on_captured = [this, f, done = std::move(done)](bool ok) {
        done(Respond(Base(ok ? daoai::kDetection : daoai::kCaptureFail, f)));
      };
      RequestDetection(*task, MakePlanRequest(*task, X_BF), std::move(on_captured));
      return;
    }

    case daoai::kPickPose: {
      // Answered from the newest detection requested before it (at most the
      // one running and the one pending after it), never behind a flood.
      std::function<void()> answer = [done = std::move(done), reply = PickReply(*task, f, &client)] {
        done(reply);
      };
      if (!WaitForDetection(*task, answer, /*takes_head=*/true)) answer();
      return;
    }

    case daoai::kSendPose:
      TeachPose(req, client, X_BF, std::move(done));
      return;

    case daoai::kCheckEmptyBox:
      PostCheck(*task, &TaskState::empty_box, MakePlanRequest(*task, X_BF), EchoMeta2(f, std::move(done)),
                {"empty-box check", daoai::kBoxNotEmpty,
                 [this, task](const PlanRequest& r) { return EmptyBoxCheck(*task, r); }});
      return;

    case daoai::kPrecisionCheck:
      PostCheck(*task, &TaskState::precision, MakePlanRequest(*task, X_BF), EchoMeta2(f, std::move(done)),
                {"precision check", daoai::kPrecisionCheckFail,
                 [this](const PlanRequest& r) { return PrecisionCheck(r); }});
      return;

    case daoai::kReportPickFailure:
      ReportPickFailure(req, client, f, *task, std::move(done));
      return;

    case daoai::kSwitchConfig: {
      if (cell_.camera.FindConfig(req.payload_1) == nullptr) {
        spdlog::warn("daoai: {} asked for unknown camera config {}", client.peer, req.payload_1);
        done(Respond(Base(daoai::kSwitchConfigFail, f)));
        return;
      }
      camera_config_id_ = req.payload_1;
      spdlog::info("daoai: camera config {} selected", req.payload_1);
      done(Respond(Base(daoai::kSwitchConfigSuccess, f)));
      return;
    }

    default:
      spdlog::warn("daoai: {} sent unknown command {}; answering UNKNOWN_COMMAND", client.peer,
                   req.command);
      done(Respond(Base(daoai::kUnknownCommand, f)));
      return;
  }
}

static Status UnknownTask(int task_id) {
  return Status::NotFound("task " + std::to_string(task_id) + " is not in the cell");
}

Result<RequestHandler::TaskSnapshot> RequestHandler::Impl::Snapshot(int task_id) const {
  TaskState* t = FindTask(task_id);
  if (!t) return UnknownTask(task_id);
  TaskSnapshot s;
  {
    std::lock_guard lock(t->mutex);
    s.in_flight = (t->running ? 1 : 0) + (t->pending ? 1 : 0);
    s.finished = t->finished;
  }
  if (std::optional<GraspQueue::Summary> last = t->queue.LastPlan()) {
    s.outcome = last->outcome;
    s.fill = last->fill;
  }
  s.grasps_left = t->queue.size();
  return s;
}

Status RequestHandler::Impl::StartDetection(int task_id, const std::optional<Pose>& X_BF) {
  TaskState* t = FindTask(task_id);
  if (!t) return UnknownTask(task_id);
  if (stopping_) return Status::Unavailable("the request handler is shutting down");
  RequestDetection(*t, MakePlanRequest(*t, X_BF), nullptr);
  return Status::Ok();
}

Status RequestHandler::Impl::WhenDetected(int task_id, std::function<void()> ready) {
  TaskState* t = FindTask(task_id);
  if (!t) return UnknownTask(task_id);
  if (!WaitForDetection(*t, ready)) ready();
  return Status::Ok();
}

Result<GraspQueue::Popped> RequestHandler::Impl::PopGrasp(int task_id, ClientContext* client,
                                                          const RequestHandler::Sendable& sendable) {
  TaskState* t = FindTask(task_id);
  if (!t) return UnknownTask(task_id);
  GraspQueue::Popped p = sendable ? t->queue.PopFirst(sendable) : t->queue.Pop();
  if (p.grasp) HandOut(*t, p, client);
  return p;
}

RequestHandler::RequestHandler(Cell cell, std::shared_ptr<GraspPlanner> planner,
                               std::unique_ptr<CalibrationService> calibration,
                               RequestHandlerOptions options)
    : impl_(std::make_unique<Impl>(std::move(cell), std::move(planner), std::move(calibration),
                                   options)) {}

RequestHandler::~RequestHandler() = default;

void RequestHandler::AddObserver(std::shared_ptr<ServerObserver> observer) {
  if (observer) impl_->AddObserver(std::move(observer));
}

void RequestHandler::HandleAsync(const Request& request, ClientContext& client, Completion done) {
  impl_->HandleContained(request, client, std::move(done));
}

void RequestHandler::CountAnswerFailure() { impl_->CountAnswerFailure(); }

std::optional<Response> RequestHandler::Handle(const Request& request, ClientContext& client,
                                               const std::function<bool()>& abandon) {
  // The completion owns the promise: called, it sets the Reply; dropped
  // unanswered (shutdown), its destruction breaks the promise. Either way
  // the future becomes ready, so this never waits for a completion that no
  // longer exists.
  auto promise = std::make_shared<std::promise<Reply>>();
  std::future<Reply> future = promise->get_future();
  impl_->HandleContained(request, client, [promise = std::move(promise)](Reply reply) {
    promise->set_value(std::move(reply));
  });
  if (abandon) {
    while (future.wait_for(std::chrono::milliseconds(10)) != std::future_status::ready) {
      // Given up: the Reply, if it comes, is never run (nothing popped).
      if (abandon()) return std::nullopt;
    }
  }
  try {
    Reply reply = future.get();
    return reply ? reply() : std::nullopt;
  } catch (const std::future_error&) {
    return std::nullopt;  // the handler shut down before answering
  }
}

void RequestHandler::Shutdown() { impl_->Shutdown(); }
const Cell& RequestHandler::cell() const { return impl_->cell(); }
int RequestHandler::camera_config_id() const { return impl_->camera_config_id(); }
int RequestHandler::QueueSize(int task_id) const { return impl_->QueueSize(task_id); }
Result<RequestHandler::TaskSnapshot> RequestHandler::Snapshot(int task_id) const {
  return impl_->Snapshot(task_id);
}
Status RequestHandler::StartDetection(int task_id, const std::optional<Pose>& X_BF) {
  return impl_->StartDetection(task_id, X_BF);
}
Status RequestHandler::WhenDetected(int task_id, std::function<void()> ready) {
  return impl_->WhenDetected(task_id, std::move(ready));
}
bool RequestHandler::RunCalibration(std::function<void(CalibrationService&)> job) {
  return impl_->RunCalibration(std::move(job));
}
RequestHandlerStats RequestHandler::stats() const { return impl_->stats(); }
std::vector<FailedPicks::Spot> RequestHandler::FailedSpots(int task_id) const {
  return impl_->FailedSpots(task_id);
}

Result<GraspQueue::Popped> RequestHandler::PopGrasp(int task_id, ClientContext* client,
                                                    const Sendable& sendable) {
  return impl_->PopGrasp(task_id, client, sendable);
}
std::optional<GraspQueue::Contents> RequestHandler::QueueContents(int task_id) const {
  const Impl::TaskState* t = impl_->FindTask(task_id);
  if (t == nullptr) return std::nullopt;
  return t->queue.contents();
}

}  // namespace bp
