#include "web/status_state.h"

#include <nlohmann/json.hpp>
#include <spdlog/sinks/base_sink.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <ctime>
#include <deque>
#include <map>
#include <mutex>
#include <tuple>

#include "core/conventions.h"
#include "grasp/bin_picking_planner.h"
#include "web/internal/overlay.h"

namespace bp {
namespace {

using json = nlohmann::json;
using Clock = std::chrono::system_clock;

std::string IsoTime(Clock::time_point t) {
  const auto ms = std::chrono::duration_cast<std::chrono::milliseconds>(t.time_since_epoch()).count();
  const std::time_t s = static_cast<std::time_t>(ms / 1000);
  std::tm tm{};
  gmtime_r(&s, &tm);
  char buf[40];
  std::strftime(buf, sizeof(buf), "%Y-%m-%dT%H:%M:%S", &tm);
  char out[48];
  std::snprintf(out, sizeof(out), "%s.%03dZ", buf, static_cast<int>(ms % 1000));
  return out;
}

json PoseJson(const Pose& X) {
  const Quat q(X.rotation());
  const Vec3 t = X.translation();
  return {{"position_m", {t.x(), t.y(), t.z()}}, {"quaternion_wxyz", {q.w(), q.x(), q.y(), q.z()}}};
}

// The plan's bin detection (issue 41): null when the stage did not run.
json BinJson(const std::optional<BinDetection>& bin) {
  if (!bin) return nullptr;
  json j = {{"found", bin->found}, {"ms", bin->ms}};
  if (bin->found) {
    j["offset_mm"] = 1e3 * bin->offset;
    j["offset_deg"] = bin->offset_deg;
    j["warning"] = bin->warn;
    j["pose"] = PoseJson(bin->X_BW);
  } else {
    j["reason"] = bin->reason;
  }
  return j;
}

// Calibration mode a response status reports (seed 000 DAOAI_MODE_*).
const char* CalibrationModeOf(int32_t status) {
  switch (status) {
    case daoai::kModeCalibration: return "manual";
    case daoai::kModeAutoCalibration: return "auto";
    case daoai::kGuidanceGood:
    case daoai::kGuidanceBad: return "guidance";
    case daoai::kMode2DAutoCalibration: return "auto_2d";
    default: return nullptr;
  }
}

// The label of a DaoAI command or status in /metrics: its number when it is
// one binpick knows (comms/daoai_message.h), "other" for anything else. A
// robot can send any int32 as a command: labelling it raw would grow
// /metrics by one series per distinct number (issue 39).
constexpr std::array<int32_t, 17> kCommandLabels = {
    daoai::kNoCommand, daoai::kStartManualCalibration, daoai::kStopManualCalibration,
    daoai::kStartAutoCalibration, daoai::kManualAccumulatePose, daoai::kAutoAccumulatePose,
    daoai::kGuidanceCalibration, daoai::kStart2DAutoCalibration, daoai::kAutoAccumulate2DPose,
    daoai::kCaptureAndProcessAsync, daoai::kCaptureAndProcess, daoai::kPickPose,
    daoai::kSendPose, daoai::kCheckEmptyBox, daoai::kPrecisionCheck, daoai::kSwitchConfig,
    daoai::kReportPickFailure};
constexpr std::array<int32_t, 22> kStatusLabels = {
    daoai::kUnknownCommand, daoai::kObjectsFound, daoai::kNoObjectFound,
    daoai::kNoCollisionFreePose, daoai::kDetection, daoai::kDropOffPose, daoai::kCaptureFail,
    daoai::kModeCalibration, daoai::kModeAutoCalibration, daoai::kGuidanceGood,
    daoai::kGuidanceBad, daoai::kMode2DAutoCalibration, daoai::kDoneGuidanceCalibration,
    daoai::kDoneCalibration, daoai::kDone2DAutoCalibration, daoai::kBoxEmpty,
    daoai::kBoxNotEmpty, daoai::kPrecisionCheckSuccess, daoai::kPrecisionCheckFail,
    daoai::kSwitchConfigSuccess, daoai::kSwitchConfigFail, daoai::kPickFailureNoted};

// Index of `value` in `known`, or known.size() for "other".
template <size_t N>
size_t LabelIndex(const std::array<int32_t, N>& known, int32_t value) {
  return static_cast<size_t>(std::find(known.begin(), known.end(), value) - known.begin());
}

template <size_t N>
std::string LabelText(const std::array<int32_t, N>& known, size_t index) {
  return index < N ? std::to_string(known[index]) : std::string("other");
}

struct LogEntry {
  Clock::time_point time;
  std::string level;
  std::string logger;
  std::string message;
};

// Keeps the last N warnings and errors and counts them. Owns its counts (the
// registry reads them through a callback), so a logger that outlives the
// registry never touches freed memory.
class ErrorSink final : public spdlog::sinks::base_sink<std::mutex> {
 public:
  explicit ErrorSink(size_t max) : max_(max) { set_level(spdlog::level::warn); }
  std::vector<LogEntry> Entries() {
    std::lock_guard lock(mutex_);
    return {entries_.begin(), entries_.end()};
  }
  double warnings() const { return static_cast<double>(warnings_.load(std::memory_order_relaxed)); }
  double errors() const { return static_cast<double>(errors_.load(std::memory_order_relaxed)); }

 protected:
  void sink_it_(const spdlog::details::log_msg& msg) override {
    if (msg.level < spdlog::level::warn) return;
    (msg.level == spdlog::level::warn ? warnings_ : errors_).fetch_add(1, std::memory_order_relaxed);
    LogEntry e;
    e.time = msg.time;
    e.level = std::string(spdlog::level::to_string_view(msg.level).data(),
                          spdlog::level::to_string_view(msg.level).size());
    e.logger.assign(msg.logger_name.data(), msg.logger_name.size());
    e.message.assign(msg.payload.data(), msg.payload.size());
    entries_.push_back(std::move(e));
    while (entries_.size() > max_) entries_.pop_front();
  }
  void flush_() override {}

 private:
  const size_t max_;
  std::atomic<uint64_t> warnings_{0}, errors_{0};
  std::deque<LogEntry> entries_;  // GUARDED_BY(base_sink::mutex_)
};

}  // namespace

class StatusState::Impl {
 public:
  Impl(const Cell& cell, MetricsRegistry& metrics, StatusStateOptions options)
      : options_(options),
        metrics_(metrics),
        start_(Clock::now()),
        capture_seconds_(metrics.GetHistogram("binpick_capture_seconds",
                                              "Capture (camera) time per detection.",
                                              LatencyBucketsSeconds())),
        plan_seconds_(metrics.GetHistogram("binpick_plan_seconds",
                                           "Detection and grasp planning time per detection.",
                                           LatencyBucketsSeconds())),
        captures_ok_(metrics.GetCounter("binpick_captures_total", "Captures by result.",
                                        {{"result", "ok"}})),
        captures_failed_(metrics.GetCounter("binpick_captures_total", "Captures by result.",
                                            {{"result", "failed"}})) {
    cell_name_ = cell.name;
    bin_ = cell.bin;
    for (const TaskSpec& t : cell.tasks) tasks_.emplace_back(t.id, t.name);
    for (const PartSpec& p : cell.parts) part_names_[p.class_id] = p.name;
    sink_ = std::make_shared<ErrorSink>(options.max_errors);
    const char* help = "Log messages by level (warnings and up).";
    metrics.AddCounterCallback("binpick_log_messages_total", help, {{"level", "warning"}},
                               [sink = sink_] { return sink->warnings(); });
    metrics.AddCounterCallback("binpick_log_messages_total", help, {{"level", "error"}},
                               [sink = sink_] { return sink->errors(); });
  }

  void OnDetection(const DetectionEvent& e) {
    const std::string task = std::to_string(e.task_id);
    (e.scene ? captures_ok_ : captures_failed_).Inc();
    capture_seconds_.Observe(e.capture_ms / 1000.0);
    if (e.plan) {
      plan_seconds_.Observe(e.plan_ms / 1000.0);
      for (const StageTime& s : e.plan->stages) {
        metrics_
            .GetHistogram("binpick_stage_seconds", "Pipeline stage latency per detection.",
                          LatencyBucketsSeconds(), {{"stage", s.stage}})
            .Observe(s.ms / 1000.0);
      }
      metrics_.GetCounter("binpick_parts_detected_total", "Part instances detected.", {{"task", task}})
          .Inc(e.plan->detections);
      metrics_.GetCounter("binpick_grasps_planned_total", "Grasps queued by detections.",
                          {{"task", task}})
          .Inc(static_cast<double>(e.plan->grasps.size()));
      CountBin(*e.plan, task);
    }
    const std::string outcome =
        !e.scene ? "capture_failed"
                 : e.plan ? std::string(ToString(e.plan->outcome)) : std::string("planner_failed");
    metrics_
        .GetCounter("binpick_detections_total", "Detections (capture + plan) by task and outcome.",
                    {{"task", task}, {"outcome", outcome}})
        .Inc();

    std::lock_guard lock(mutex_);
    Detection& d = last_;
    d.seq = ++detections_;
    d.task_id = e.task_id;
    d.time = e.time;
    d.capture_ms = e.capture_ms;
    d.plan_ms = e.plan_ms;
    d.outcome = outcome;
    d.capture_status = e.capture_status.ok() ? "" : e.capture_status.ToString();
    d.plan_status = e.plan_status.ok() ? "" : e.plan_status.ToString();
    d.scene = e.scene;
    d.X_BF = e.request.X_BF;
    d.queued = e.queued;
    if (e.queued) {
      // What the task's queue was refilled with (nothing when the capture failed).
      queue_.seq = d.seq;
      queue_.task_id = e.task_id;
      queue_.grasps = e.plan ? e.plan->grasps : std::vector<Grasp>{};
    }
    if (e.plan) {
      d.stages = e.plan->stages;
      d.parts = e.plan->parts;
      d.detections = e.plan->detections;
      d.roi_points = e.plan->roi_points;
      d.message = e.plan->message;
      d.bin = e.plan->bin;
      d.fill = e.plan->fill;
    } else {
      d.bin.reset();
      d.fill.reset();
      d.stages.clear();
      d.parts.clear();
      d.detections = 0;
      d.roi_points = 0;
      d.message.clear();
    }
  }

  // Issue 41: the bin's measured offset and fill level of the task's last
  // plan (gauges), bins not found and offset warnings (counters).
  void CountBin(const PlanResult& plan, const std::string& task) {
    if (const std::optional<BinDetection>& bin = plan.bin) {
      metrics_.GetGauge("binpick_bin_found", "1 when the last plan found the bin, 0 when not.", {{"task", task}})
          .Set(bin->found ? 1 : 0);
      if (bin->found) {
        metrics_.GetGauge("binpick_bin_offset_mm", "Measured bin pose from nominal, translation (mm).",
                          {{"task", task}})
            .Set(1e3 * bin->offset);
        metrics_.GetGauge("binpick_bin_offset_deg", "Measured bin pose from nominal, rotation (deg).",
                          {{"task", task}})
            .Set(bin->offset_deg);
      } else {
        metrics_.GetCounter("binpick_bin_not_found_total", "Plans whose bin detection did not find the bin.",
                            {{"task", task}})
            .Inc();
      }
      if (bin->warn) {
        metrics_.GetCounter("binpick_bin_offset_warnings_total",
                            "Plans that found the bin beyond bin.detect_warn from nominal.", {{"task", task}})
            .Inc();
      }
    }
    if (const std::optional<FillLevel>& fill = plan.fill) {
      metrics_.GetGauge("binpick_bin_fill_mean_height_m", "Fill level: mean height over the bin floor (m).",
                        {{"task", task}})
          .Set(fill->mean_height);
      metrics_.GetGauge("binpick_bin_fill_max_height_m", "Fill level: highest point over the bin floor (m).",
                        {{"task", task}})
          .Set(fill->max_height);
      metrics_.GetGauge("binpick_bin_fill_occupied_ratio", "Fill level: occupied share of the bin floor, 0..1.",
                        {{"task", task}})
          .Set(fill->occupied_fraction);
    }
  }

  void OnAnswer(const AnswerEvent& e) {
    const int32_t command = e.request.command;
    const int32_t status = e.response.status;
    const size_t c = LabelIndex(kCommandLabels, command);
    const size_t st = LabelIndex(kStatusLabels, status);
    ResponseCounter(c, st).Inc();
    if (command == daoai::kPickPose) ServedCounter(st).Inc();
    const std::string task = std::to_string(e.request.payload_1);
    if (command == daoai::kPrecisionCheck && status == daoai::kPrecisionCheckSuccess) {
      // payload_1 of the response: the target's distance from its reference, mm x MULT.
      metrics_
          .GetGauge("binpick_precision_error_mm",
                    "Last precision check (command 50) of the task: target distance from its reference, mm.",
                    {{"task", task}})
          .Set(FromFixed(e.response.payload[0]));
    }
    const bool empty_answer = command == daoai::kCheckEmptyBox &&
                              (status == daoai::kBoxEmpty || status == daoai::kBoxNotEmpty);
    // A flip: the task's empty-box answer differs from its previous one. A
    // refill flips it once; flips in quick succession are a flapping rule.
    Counter* flips = empty_answer ? &metrics_.GetCounter("binpick_empty_box_flips_total",
                                                         "Empty-box answers (command 40) unlike the task's "
                                                         "previous answer.",
                                                         {{"task", task}})
                                  : nullptr;
    std::lock_guard lock(mutex_);
    if (flips != nullptr) {
      auto [it, first] = last_empty_answer_.try_emplace(e.request.payload_1, status);
      if (!first && it->second != status) flips->Inc();
      it->second = status;
    }
    Robot& r = robots_[e.peer];
    if (r.answers == 0) r.first_seen = e.time;
    r.client_id = e.client_id;
    r.last_seen = e.time;
    ++r.answers;
    if (e.X_BF) r.X_BF = e.X_BF;
    r.last_command = command;
    r.last_status = status;
    if (robots_.size() > options_.max_robots) {
      auto oldest = robots_.begin();
      for (auto it = robots_.begin(); it != robots_.end(); ++it) {
        if (it->second.last_seen < oldest->second.last_seen) oldest = it;
      }
      robots_.erase(oldest);
    }
    if (daoai::IsCalibrationCommand(command)) {
      Calibration& c = calibration_;
      c.last_command = command;
      c.last_status = status;
      c.time = e.time;
      if (const char* mode = CalibrationModeOf(status)) {
        if (c.mode != mode) c.poses = 0;
        c.mode = mode;
        if (command != daoai::kStartManualCalibration && command != daoai::kStartAutoCalibration &&
            command != daoai::kStart2DAutoCalibration) {
          ++c.poses;
        }
      } else if (status == daoai::kDoneCalibration || status == daoai::kDoneGuidanceCalibration ||
                 status == daoai::kDone2DAutoCalibration) {
        c.mode = "done";
        ++c.completed;
      } else {
        c.mode = "none";
      }
    }
  }

  // A failed pick reported by a robot (command 60): counted per task, class,
  // grasp name and reason; the page lists the totals.
  void OnPickFailure(const PickFailureEvent& e) {
    const auto name = part_names_.find(e.grasp.class_id);
    const std::string klass = name != part_names_.end() ? name->second : std::to_string(e.grasp.class_id);
    const std::string grasp = BaseGraspName(e.grasp.name);
    metrics_
        .GetCounter("binpick_failed_picks_total",
                    "Failed picks reported by robots (command 60) by task, part class, grasp and reason.",
                    {{"task", std::to_string(e.task_id)}, {"class", klass}, {"grasp", grasp},
                     {"reason", std::string(ToString(e.reason))}})
        .Inc();
    std::lock_guard lock(mutex_);
    FailedPickRow& row = failed_picks_[{e.task_id, klass, grasp}];
    ++row.failures;
    row.last_reason = std::string(ToString(e.reason));
    row.last_time = e.time;
    row.last_peer = e.peer;
    if (e.refused) ++row.spots_refused;
  }

  // binpick_responses_total for a (command, status) label index pair: looked
  // up in the registry once, then read from the cache without its mutex.
  Counter& ResponseCounter(size_t command, size_t status) {
    std::atomic<Counter*>& slot = responses_[command][status];
    if (Counter* counter = slot.load(std::memory_order_acquire)) return *counter;
    Counter& counter = metrics_.GetCounter(
        "binpick_responses_total", "Responses written to robots by command and status.",
        {{"command", LabelText(kCommandLabels, command)},
         {"status", LabelText(kStatusLabels, status)}});
    slot.store(&counter, std::memory_order_release);
    return counter;
  }
  Counter& ServedCounter(size_t status) {
    std::atomic<Counter*>& slot = served_[status];
    if (Counter* counter = slot.load(std::memory_order_acquire)) return *counter;
    Counter& counter = metrics_.GetCounter(
        "binpick_grasps_served_total",
        "Pick pose (command 21) responses by status; status 2 handed out a grasp.",
        {{"status", LabelText(kStatusLabels, status)}});
    slot.store(&counter, std::memory_order_release);
    return counter;
  }

  std::string StatusJson() const {
    // Copy under the lock; build JSON outside it.
    Detection d;
    Queue queue;
    std::map<std::string, Robot> robots;
    std::map<std::tuple<int, std::string, std::string>, FailedPickRow> failed_picks;
    Calibration calibration;
    uint64_t detections = 0;
    std::function<int(int)> queue_size;
    QueueContentsProbe queue_contents;
    CalibrationProbe calibration_probe;
    {
      std::lock_guard lock(mutex_);
      d = last_;
      queue = queue_;
      robots = robots_;
      failed_picks = failed_picks_;
      calibration = calibration_;
      detections = detections_;
      queue_size = queue_size_;
      queue_contents = queue_contents_;
      calibration_probe = calibration_probe_;
    }
    d.scene.reset();
    const Clock::time_point now = Clock::now();
    json j;
    j["cell"] = cell_name_;
    j["time"] = IsoTime(now);
    j["uptime_s"] = std::chrono::duration<double>(now - start_).count();
    j["detections"] = detections;

    json tasks = json::array();
    for (const auto& [id, name] : tasks_) {
      json t = {{"id", id}, {"name", name}};
      if (queue_size) t["queue_size"] = queue_size(id);
      tasks.push_back(t);
    }
    j["tasks"] = tasks;

    j["detection"] = detections > 0 ? DetectionJson(d) : json(nullptr);
    j["queue"] = queue.seq > 0 ? QueueJson(queue, queue_size, queue_contents) : json(nullptr);

    json rl = json::array();
    for (const auto& [peer, r] : robots) {
      json rj = {{"peer", peer},
                 {"client_id", r.client_id},
                 {"last_seen", IsoTime(r.last_seen)},
                 {"idle", now - r.last_seen > options_.robot_idle},
                 {"answers", r.answers},
                 {"last_command", r.last_command},
                 {"last_status", r.last_status}};
      rj["pose"] = r.X_BF ? PoseJson(*r.X_BF) : json(nullptr);
      rl.push_back(rj);
    }
    j["robots"] = rl;

    json fp = json::array();
    for (const auto& [key, row] : failed_picks) {
      fp.push_back({{"task", std::get<0>(key)}, {"class", std::get<1>(key)}, {"grasp", std::get<2>(key)},
                    {"failures", row.failures}, {"spots_refused", row.spots_refused},
                    {"last_reason", row.last_reason}, {"last_peer", row.last_peer},
                    {"last_time", IsoTime(row.last_time)}});
    }
    j["failed_picks"] = fp;

    json cal = json::array();
    if (calibration_probe) {
      for (const auto& [k, v] : calibration_probe()) cal.push_back({{"name", k}, {"value", v}});
    } else {
      cal.push_back({{"name", "mode"}, {"value", calibration.mode}});
      cal.push_back({{"name", "poses accumulated"}, {"value", std::to_string(calibration.poses)}});
      cal.push_back({{"name", "calibrations completed"}, {"value", std::to_string(calibration.completed)}});
      if (calibration.last_command != 0) {
        cal.push_back({{"name", "last command / status"},
                       {"value", std::to_string(calibration.last_command) + " / " +
                                     std::to_string(calibration.last_status) + " at " +
                                     IsoTime(calibration.time)}});
      }
    }
    j["calibration"] = cal;

    json errors = json::array();
    for (const LogEntry& e : sink_->Entries()) {
      errors.push_back(
          {{"time", IsoTime(e.time)}, {"level", e.level}, {"logger", e.logger}, {"message", e.message}});
    }
    j["errors"] = errors;
    return j.dump(-1, ' ', false, json::error_handler_t::replace);
  }

  // Encoding a VGA PNG takes tens of ms: the last image of each kind is kept
  // until a new detection or a grasp handed out changes the overlay.
  std::optional<std::vector<uint8_t>> RenderPng(internal::OverlayImage which) const {
    Detection d;
    std::vector<Grasp> grasps;  // drawn when this capture refilled the queue
    int task_id = 0;
    std::function<int(int)> queue_size;
    QueueContentsProbe queue_contents;
    {
      std::lock_guard lock(mutex_);
      if (!last_.scene) return std::nullopt;
      d = last_;
      if (queue_.seq == d.seq) grasps = queue_.grasps;
      task_id = queue_.task_id;
      queue_size = queue_size_;
      queue_contents = queue_contents_;
    }
    const auto* captured = dynamic_cast<const CapturedFrame*>(d.scene.get());
    if (!captured) return std::nullopt;
    const int total = static_cast<int>(grasps.size());
    const int left = queue_size ? std::clamp(queue_size(task_id), 0, total) : total;
    const std::vector<internal::GraspState> states =
        GraspStates(grasps, left, queue_contents ? queue_contents(task_id) : std::nullopt);
    const size_t slot = which == internal::OverlayImage::kDepth ? 0 : 1;
    std::lock_guard cache_lock(png_mutex_);  // HTTP thread only: never contended by robots
    PngCache& cached = png_cache_[slot];
    if (cached.png && cached.seq == d.seq && cached.states == states) return cached.png;
    internal::BinOutline outline;
    outline.X_BW_nominal = bin_.X_BW;
    outline.measured = d.bin;
    outline.inner_size = bin_.inner_size;
    outline.wall_thickness = bin_.wall_thickness;
    cached.png = internal::RenderOverlayPng(captured->frame(), which, d.parts, grasps, states, &outline);
    cached.seq = d.seq;
    cached.states = states;
    return cached.png;
  }

  struct Detection {
    uint64_t seq = 0;
    int task_id = 0;
    Clock::time_point time{};
    double capture_ms = 0, plan_ms = 0;
    std::string outcome, capture_status, plan_status, message;
    CaptureHandle scene;
    std::optional<Pose> X_BF;
    std::vector<StageTime> stages;
    std::vector<DetectedPart> parts;
    bool queued = true;
    int detections = 0;
    int64_t roi_points = 0;
    std::optional<BinDetection> bin;
    std::optional<FillLevel> fill;
  };
  struct Queue {
    uint64_t seq = 0;  // the detection that refilled it; 0: none yet
    int task_id = 0;
    std::vector<Grasp> grasps;
  };

  // The last detection: its outcome, stage times, parts, bin and fill level.
  json DetectionJson(const Detection& d) const {
    json det;
    det["seq"] = d.seq;
    det["queued"] = d.queued;
    det["task"] = d.task_id;
    det["time"] = IsoTime(d.time);
    det["outcome"] = d.outcome;
    det["capture_ms"] = d.capture_ms;
    det["plan_ms"] = d.plan_ms;
    det["capture_status"] = d.capture_status;
    det["plan_status"] = d.plan_status;
    det["message"] = d.message;
    det["detections"] = d.detections;
    det["roi_points"] = d.roi_points;
    json stages = json::array();
    for (const StageTime& s : d.stages) stages.push_back({{"stage", s.stage}, {"ms", s.ms}});
    det["stages"] = stages;
    json parts = json::array();
    for (const DetectedPart& p : d.parts) {
      json pj = PoseJson(p.X_BO);
      pj["class_id"] = p.class_id;
      auto it = part_names_.find(p.class_id);
      pj["class"] = it == part_names_.end() ? "" : it->second;
      pj["score"] = p.score;
      parts.push_back(pj);
    }
    det["parts"] = parts;
    det["bin"] = BinJson(d.bin);
    det["fill"] = d.fill ? json{{"mean_height_m", d.fill->mean_height},
                                {"max_height_m", d.fill->max_height},
                                {"occupied_fraction", d.fill->occupied_fraction}}
                         : json(nullptr);
    return det;
  }

  // The queue: the grasps of the last plan that refilled a queue, each
  // handed out, next, queued or withdrawn (GraspStates). `queue.seq` > 0.
  json QueueJson(const Queue& queue, const std::function<int(int)>& queue_size,
                 const QueueContentsProbe& queue_contents) const {
    const int total = static_cast<int>(queue.grasps.size());
    int left = total;
    if (queue_size) left = std::clamp(queue_size(queue.task_id), 0, total);
    const std::vector<internal::GraspState> states =
        GraspStates(queue.grasps, left, queue_contents ? queue_contents(queue.task_id) : std::nullopt);
    int withdrawn = 0;
    for (internal::GraspState s : states) withdrawn += s == internal::GraspState::kWithdrawn;
    json grasps = json::array();
    for (int i = 0; i < total; ++i) {
      const Grasp& g = queue.grasps[static_cast<size_t>(i)];
      json gj = PoseJson(g.X_BT);
      gj["index"] = i + 1;
      gj["class_id"] = g.class_id;
      auto it = part_names_.find(g.class_id);
      gj["class"] = it == part_names_.end() ? "" : it->second;
      gj["instance_id"] = g.instance_id;
      gj["score"] = g.score;
      gj["name"] = g.name;
      gj["state"] = StateName(states[static_cast<size_t>(i)]);
      grasps.push_back(gj);
    }
    return {{"seq", queue.seq}, {"task", queue.task_id}, {"total", total},
            {"remaining", left}, {"withdrawn", withdrawn}, {"grasps", grasps}};
  }

  struct Robot {
    uint64_t client_id = 0;
    Clock::time_point first_seen{}, last_seen{};
    uint64_t answers = 0;
    std::optional<Pose> X_BF;
    int32_t last_command = 0, last_status = 0;
  };
  struct Calibration {
    std::string mode = "none";
    int poses = 0;
    int completed = 0;
    int32_t last_command = 0, last_status = 0;
    Clock::time_point time{};
  };

  const StatusStateOptions options_;
  MetricsRegistry& metrics_;
  const Clock::time_point start_;
  Histogram& capture_seconds_;
  Histogram& plan_seconds_;
  Counter& captures_ok_;
  Counter& captures_failed_;
  std::string cell_name_;
  BinSpec bin_;  // the cell's nominal bin, for the outline
  std::vector<std::pair<int, std::string>> tasks_;
  std::map<int, std::string> part_names_;
  std::shared_ptr<ErrorSink> sink_;
  // Counters by label index (the last index of each is "other"); null until
  // first used. Written once each, read lock-free.
  std::array<std::array<std::atomic<Counter*>, kStatusLabels.size() + 1>,
             kCommandLabels.size() + 1>
      responses_{};
  std::array<std::atomic<Counter*>, kStatusLabels.size() + 1> served_{};

  // Each grasp's state. With `contents` (the live queue): queued ones are
  // next / queued, withdrawn ones withdrawn, the rest handed out. Without
  // it, the first total - left were handed out (GraspQueue pops from the front).
  static std::vector<internal::GraspState> GraspStates(const std::vector<Grasp>& grasps, int left,
                                                       const std::optional<GraspQueue::Contents>& contents) {
    using internal::GraspState;
    std::vector<GraspState> states(grasps.size(), GraspState::kQueued);
    const int total = static_cast<int>(grasps.size());
    if (!contents) {
      const int served = total - left;
      for (int i = 0; i < total; ++i) {
        states[static_cast<size_t>(i)] = i < served ? GraspState::kServed : i == served ? GraspState::kNext
                                                                                         : GraspState::kQueued;
      }
      return states;
    }
    auto has = [](const std::vector<int>& ids, int id) { return std::find(ids.begin(), ids.end(), id) != ids.end(); };
    for (size_t i = 0; i < grasps.size(); ++i) {
      const int id = grasps[i].instance_id;
      if (has(contents->queued, id)) {
        states[i] = !contents->queued.empty() && contents->queued.front() == id ? GraspState::kNext : GraspState::kQueued;
      } else {
        states[i] = has(contents->withdrawn, id) ? GraspState::kWithdrawn : GraspState::kServed;
      }
    }
    return states;
  }
  static const char* StateName(internal::GraspState s) {
    switch (s) {
      case internal::GraspState::kServed: return "served";
      case internal::GraspState::kNext: return "next";
      case internal::GraspState::kQueued: return "queued";
      case internal::GraspState::kWithdrawn: return "withdrawn";
    }
    return "?";
  }

  struct PngCache {
    uint64_t seq = 0;
    std::vector<internal::GraspState> states;
    std::optional<std::vector<uint8_t>> png;
  };
  mutable std::mutex png_mutex_;
  mutable PngCache png_cache_[2];  // GUARDED_BY(png_mutex_): depth, intensity

  mutable std::mutex mutex_;
  std::function<int(int)> queue_size_;    // GUARDED_BY(mutex_); called outside it
  QueueContentsProbe queue_contents_;     // GUARDED_BY(mutex_); called outside it
  CalibrationProbe calibration_probe_;    // GUARDED_BY(mutex_); called outside it
  Detection last_;                        // GUARDED_BY(mutex_)
  Queue queue_;                           // GUARDED_BY(mutex_)
  uint64_t detections_ = 0;               // GUARDED_BY(mutex_)
  std::map<std::string, Robot> robots_;   // GUARDED_BY(mutex_), by peer
  Calibration calibration_;               // GUARDED_BY(mutex_)
  std::map<int32_t, int32_t> last_empty_answer_;  // GUARDED_BY(mutex_): task -> 41 / 42
  struct FailedPickRow {
    uint64_t failures = 0;
    uint64_t spots_refused = 0;  // reports that took a spot to its max_failures
    std::string last_reason, last_peer;
    std::chrono::system_clock::time_point last_time{};
  };
  // GUARDED_BY(mutex_): (task, class name, grasp name) -> failed picks reported.
  std::map<std::tuple<int, std::string, std::string>, FailedPickRow> failed_picks_;
};

StatusState::StatusState(const Cell& cell, MetricsRegistry& metrics, StatusStateOptions options)
    : impl_(std::make_unique<Impl>(cell, metrics, options)) {}
StatusState::~StatusState() = default;

void StatusState::OnDetection(const DetectionEvent& event) {
  try {
    impl_->OnDetection(event);
  } catch (const std::exception&) {
    // Observers must not throw into the server (allocation failure only).
  }
}

void StatusState::OnAnswer(const AnswerEvent& event) {
  try {
    impl_->OnAnswer(event);
  } catch (const std::exception&) {
  }
}

void StatusState::OnPickFailure(const PickFailureEvent& event) {
  try {
    impl_->OnPickFailure(event);
  } catch (const std::exception&) {
  }
}

void StatusState::SetQueueProbe(std::function<int(int)> queue_size) {
  std::lock_guard lock(impl_->mutex_);
  impl_->queue_size_ = std::move(queue_size);
}
void StatusState::SetQueueContentsProbe(QueueContentsProbe probe) {
  std::lock_guard lock(impl_->mutex_);
  impl_->queue_contents_ = std::move(probe);
}
void StatusState::SetCalibrationProbe(CalibrationProbe probe) {
  std::lock_guard lock(impl_->mutex_);
  impl_->calibration_probe_ = std::move(probe);
}
std::shared_ptr<spdlog::sinks::sink> StatusState::LogSink() { return impl_->sink_; }
std::string StatusState::StatusJson() const { return impl_->StatusJson(); }
std::optional<std::vector<uint8_t>> StatusState::RenderDepthPng() const {
  return impl_->RenderPng(internal::OverlayImage::kDepth);
}
std::optional<std::vector<uint8_t>> StatusState::RenderIntensityPng() const {
  return impl_->RenderPng(internal::OverlayImage::kIntensity);
}

}  // namespace bp
