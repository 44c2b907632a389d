// What the status page and /metrics show, collected from the server's
// observer events (comms/server_observer.h) and the log.
//
// StatusState owns the page's state: the latest detection (its capture handle,
// plan, stage times), the robots seen with their last pose and answer, the
// calibration state seen in answers, and the last warnings/errors (a spdlog
// sink). It also counts the metrics of those events into a MetricsRegistry.
//
// Threading: OnDetection / OnAnswer run on detection workers and transport
// threads; they take the state mutex for a copy of a few fields (no image
// work, no I/O) and return. The HTTP thread reads through the *Json() and
// Render*Png() members, which copy under the mutex and do the work (JSON,
// PNG encoding) outside it, so a page load never delays a robot.
#pragma once

#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "comms/server_observer.h"
#include "core/cell.h"
#include "grasp/grasp_queue.h"
#include "web/metrics.h"

namespace spdlog::sinks {
class sink;
}

namespace bp {

struct StatusStateOptions {
  size_t max_errors = 50;      // warnings and errors kept for the page
  size_t max_robots = 32;      // robots listed (the least recently seen are dropped)
  // A robot not heard from for this long is listed as idle.
  std::chrono::seconds robot_idle{60};
};

class StatusState final : public ServerObserver {
 public:
  StatusState(const Cell& cell, MetricsRegistry& metrics, StatusStateOptions options = {});
  ~StatusState() override;
  StatusState(const StatusState&) = delete;
  StatusState& operator=(const StatusState&) = delete;

  void OnDetection(const DetectionEvent& event) override;
  void OnAnswer(const AnswerEvent& event) override;
  // Counts binpick_failed_picks_total and lists the totals on the page.
  void OnPickFailure(const PickFailureEvent& event) override;

  // Grasps left in a task's queue (RequestHandler::QueueSize), so the page
  // can mark the grasps already handed out. Thread-safe; called on the HTTP thread.
  void SetQueueProbe(std::function<int(int task_id)> queue_size);
  // The queued and withdrawn grasps of a task (RequestHandler::QueueContents):
  // with it the page tells grasps handed out from grasps withdrawn as stale
  // (docs/protocols.md, "Stale grasps"); without it, every grasp no longer
  // queued counts as handed out. Thread-safe; called on the HTTP thread.
  using QueueContentsProbe = std::function<std::optional<GraspQueue::Contents>(int task_id)>;
  void SetQueueContentsProbe(QueueContentsProbe probe);
  // Calibration hook: rows (name, value) shown under "Calibration", replacing
  // what the state infers from answers (mode, poses accumulated, last status).
  // The calibration engine sets it once it has a state to show. Thread-safe;
  // called on the HTTP thread, so it must be quick and thread-safe itself.
  using CalibrationProbe = std::function<std::vector<std::pair<std::string, std::string>>()>;
  void SetCalibrationProbe(CalibrationProbe probe);
  // A sink keeping the last max_errors warnings and errors (and counting
  // binpick_log_messages_total). Add it to the loggers whose errors the page shows.
  std::shared_ptr<spdlog::sinks::sink> LogSink();

  // GET /api/status: the whole page state as one JSON document (docs/status_page.md).
  std::string StatusJson() const;
  // The latest capture's depth (colour-mapped) or intensity image with the
  // detected parts and the grasp queue drawn on it, PNG-encoded. nullopt when
  // there is no organized frame to show (no capture yet, or a planner whose
  // scene is not a Frame).
  std::optional<std::vector<uint8_t>> RenderDepthPng() const;
  std::optional<std::vector<uint8_t>> RenderIntensityPng() const;

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace bp
