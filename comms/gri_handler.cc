#include "comms/gri_handler.h"

#include <algorithm>
#include <atomic>
#include <cmath>

#include <spdlog/spdlog.h>

#include <utility>

#include "comms/internal/exception_text.h"
#include "core/conventions.h"
#include "core/fault_points.h"

namespace bp {
namespace {

using gri::Code;
using gri::Format;
using gri::JobStatus;

using internal::ExceptionText;

bool ValidPoseFormat(uint8_t pose_format) {
  return pose_format >= 1 && pose_format <= gri::kMaxPoseFormat;
}

// The official format numbers quaternion fields w, x, y, z for pose format 1
// and x, y, z, w for 2; v2 (seed 002) uses x, y, z, w for both.
QuaternionOrder OrderFor(Format f, uint8_t pose_format) {
  return f == Format::kOfficial && pose_format == 1 ? QuaternionOrder::kWXYZ
                                                    : QuaternionOrder::kXYZW;
}

// X in the request's format and units (official positions always in mm).
Result<std::array<double, 7>> ToWire(const Pose& X, Format f, uint8_t pose_format) {
  Result<std::array<double, 7>> v =
      EncodeGriPose(X, static_cast<GriPoseFormat>(pose_format), OrderFor(f, pose_format));
  if (!v.ok()) return v.status();
  if (f == Format::kOfficial) {
    for (int i = 0; i < 3; ++i) (*v)[i] = X.translation()[i] * 1000.0;
  }
  return v;
}

Result<Pose> FromWire(const gri::Request& r) {
  std::array<double, 7> v = r.pose;
  if (r.format == Format::kOfficial) v[0] = v[1] = v[2] = 0.0;  // position decoded below
  Result<Pose> X = DecodeGriPose(v, static_cast<GriPoseFormat>(r.pose_format),
                                 OrderFor(r.format, r.pose_format));
  if (X.ok() && r.format == Format::kOfficial) {
    X->translation() = Vec3(r.pose[0], r.pose[1], r.pose[2]) / 1000.0;
  }
  return X;
}

bool NeedsJob(uint8_t action) {
  switch (action) {
    case gri::kTriggerJobSync:
    case gri::kTriggerJobAsync:
    case gri::kGetJobStatus:
    case gri::kGetNextPose:
    case gri::kGetRelatedPose:
      return true;
    default:
      return false;
  }
}

bool ReturnsPose(uint8_t action) {
  return action == gri::kTriggerJobSync || action == gri::kGetNextPose ||
         action == gri::kGetRelatedPose;
}

// `primary` goes to v2 data_1 / official data_2 (remaining primary poses; the
// job status for GET_JOB_STATUS; 1 = ready for STATUS), `related` to v2
// data_2 / official data_3. Official data_1, the node return code, is 0.
gri::Response Build(const gri::Request& req, Code code,
                    const std::optional<std::array<double, 7>>& pose = std::nullopt,
                    int32_t primary = 0, int32_t related = 0) {
  gri::Response r = GriHandler::ErrorResponse(req, code);
  if (pose) r.pose = *pose;
  const size_t slot = req.format == Format::kV2 ? 0 : 1;
  r.data[slot] = primary;
  r.data[slot + 1] = related;
  return r;
}

// The answer handing out `g` with `remaining` grasps left including it, or
// the reason it cannot be written in the request's format (every field
// checked: gri::EncodeResponse).
// binpick extension of the official format (docs/protocols.md "Fill level
// over the GRI"): data_4..6 of a pose answer carry the fill level of the
// detection the pose comes from, as rc_reason's overall filling level:
// mean and max height in percent of the bin's inner height, and the
// occupied share of the floor in percent, each x 100 (0..10000). v2 has no
// room for them (data_1..5 hold the job's counts and status).
void PutFillLevel(const gri::Request& req, const std::optional<FillLevel>& fill, double bin_height,
                  gri::Response& r) {
  if (req.format == Format::kV2 || !fill || !(bin_height > 0)) return;
  const auto percent100 = [](double fraction) {
    return static_cast<int32_t>(std::lround(std::clamp(fraction, 0.0, 1.0) * 10000.0));
  };
  r.data[3] = percent100(fill->mean_height / bin_height);
  r.data[4] = percent100(fill->max_height / bin_height);
  r.data[5] = percent100(fill->occupied_fraction);
}

Result<gri::Response> PoseAnswer(const gri::Request& req, const Grasp& g, int remaining,
                                 const std::optional<FillLevel>& fill, double bin_height) {
  Result<std::array<double, 7>> wire = ToWire(g.X_BT, req.format, req.pose_format);
  if (!wire.ok()) return wire.status();
  // The related poses: the part's other grasps, then the part (NextPoseReply).
  gri::Response r = Build(req, Code::kOk, *wire, remaining - 1,
                          static_cast<int32_t>(g.related_X_B.size() + 1));
  PutFillLevel(req, fill, bin_height, r);
  if (Result<std::vector<uint8_t>> bytes = gri::EncodeResponse(r); !bytes.ok()) return bytes.status();
  return r;
}

}  // namespace

GriHandler::GriHandler(RequestHandler& tasks) : tasks_(tasks) {
  for (const TaskSpec& t : tasks_.cell().tasks) jobs_.emplace(t.id, Job{});
}

gri::Response GriHandler::ErrorResponse(const gri::Request& request, gri::Code code) {
  gri::Response r;
  r.format = request.format;
  r.pose_format = request.pose_format;
  r.action = request.action;
  r.job_id = request.job_id;
  r.error_code = gri::WireErrorCode(request.format, code);
  return r;
}

std::vector<uint8_t> GriHandler::Serialize(const gri::Response& response, bool* replaced) {
  fault::Hit("gri.serialize");  // tests: the encoding throws (no memory)
  Result<std::vector<uint8_t>> bytes = gri::EncodeResponse(response);
  if (replaced) *replaced = !bytes.ok();
  if (bytes.ok()) return std::move(*bytes);
  spdlog::error(
      "gri: {} response to action {} job {} does not fit its format ({}); answering "
      "INTERNAL_ERROR",
      gri::ToString(response.format), response.action, response.job_id, bytes.status().ToString());
  gri::Request echo;
  echo.format = response.format;
  echo.pose_format = response.pose_format;
  echo.action = response.action;
  echo.job_id = response.job_id;
  bytes = gri::EncodeResponse(ErrorResponse(echo, Code::kInternalError));
  if (!bytes.ok()) {  // only the job id can still not fit: drop it
    echo.job_id = 0;
    bytes = gri::EncodeResponse(ErrorResponse(echo, Code::kInternalError));
  }
  return std::move(*bytes);
}

JobStatus GriHandler::StatusLocked(const RequestHandler::TaskSnapshot& s, const Job& job) const {
  if (s.in_flight > 0) return JobStatus::kRunning;
  if (s.finished <= job.consumed) return JobStatus::kInactive;
  if (!s.outcome) return JobStatus::kRunning;  // a detection started between the reads
  if (*s.outcome == PlanResult::Outcome::kCaptureFailed ||
      *s.outcome == PlanResult::Outcome::kPlannerFailed) {
    return JobStatus::kFailed;
  }
  return JobStatus::kDone;
}

std::optional<JobStatus> GriHandler::JobStatusOf(int job_id) const {
  Result<RequestHandler::TaskSnapshot> s = tasks_.Snapshot(job_id);
  if (!s.ok()) return std::nullopt;
  std::lock_guard lock(mutex_);
  return StatusLocked(*s, jobs_.at(job_id));
}

GriHandler::Reply GriHandler::NextPoseReply(const gri::Request& req, bool after_trigger,
                                            ClientContext* client) {
  return [this, req, after_trigger, client]() -> gri::Response {
    std::lock_guard lock(mutex_);
    const Result<RequestHandler::TaskSnapshot> s = tasks_.Snapshot(req.job_id);
    if (!s.ok()) return Build(req, Code::kJobDoesNotExist);
    Job& job = jobs_.at(req.job_id);
    switch (StatusLocked(*s, job)) {
      case JobStatus::kRunning:
        return Build(req, Code::kJobStillRunning);
      case JobStatus::kInactive:
        return Build(req, Code::kNoPosesFound);
      case JobStatus::kFailed:
        job.consumed = s->finished;
        spdlog::warn("gri: job {}: the last detection failed (capture or planner)", req.job_id);
        return Build(req, Code::kPipelineNotAvailable);
      case JobStatus::kDone:
        break;
    }
    // Encoded and range-checked before the grasp leaves the queue (the pop
    // rule, as DaoAI and Modbus): a grasp whose answer does not fit this
    // request's format (an official pose beyond +-2147 mm) stays queued for
    // a robot or a later plan that can take it; the next one that fits is
    // handed out, and only once the transport wrote it (ClientContext::settle).
    std::optional<gri::Response> answer;
    Status refusal;
    const Result<GraspQueue::Popped> p =
        tasks_.PopGrasp(req.job_id, client, [&](const Grasp& g, int remaining) {
          Result<gri::Response> r = PoseAnswer(req, g, remaining, s->fill, tasks_.cell().bin.inner_size.z());
          if (!r.ok()) {
            if (refusal.ok()) refusal = r.status();
            return false;
          }
          answer = std::move(*r);
          return true;
        });
    if (p.ok() && p->refused > 0) {
      spdlog::error("gri: job {}: {} grasp(s) cannot be sent in this request's format ({}); they "
                    "stay queued", req.job_id, p->refused, refusal.ToString());
    }
    if (!p.ok() || !p->grasp) {
      if (p.ok() && p->refused > 0) return Build(req, Code::kInternalError);
      job.consumed = s->finished;
      job.related.clear();
      job.next_related = 0;
      if (after_trigger) spdlog::info("gri: job {}: no poses found", req.job_id);
      return Build(req, Code::kNoPosesFound);
    }
    const Grasp& g = *p->grasp;
    job.related = g.related_X_B;
    job.related.push_back(g.X_BO);
    job.next_related = 0;
    if (p->remaining == 1) job.consumed = s->finished;  // all taken: back to INACTIVE
    return *answer;
  };
}

void GriHandler::HandleAsync(const gri::Request& req, ClientContext& client, Completion done) noexcept {
  std::shared_ptr<std::atomic<bool>> answered;
  try {
    answered = std::make_shared<std::atomic<bool>>(false);
    Handle(req, client, [answered, done](Reply reply) {
      if (!answered->exchange(true)) done(std::move(reply));
    });
    return;
  } catch (...) {
    tasks_.CountAnswerFailure();
    spdlog::error("gri: handling action {} job {} from {} threw ({}); {}", req.action, req.job_id, client.peer,
                  ExceptionText(), answered && answered->load() ? "it was answered already" : "answering INTERNAL_ERROR");
  }
  if (answered && answered->exchange(true)) return;  // answered before it threw
  try {
    done([r = ErrorResponse(req, Code::kInternalError)] { return r; });
  } catch (...) {
    spdlog::error("gri: answering action {} after its handling threw threw too: {}", req.action, ExceptionText());
  }
}

void GriHandler::Handle(const gri::Request& req, ClientContext& client, Completion done) {
  fault::Hit("gri.handle");  // tests: throws inside HandleAsync
  ++client.requests;
  auto answer = [&done, &req](Code code) { done([r = Build(req, code)] { return r; }); };

  // Every request carries the robot pose: keep it (status, eye-in-hand captures).
  std::optional<Pose> X_BF;
  if (ValidPoseFormat(req.pose_format)) {
    if (Result<Pose> decoded = FromWire(req); decoded.ok()) {
      X_BF = *decoded;
      client.X_BF = X_BF;
      client.pose_time = std::chrono::system_clock::now();
    } else {
      spdlog::debug("gri: {} sent an undecodable pose: {}", client.peer,
                    decoded.status().ToString());
    }
  }

  if (NeedsJob(req.action) && !tasks_.Snapshot(req.job_id).ok()) {
    spdlog::warn("gri: {} named unknown job {} (action {}); answering JOB_DOES_NOT_EXIST",
                 client.peer, req.job_id, req.action);
    answer(Code::kJobDoesNotExist);
    return;
  }
  if (ReturnsPose(req.action) && !ValidPoseFormat(req.pose_format)) {
    spdlog::warn(
        "gri: {} asked for a pose in pose format {} (action {}); answering "
        "INVALID_REQUEST_ERROR",
        client.peer, req.pose_format, req.action);
    answer(Code::kInvalidRequest);
    return;
  }
  if (NeedsJob(req.action)) client.last_task_id = req.job_id;

  switch (req.action) {
    case gri::kStatus:
      done([r = Build(req, Code::kOk, std::nullopt, 1)] { return r; });
      return;

    case gri::kTriggerJobSync:
    case gri::kTriggerJobAsync: {
      {
        std::lock_guard lock(mutex_);
        Job& job = jobs_.at(req.job_id);
        job.related.clear();
        job.next_related = 0;
      }
      if (Status s = tasks_.StartDetection(req.job_id, X_BF); !s.ok()) {
        spdlog::warn("gri: job {} not started: {}", req.job_id, s.ToString());
        answer(Code::kInternalError);
        return;
      }
      if (req.action == gri::kTriggerJobAsync) {
        answer(Code::kOk);
        return;
      }
      // Sync: answer with the first pose once the detection finished.
      Reply reply = NextPoseReply(req, /*after_trigger=*/true, &client);
      (void)tasks_.WhenDetected(req.job_id,
                            [done = std::move(done), reply = std::move(reply)] { done(reply); });
      return;
    }

    case gri::kGetJobStatus: {
      const std::optional<JobStatus> status = JobStatusOf(req.job_id);
      done([r = Build(req, Code::kOk, std::nullopt, static_cast<int32_t>(*status))] { return r; });
      return;
    }

    case gri::kGetNextPose:
      done(NextPoseReply(req, /*after_trigger=*/false, &client));
      return;

    case gri::kGetRelatedPose:
      done([this, req]() -> gri::Response {
        std::lock_guard lock(mutex_);
        Job& job = jobs_.at(req.job_id);
        const int primary = tasks_.QueueSize(req.job_id);
        if (job.next_related >= job.related.size())
          return Build(req, Code::kNoRelatedPoses, std::nullopt, primary);
        const Pose& X_B = job.related[job.next_related++];
        Result<std::array<double, 7>> wire = ToWire(X_B, req.format, req.pose_format);
        if (!wire.ok()) {
          spdlog::error("gri: job {}: related pose cannot be encoded: {}", req.job_id,
                        wire.status().ToString());
          return Build(req, Code::kInternalError);
        }
        return Build(req, Code::kOk, *wire, primary,
                     static_cast<int32_t>(job.related.size() - job.next_related));
      });
      return;

    case gri::kHecInit:
    case gri::kHecSetPose:
    case gri::kHecCalibrate:
      if (!client.may_change_cell) {
        // A calibration rewrites the hand-eye file every robot's picks use.
        spdlog::warn("gri: {} may not change the cell (not in the config allowlist): HEC action "
                     "{} refused, answered HEC_CONFIG_ERROR", client.peer, req.action);
        answer(Code::kHecConfigError);
        return;
      }
      HandEye(req, X_BF, std::move(done));
      return;

    default:
      answer(Code::kInvalidAction);
      return;
  }
}

// Hand-eye calibration (docs/protocols.md "GRI semantics"): HEC_INIT starts a
// calibration (data_1: the pipeline, logged), HEC_SET_POSE captures the board
// at the request's robot pose into slot data_2, HEC_CALIBRATE solves. The
// steps run on the request handler's calibration sequence.
void GriHandler::HandEye(const gri::Request& req, const std::optional<Pose>& X_BF, Completion done) {
  auto reply = [done](const gri::Request& r, Code code) { done([resp = Build(r, code)] { return resp; }); };
  if (!tasks_.cell().calibration) {
    spdlog::warn("gri: HEC action {}: the cell has no calibration section", req.action);
    reply(req, Code::kHecConfigError);
    return;
  }
  constexpr int kMaxSlot = 8;  // 0-7 (documentation) or 1-8 (its reference client)
  // A refused step (the calibration queue is full: logged and counted by the
  // request handler) is answered with the action's own error.
  bool posted = true;
  Code refused = Code::kHecCalibrateError;
  switch (req.action) {
    case gri::kHecInit:
      refused = Code::kHecInitError;
      posted = tasks_.RunCalibration([this, req, X_BF, reply](CalibrationService& calib) {
        const Status s = calib.Start(CalibrationKind::kManual, X_BF.value_or(Pose::Identity()));
        {
          std::lock_guard lock(mutex_);
          hec_started_ = s.ok();
        }
        if (!s.ok()) spdlog::error("gri: HEC_INIT (pipeline {}) failed: {}", req.data[0], s.ToString());
        else spdlog::info("gri: HEC_INIT: hand-eye calibration for pipeline {} started", req.data[0]);
        reply(req, s.ok() ? Code::kOk : Code::kHecInitError);
      });
      break;
    case gri::kHecSetPose: {
      const int slot = req.data[1];
      if (!X_BF || slot < 0 || slot > kMaxSlot) {
        spdlog::warn("gri: HEC_SET_POSE with {} (slot {})", X_BF ? "a pose" : "no usable pose", slot);
        reply(req, Code::kHecSetPoseError);
        return;
      }
      refused = Code::kHecSetPoseError;
      posted = tasks_.RunCalibration([this, req, slot, X_BF = *X_BF, reply](CalibrationService& calib) {
        bool started;
        {
          std::lock_guard lock(mutex_);
          started = hec_started_;
        }
        if (!started) {
          reply(req, Code::kHecInitError);
          return;
        }
        Result<CalibrationStep> step = calib.AccumulateInSlot(CalibrationKind::kManual, slot, X_BF);
        if (!step.ok()) spdlog::warn("gri: HEC_SET_POSE slot {}: {}", slot, step.status().ToString());
        reply(req, step.ok() ? Code::kOk : Code::kHecSetPoseError);
      });
      break;
    }
    default:  // kHecCalibrate
      posted = tasks_.RunCalibration([this, req, reply](CalibrationService& calib) {
        bool started;
        {
          std::lock_guard lock(mutex_);
          started = hec_started_;
          hec_started_ = false;
        }
        if (!started) {
          reply(req, Code::kHecInitError);
          return;
        }
        const Status s = calib.Finish(CalibrationKind::kManual);
        if (!s.ok()) spdlog::error("gri: HEC_CALIBRATE: {}", s.ToString());
        reply(req, s.ok() ? Code::kOk
                   : s.code() == Status::Code::kInvalidArgument ? Code::kHecInsufficientDetection
                                                                : Code::kHecCalibrateError);
      });
      break;
  }
  if (!posted) reply(req, refused);
}

}  // namespace bp
