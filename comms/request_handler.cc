#include "comms/request_handler.h"

#include <spdlog/spdlog.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <cmath>
#include <deque>
#include <future>
#include <map>
#include <mutex>
#include <thread>
#include <utility>
#include <vector>

#include "core/conventions.h"
#include "grasp/empty_box.h"
#include "grasp/grasp_queue.h"

namespace bp {
namespace {

using daoai::Request;
using daoai::Response;
using Reply = RequestHandler::Reply;
using Completion = RequestHandler::Completion;

Reply NoResponse() {
  return [] { return std::optional<Response>(); };
}

Reply Respond(Response r) {
  return [r] { return std::optional<Response>(r); };
}

bool NeedsTask(int32_t command) {
  switch (command) {
    case daoai::kCaptureAndProcessAsync:
    case daoai::kCaptureAndProcess:
    case daoai::kPickPose:
    case daoai::kCheckEmptyBox:
    case daoai::kPrecisionCheck:
      return true;
    default:
      return false;
  }
}

// How one request is read and answered: the pose encoding (the convention
// meta_1 names, the cell's position unit), the cell's dialect, and the
// request's meta_2, which every answer echoes.
struct WireFormat {
  OrientationConvention convention = OrientationConvention::kAxisAngle;
  double position_scale = 1.0;  // metres per wire unit (before MULT)
  DaoaiDialect dialect = DaoaiDialect::kVisionPilot;
  int32_t meta_2 = 2;
  bool v1() const { return dialect == DaoaiDialect::kSocketV1; }
};

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

// Runs jobs one after another, in submission order, on the arena.
class SerialJobs {
 public:
  explicit SerialJobs(std::function<void(std::function<void()>)> spawn) : spawn_(std::move(spawn)) {}
  void Post(std::function<void()> job) {
    bool start = false;
    {
      std::lock_guard lock(mutex_);
      jobs_.push_back(std::move(job));
      if (!running_) running_ = start = true;
    }
    if (start) spawn_([this] { Drain(); });
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
      job();
    }
  }
  std::function<void(std::function<void()>)> spawn_;
  std::mutex mutex_;
  std::deque<std::function<void()>> jobs_;  // GUARDED_BY(mutex_)
  bool running_ = false;                    // GUARDED_BY(mutex_)
};

}  // namespace

class RequestHandler::Impl {
 public:
  struct TaskState {
    TaskSpec spec;
    GraspQueue queue;
    std::mutex mutex;
    int in_flight = 0;                  // GUARDED_BY(mutex): detections running
    uint64_t finished = 0;              // GUARDED_BY(mutex): detections finished
    std::vector<std::function<void()>> waiters;  // GUARDED_BY(mutex): pick poses waiting
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
    for (auto& [id, t] : tasks_) {
      std::lock_guard lock(t->mutex);
      t->waiters.clear();
    }
  }

  void HandleAsync(const Request& req, ClientContext& client, Completion done);

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
  Status WhenIdle(int task_id, std::function<void()> ready);
  Result<GraspQueue::Popped> PopGrasp(int task_id);
  void RunCalibration(std::function<void(CalibrationService&)> job) {
    serial_.Post([this, job = std::move(job)] {
      calibration_mode_.reset();
      job(*calibration_);
    });
  }

 private:
  // Runs a planner call, turning an exception into Internal: a detection
  // that throws must still finish (answer the capture, release waiting
  // picks), never leave the task in flight forever.
  template <typename F>
  static auto Guard(const char* what, F&& f) -> decltype(f()) {
    try {
      return f();
    } catch (const std::exception& e) {
      return Status::Internal(std::string(what) + " threw: " + e.what());
    } catch (...) {
      return Status::Internal(std::string(what) + " threw");
    }
  }

  // Runs f on the arena (never on the caller's thread). Exceptions must not
  // escape f: they are caught and logged here as a last resort.
  void Spawn(std::function<void()> f) {
    {
      std::lock_guard lock(pending_mutex_);
      ++pending_;
    }
    auto job = std::make_shared<std::function<void()>>(std::move(f));
    auto run = [this, job] {
      try {
        (*job)();
      } catch (const std::exception& e) {
        spdlog::error("daoai: detection worker failed: {}", e.what());
      }
      *job = nullptr;  // release captures before Shutdown may return
      std::lock_guard lock(pending_mutex_);
      --pending_;
      pending_cv_.notify_all();
    };
#if defined(__SANITIZE_THREAD__)
    // The system's libtbb is not instrumented, so ThreadSanitizer cannot see
    // the hand-off through the arena and reports every task as a race. Under
    // TSan, run each job on its own thread instead (same ordering guarantees:
    // none beyond the mutexes above).
    std::thread(run).detach();
#else
    arena_.enqueue(run);
#endif
  }

  // A status-only answer: meta_1 is the cell's robot type, meta_2 the
  // request's version (echoed: the seeds' scripts raise a popup when it
  // differs from their own).
  Response Base(int32_t status, const WireFormat& f) const { return Base(status, f.meta_2); }
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
    return p;
  }

  void StartDetection(TaskState& t, PlanRequest plan_request, std::function<void(bool)> on_captured);
  void FinishDetection(TaskState& t);
  Reply PickReply(TaskState& t, WireFormat f);
  void Calibrate(const Request& req, const std::optional<Pose>& X_BF, const WireFormat& f,
                 Completion done);

  Cell cell_;
  std::shared_ptr<GraspPlanner> planner_;
  std::unique_ptr<CalibrationService> calibration_;  // used from serial_ jobs only
  std::map<int, std::unique_ptr<TaskState>> tasks_;  // fixed after construction
  std::atomic<int> camera_config_id_{1};
  std::mutex capture_mutex_;  // one capture at a time (one camera)
  std::atomic<bool> stopping_{false};

  // Calibration mode (seed 000 DAOAI_MODE_*): touched by serial_ jobs only.
  std::optional<CalibrationKind> calibration_mode_;

  // Work spawned on the arena and not finished yet; Shutdown waits for 0.
  std::mutex pending_mutex_;
  std::condition_variable pending_cv_;
  int pending_ = 0;  // GUARDED_BY(pending_mutex_)
  tbb::task_arena arena_;
  SerialJobs serial_;  // calibration steps and teaching, in request order
  std::vector<std::shared_ptr<ServerObserver>> observers_;  // fixed before serving

  void NotifyDetection(const DetectionEvent& e) const {
    for (const auto& o : observers_) o->OnDetection(e);
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
          for (const auto& o : observers_) o->OnAnswer(e);
        }
        return r;
      });
    };
  }
};

void RequestHandler::Impl::StartDetection(TaskState& t, PlanRequest plan_request,
                                          std::function<void(bool)> on_captured) {
  {
    std::lock_guard lock(t.mutex);
    ++t.in_flight;
    t.queue.Reset();  // the old grasps describe a scene that is about to change
  }
  Spawn([this, &t, plan_request = std::move(plan_request), on_captured = std::move(on_captured)] {
    const auto t0 = std::chrono::steady_clock::now();
    DetectionEvent event;
    event.task_id = t.spec.id;
    event.request = plan_request;
    event.time = std::chrono::system_clock::now();
    Result<CaptureHandle> scene = Status::Unavailable("not captured");
    {
      std::lock_guard lock(capture_mutex_);
      scene = Guard("capture", [&] { return planner_->Capture(plan_request); });
    }
    const auto t1 = std::chrono::steady_clock::now();
    event.capture_ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
    if (!scene.ok() || !*scene) {
      spdlog::warn("daoai: task {} capture failed: {}", t.spec.id,
                   scene.ok() ? "planner returned no scene" : scene.status().ToString());
      event.capture_status = scene.ok() ? Status::Internal("planner returned no scene") : scene.status();
      event.plan_status = event.capture_status;
      PlanResult failed;
      failed.outcome = PlanResult::Outcome::kCaptureFailed;
      t.queue.Replace(std::move(failed));
      NotifyDetection(event);
      if (on_captured) on_captured(false);
      FinishDetection(t);
      return;
    }
    if (on_captured) on_captured(true);
    Result<PlanResult> plan = Guard("detection", [&] { return planner_->Plan(plan_request, **scene); });
    PlanResult result;
    if (plan.ok()) {
      result = std::move(*plan);
    } else {
      spdlog::error("daoai: task {} planning failed ({}); reporting no objects", t.spec.id,
                    plan.status().ToString());
      result.outcome = PlanResult::Outcome::kNoObjects;
    }
    const auto t2 = std::chrono::steady_clock::now();
    const auto ms = std::chrono::duration<double, std::milli>(t2 - t0);
    spdlog::info("daoai: task {} detection: {} grasps, {} detections, outcome {} in {:.1f} ms",
                 t.spec.id, result.grasps.size(), result.detections, ToString(result.outcome),
                 ms.count());
    if (!observers_.empty()) {
      event.scene = *scene;
      event.plan_status = plan.status();
      if (plan.ok()) event.plan = result;
      event.plan_ms = std::chrono::duration<double, std::milli>(t2 - t1).count();
    }
    t.queue.Replace(std::move(result));
    // After the refill (an observer reading the queue sees the new one),
    // before waiting picks are answered (their answers follow the detection).
    if (!observers_.empty()) NotifyDetection(event);
    FinishDetection(t);
  });
}

void RequestHandler::Impl::FinishDetection(TaskState& t) {
  std::vector<std::function<void()>> ready;
  {
    std::lock_guard lock(t.mutex);
    ++t.finished;
    if (--t.in_flight == 0) ready.swap(t.waiters);
  }
  for (auto& w : ready) w();
}

Reply RequestHandler::Impl::PickReply(TaskState& t, WireFormat f) {
  return [this, &t, f]() -> std::optional<Response> {
    const GraspQueue::Popped p = t.queue.Pop();
    if (p.grasp) {
      Response r = Base(t.spec.kind == TaskSpec::Kind::kPlace ? daoai::kDropOffPose
                                                              : daoai::kObjectsFound, f);
      Status s = EncodePose(p.grasp->X_BT, f, r);
      const Result<int32_t> remaining = ToFixed(p.remaining);
      const Result<int32_t> klass = ToFixed(p.grasp->class_id);
      if (s.ok() && !remaining.ok()) s = remaining.status();
      if (s.ok() && !klass.ok()) s = klass.status();
      planner_->NotifyHandedOut(t.spec, *p.grasp);
      if (!s.ok()) {
        spdlog::error("daoai: task {} grasp on instance {} does not fit the wire format ({}); "
                      "answering NO_OBJECT_FOUND", t.spec.id, p.grasp->instance_id, s.ToString());
        return Base(daoai::kNoObjectFound, f);
      }
      r.payload[0] = *remaining;
      r.payload[1] = *klass;
      return r;
    }
    // Nothing to hand out: say why, in the dialect's vocabulary.
    int32_t status = daoai::kNoObjectFound;
    if (!p.outcome || *p.outcome == PlanResult::Outcome::kCaptureFailed) {
      status = f.v1() ? daoai::kNoImageCaptured : daoai::kNoObjectFound;
    } else if (*p.outcome == PlanResult::Outcome::kNoCollisionFree) {
      status = f.v1() ? daoai::kNoObjectFound : daoai::kNoCollisionFreePose;
    }
    return Base(status, f);
  };
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
  serial_.Post([this, command, X_BF, f, done = std::move(done)] {
    auto answer = [&](int32_t status, const std::optional<Pose>& pose = std::nullopt) {
      Response r = Base(status, f);
      if (pose) {
        const Status s = EncodePose(*pose, f, r);
        if (!s.ok()) spdlog::error("daoai: calibration pose does not fit the wire: {}", s.ToString());
      }
      done(Respond(r));
    };
    auto start = [&](CalibrationKind kind) -> bool {
      const Status s = calibration_->Start(kind, X_BF);
      if (!s.ok()) {
        spdlog::error("daoai: calibration start failed: {}", s.ToString());
        calibration_mode_.reset();
        return false;
      }
      calibration_mode_ = kind;
      return true;
    };
    // Accumulates in `kind`; @returns the step or nullopt (logged) on failure.
    auto accumulate = [&](CalibrationKind kind) -> std::optional<CalibrationStep> {
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
    };
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
        if (start(CalibrationKind::kAuto)) {
          answer(daoai::kModeAutoCalibration, X_BF);
        } else {
          answer(daoai::kUnknownCommand);
        }
        return;
      case daoai::kAutoAccumulatePose: {
        if (calibration_mode_ != CalibrationKind::kAuto) {
          spdlog::warn("daoai: auto accumulate outside auto calibration");
          answer(daoai::kUnknownCommand);
          return;
        }
        const auto step = accumulate(CalibrationKind::kAuto);
        if (!step) {
          answer(daoai::kUnknownCommand);
        } else if (step->done) {
          answer(daoai::kDoneCalibration);
        } else {
          answer(daoai::kModeAutoCalibration, step->next_X_BF.value_or(X_BF));
        }
        return;
      }
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
        if (start(CalibrationKind::kAuto2D)) {
          answer(daoai::kMode2DAutoCalibration, X_BF);
        } else {
          answer(daoai::kUnknownCommand);
        }
        return;
      case daoai::kAutoAccumulate2DPose: {
        if (calibration_mode_ != CalibrationKind::kAuto2D) {
          spdlog::warn("daoai: 2D accumulate outside 2D auto calibration");
          answer(daoai::kUnknownCommand);
          return;
        }
        const auto step = accumulate(CalibrationKind::kAuto2D);
        if (!step) {
          answer(daoai::kUnknownCommand);
        } else if (step->done) {
          answer(daoai::kDone2DAutoCalibration);
        } else {
          answer(daoai::kMode2DAutoCalibration, step->next_X_BF.value_or(X_BF));
        }
        return;
      }
      default:
        answer(daoai::kUnknownCommand);
    }
  });
}

void RequestHandler::Impl::HandleAsync(const Request& req, ClientContext& client,
                                       Completion done) {
  ++client.requests;
  if (stopping_) return;  // shutting down: completions are dropped
  std::shared_ptr<AnswerEvent> answer_event;
  done = Observed(req, client, answer_event, std::move(done));

  // meta_2 is 1 or 2 (both seeds' programs send 1, seed 000's text says 2)
  // and is echoed; anything else is garbage (or a misaligned stream): answer
  // UNKNOWN_COMMAND. The rules follow the cell's dialect, not meta_2.
  if (req.meta_2 != 1 && req.meta_2 != 2) {
    spdlog::warn("daoai: {} sent protocol version (meta_2) {} (command {}); expected 1 or 2; "
                 "answering UNKNOWN_COMMAND", client.peer, req.meta_2, req.command);
    done(Respond(Base(daoai::kUnknownCommand, cell_.robot.protocol_version)));
    return;
  }
  // meta_1 selects the orientation convention of both directions.
  const std::optional<RobotModel> model = FindRobotModel(static_cast<RobotType>(req.meta_1));
  if (!model) {
    spdlog::warn("daoai: {} sent unknown robot type (meta_1) {} (command {}); answering "
                 "UNKNOWN_COMMAND", client.peer, req.meta_1, req.command);
    done(Respond(Base(daoai::kUnknownCommand, req.meta_2)));
    return;
  }
  if (model->type != cell_.robot.model.type && !client.warned_meta_1) {
    client.warned_meta_1 = true;
    spdlog::warn("daoai: {} says it is a {} robot (meta_1 {}) but the cell is configured for {} "
                 "(meta_1 {}); answering in the {} convention with the cell's meta_1",
                 client.peer, ToString(model->type), req.meta_1, ToString(cell_.robot.model.type),
                 static_cast<int>(cell_.robot.model.type), ToString(model->convention));
  }
  WireFormat f;
  f.convention = model->convention;
  // meta_1 99 ("other") says only that the robot has no id of its own; the
  // cell names which one it is (Adept, Kawasaki, Comau, Syntec, Turin).
  if (model->type == RobotType::kOther && cell_.robot.model.type == RobotType::kOther) {
    f.convention = cell_.robot.model.convention;
  }
  f.position_scale = cell_.robot.position_scale;
  f.dialect = cell_.robot.dialect;
  f.meta_2 = req.meta_2;

  // Every message carries the robot pose: record it (status page, liveness,
  // eye-in-hand captures, calibration, teaching).
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

  TaskState* task = nullptr;
  if (NeedsTask(req.command)) {
    auto it = tasks_.find(req.payload_1);
    if (it == tasks_.end()) {
      spdlog::warn("daoai: {} named unknown task id {} (payload_1) with command {}; answering "
                   "UNKNOWN_COMMAND", client.peer, req.payload_1, req.command);
      done(Respond(Base(daoai::kUnknownCommand, f)));
      return;
    }
    task = it->second.get();
    client.last_task_id = task->spec.id;
  }

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
      StartDetection(*task, MakePlanRequest(*task, X_BF), nullptr);
      return;

    case daoai::kCaptureAndProcess: {
      // Answer when the image is captured, not when detection ends.
      auto on_captured = [this, f, done = std::move(done)](bool ok) {
        done(Respond(Base(ok ? daoai::kDetection : daoai::kCaptureFail, f)));
      };
      StartDetection(*task, MakePlanRequest(*task, X_BF), std::move(on_captured));
      return;
    }

    case daoai::kPickPose: {
      Reply reply = PickReply(*task, f);
      {
        std::unique_lock lock(task->mutex);
        if (task->in_flight > 0) {
          task->waiters.push_back([done = std::move(done), reply = std::move(reply)] { done(reply); });
          return;
        }
      }
      done(std::move(reply));
      return;
    }

    case daoai::kSendPose: {
      // Teach: no response. The pose is the robot's tool pose (what it sends).
      if (!X_BF) {
        spdlog::warn("daoai: {} sent a teach pose that could not be decoded; ignored", client.peer);
        done(NoResponse());
        return;
      }
      auto it = tasks_.find(req.payload_1);
      if (it == tasks_.end()) it = tasks_.find(client.last_task_id);
      if (it == tasks_.end()) {
        spdlog::warn("daoai: {} sent a teach pose for unknown task {}; ignored", client.peer,
                     req.payload_1);
        done(NoResponse());
        return;
      }
      TeachRequest teach{it->second->spec, *X_BF};
      done(NoResponse());
      serial_.Post([this, teach] {
        const Status s = Guard("teach", [&] { return planner_->Teach(teach); });
        if (s.ok()) {
          spdlog::info("daoai: taught a grasp for task {}", teach.task.id);
        } else {
          spdlog::warn("daoai: teach for task {} not stored: {}", teach.task.id, s.ToString());
        }
      });
      return;
    }

    case daoai::kCheckEmptyBox: {
      PlanRequest plan_request = MakePlanRequest(*task, X_BF);
      Spawn([this, task, f, plan_request = std::move(plan_request), done = std::move(done)] {
        const auto t0 = std::chrono::steady_clock::now();
        DetectionEvent event;
        event.task_id = task->spec.id;
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
                       "BOX_NOT_EMPTY", task->spec.id, scene.status().ToString());
          done(Respond(Base(daoai::kBoxNotEmpty, f)));
          return;
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
                       task->spec.id, plan.status().ToString());
          done(Respond(Base(daoai::kBoxNotEmpty, f)));
          return;
        }
        const EmptyBoxRule& rule = task->spec.empty_box;
        const int64_t points = EmptyBoxPoints(rule, plan->roi_points, plan->largest_region_points);
        const bool empty = IsBoxEmpty(rule, *plan);
        spdlog::info("daoai: task {} empty-box check: {} points (threshold {}), {} detections: {}",
                     task->spec.id, points, rule.threshold_points, plan->detections,
                     empty ? "EMPTY" : "NOT EMPTY");
        done(Respond(Base(empty ? daoai::kBoxEmpty : daoai::kBoxNotEmpty, f)));
      });
      return;
    }

    case daoai::kPrecisionCheck: {
      PlanRequest plan_request = MakePlanRequest(*task, X_BF);
      Spawn([this, f, plan_request = std::move(plan_request), done = std::move(done)] {
        Result<double> error_mm = Status::Unavailable("not run");
        {
          std::lock_guard lock(capture_mutex_);
          error_mm = Guard("precision check", [&] { return planner_->CheckPrecision(plan_request); });
        }
        Result<int32_t> fixed = error_mm.ok() ? ToFixed(*error_mm) : Result<int32_t>(error_mm.status());
        if (!fixed.ok()) {
          spdlog::warn("daoai: task {} precision check failed: {}", plan_request.task.id,
                       fixed.status().ToString());
          done(Respond(Base(daoai::kPrecisionCheckFail, f)));
          return;
        }
        Response r = Base(daoai::kPrecisionCheckSuccess, f);
        r.payload[0] = *fixed;
        done(Respond(r));
      });
      return;
    }

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
    s.in_flight = t->in_flight;
    s.finished = t->finished;
  }
  if (std::optional<GraspQueue::Summary> last = t->queue.LastPlan()) s.outcome = last->outcome;
  s.grasps_left = t->queue.size();
  return s;
}

Status RequestHandler::Impl::StartDetection(int task_id, const std::optional<Pose>& X_BF) {
  TaskState* t = FindTask(task_id);
  if (!t) return UnknownTask(task_id);
  if (stopping_) return Status::Unavailable("the request handler is shutting down");
  StartDetection(*t, MakePlanRequest(*t, X_BF), nullptr);
  return Status::Ok();
}

Status RequestHandler::Impl::WhenIdle(int task_id, std::function<void()> ready) {
  TaskState* t = FindTask(task_id);
  if (!t) return UnknownTask(task_id);
  {
    std::lock_guard lock(t->mutex);
    if (t->in_flight > 0) {
      t->waiters.push_back(std::move(ready));
      return Status::Ok();
    }
  }
  ready();
  return Status::Ok();
}

Result<GraspQueue::Popped> RequestHandler::Impl::PopGrasp(int task_id) {
  TaskState* t = FindTask(task_id);
  if (!t) return UnknownTask(task_id);
  GraspQueue::Popped p = t->queue.Pop();
  if (p.grasp) planner_->NotifyHandedOut(t->spec, *p.grasp);
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
  impl_->HandleAsync(request, client, std::move(done));
}

std::optional<Response> RequestHandler::Handle(const Request& request, ClientContext& client) {
  auto promise = std::make_shared<std::promise<Reply>>();
  std::future<Reply> future = promise->get_future();
  impl_->HandleAsync(request, client, [promise](Reply reply) { promise->set_value(std::move(reply)); });
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
Status RequestHandler::WhenIdle(int task_id, std::function<void()> ready) {
  return impl_->WhenIdle(task_id, std::move(ready));
}
void RequestHandler::RunCalibration(std::function<void(CalibrationService&)> job) {
  impl_->RunCalibration(std::move(job));
}

Result<GraspQueue::Popped> RequestHandler::PopGrasp(int task_id) { return impl_->PopGrasp(task_id); }

}  // namespace bp
