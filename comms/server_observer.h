// What the server tells observers (recorder, status page, metrics): every
// detection (capture + plan) and every response written to a robot.
//
// Order: OnDetection of a detection that fills a task's queue runs after the
// queue holds its grasps and before the picks waiting for it are answered.
//
// Threading: OnDetection runs on the detection worker that ran it, OnAnswer
// on the transport's thread right after the response is built (before it is
// written). Both can run concurrently from several threads; observers
// synchronize themselves and must return quickly (no blocking I/O on the
// caller's thread: queue it). Exceptions must not escape.
#pragma once

#include <chrono>
#include <cstdint>
#include <optional>
#include <string>

#include "comms/daoai_message.h"
#include "core/pose.h"
#include "core/status.h"
#include "grasp/failed_picks.h"
#include "grasp/planner.h"

namespace bp {

struct DetectionEvent {
  int task_id = 0;
  PlanRequest request;
  // The capture; null when it failed (capture_status says why). A
  // BinPickingPlanner's scene is a CapturedFrame (grasp/bin_picking_planner.h).
  CaptureHandle scene;
  Status capture_status;
  // The plan; nullopt when the capture or the planner failed (plan_status).
  std::optional<PlanResult> plan;
  Status plan_status;
  double capture_ms = 0.0;
  double plan_ms = 0.0;
  std::chrono::system_clock::time_point time{};  // capture start
  // False when the plan did not refill the task's grasp queue (an empty-box
  // check, RC 40): its grasps were never offered to a robot.
  bool queued = true;
};

struct AnswerEvent {
  uint64_t client_id = 0;
  std::string peer;             // "ip:port" or "modbus host:port"
  std::optional<Pose> X_BF;     // the robot's last pose on that connection
  daoai::Request request;
  daoai::Response response;
  std::chrono::system_clock::time_point time{};
};

// A robot reported that the last grasp it was given failed (command 60;
// grasp/failed_picks.h). Sent on the transport's thread, before the answer.
struct PickFailureEvent {
  int task_id = 0;
  uint64_t client_id = 0;
  std::string peer;
  Grasp grasp;  // the grasp that failed, as handed out
  PickFailure reason = PickFailure::kUnspecified;
  int failures_on_spot = 0;  // this one included
  bool refused = false;      // the spot reached max_failures
  int withdrawn = 0;         // queued grasps withheld or refused at once
  std::chrono::system_clock::time_point time{};
};

class ServerObserver {
 public:
  virtual ~ServerObserver() = default;
  virtual void OnPickFailure(const PickFailureEvent& /*event*/) {}
  virtual void OnDetection(const DetectionEvent& /*event*/) {}
  virtual void OnAnswer(const AnswerEvent& /*event*/) {}
};

}  // namespace bp
