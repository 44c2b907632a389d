#include "comms/robot_flows.h"

#include <chrono>
#include <cmath>
#include <cstdio>
#include <functional>
#include <map>
#include <algorithm>

namespace bp {
namespace {

using Clock = std::chrono::steady_clock;

const char* CommandName(int32_t command) {
  switch (command) {
    case daoai::kNoCommand: return "NO_COMMAND";
    case daoai::kStartManualCalibration: return "START_MANUAL_CALIBRATION";
    case daoai::kStopManualCalibration: return "STOP_MANUAL_CALIBRATION";
    case daoai::kStartAutoCalibration: return "START_AUTO_CALIBRATION";
    case daoai::kManualAccumulatePose: return "MANUAL_ACCUMULATE_POSE";
    case daoai::kAutoAccumulatePose: return "AUTO_ACCUMULATE_POSE";
    case daoai::kGuidanceCalibration: return "GUIDANCE_CALIBRATION";
    case daoai::kStart2DAutoCalibration: return "START_2D_AUTO_CALIBRATION";
    case daoai::kAutoAccumulate2DPose: return "AUTO_ACCUMULATE_2D_POSE";
    case daoai::kCaptureAndProcessAsync: return "CAPTURE_AND_PROCESS_ASYNC";
    case daoai::kCaptureAndProcess: return "CAPTURE_AND_PROCESS";
    case daoai::kPickPose: return "PICK_POSE";
    case daoai::kSendPose: return "SEND_POSE";
    case daoai::kCheckEmptyBox: return "CHECK_EMPTY_BOX";
    case daoai::kPrecisionCheck: return "PRECISION_CHECK";
    case daoai::kSwitchConfig: return "SWITCH_CONFIG";
    default: return "?";
  }
}

// Where the simulated robot waits while the camera captures (seed:
// detection_pose): above the bin, tool pointing down.
Pose DetectionPose() {
  return MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), Vec3(0.4, -0.3, 0.6));
}

// 2D flows (seed 000 send_robot_data_2d / recv_daoai_data_2d): the robot
// sends and receives its tool pose in its plane frame P. Its capture / centre
// pose: 0.3 m above the plane origin, tool pointing down.
Pose PlaneCentrePose() {
  return MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), Vec3(0.0, 0.0, 0.3));
}

// seed 003 adjust_det_pose: where the robot shows the camera the part it
// holds: 0.5 m under the default cell's camera, turned 0.4 rad about the
// vertical so a part's features are not axis-aligned, the tool tilted 35 deg
// off the line of sight so the camera sees the part's sides (pointing
// straight at the camera, a part hides what it has toward the flange).
Pose AdjustDetectionPose() {
  return MakePose(Mat3(Eigen::AngleAxisd(0.4, Vec3::UnitZ()) * Eigen::AngleAxisd(35.0 * M_PI / 180, Vec3::UnitX())),
                  Vec3(0.7, 0.0, 0.55));
}

class Runner {
 public:
  Runner(RobotClient& robot, std::ostream& out) : robot_(robot), out_(out) {}

  // A request whose robot script reads the answer.
  Result<RobotReply> Call(int32_t command, int32_t payload_1 = 0) {
    const auto t0 = Clock::now();
    Result<RobotReply> reply = robot_.Call(command, payload_1);
    const double ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    ++summary_.steps;
    if (!reply.ok()) {
      Print(command, payload_1, "ERROR " + reply.status().ToString(), nullptr, ms);
      return reply;
    }
    summary_.latencies_ms.push_back(ms);
    summary_.last_status = reply->status;
    Print(command, payload_1, DaoaiStatusName(reply->status, robot_.options().dialect) + "(" +
                                  std::to_string(reply->status) + ")",
          &*reply, ms);
    for (const std::string& w : reply->warnings) out_ << "      popup: " << w << "\n";
    return reply;
  }

  // A request whose robot script reads no answer.
  Status Send(int32_t command, int32_t payload_1 = 0) {
    const auto t0 = Clock::now();
    Status s = robot_.Send(command, payload_1);
    const double ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
    ++summary_.steps;
    Print(command, payload_1, s.ok() ? "sent (no response)" : "ERROR " + s.ToString(), nullptr, ms);
    return s;
  }

  FlowSummary& summary() { return summary_; }

 private:
  void Print(int32_t command, int32_t payload_1, const std::string& status,
             const RobotReply* reply, double ms) {
    char line[512];
    std::snprintf(line, sizeof(line), "[%3d] %s(%d) p1=%d -> %s", summary_.steps,
                  CommandName(command), command, payload_1, status.c_str());
    out_ << line;
    if (reply && (reply->status == daoai::kObjectsFound || reply->status == daoai::kDropOffPose ||
                  reply->status == daoai::kModeAutoCalibration ||
                  reply->status == daoai::kMode2DAutoCalibration)) {
      const auto& r = reply->raw;
      std::snprintf(line, sizeof(line), " pose [%.4f %.4f %.4f | %.4f %.4f %.4f %.4f]",
                    FromFixed(r.position[0]), FromFixed(r.position[1]), FromFixed(r.position[2]),
                    FromFixed(r.orientation[0]), FromFixed(r.orientation[1]),
                    FromFixed(r.orientation[2]), FromFixed(r.orientation[3]));
      out_ << line;
    }
    if (reply && (reply->status == daoai::kObjectsFound || reply->status == daoai::kDropOffPose ||
                  command == daoai::kPickPose)) {
      std::snprintf(line, sizeof(line), " remaining %g class %g", reply->payload[0],
                    reply->payload[1]);
      out_ << line;
    }
    if (reply && reply->status == daoai::kPrecisionCheckSuccess) {
      std::snprintf(line, sizeof(line), " error %.3f mm", reply->payload[0]);
      out_ << line;
    }
    std::snprintf(line, sizeof(line), "  %.3f ms\n", ms);
    out_ << line;
  }

  RobotClient& robot_;
  std::ostream& out_;
  FlowSummary summary_;
};

// seed 003 daoai_get_picking_pose(): true when the robot has a pose to move to.
bool PickPoseOk(const RobotReply& r) {
  if (r.status == daoai::kNoObjectFound || r.status == daoai::kNoCollisionFreePose) return false;
  return r.payload[0] > 0;
}

// seed 003 daoai_capture_and_process(): move to `at` and capture for
// `task`. @returns false (and marks the flow failed) when the server did not
// acknowledge the capture.
Result<bool> CaptureAt(RobotClient& robot, Runner& run, int task, const Pose& at) {
  robot.SetPose(at);
  Result<RobotReply> cap = run.Call(daoai::kCaptureAndProcess, task);
  if (!cap.ok()) return cap.status();
  if (cap->status != daoai::kDetection) {
    run.summary().ok = false;  // popup("DaoAI Image Capture Failed.")
    return false;
  }
  return true;
}

Result<bool> CaptureAtDetectionPose(RobotClient& robot, Runner& run, int task) {
  return CaptureAt(robot, run, task, DetectionPose());
}

// The seed's pick program: capture at `home`, then pick poses until none is
// left (moving to `target(pick pose)` and back to `home` after each),
// re-capture while a cycle picked something; finally the empty-box check.
Status PickLoop(RobotClient& robot, Runner& run, const FlowOptions& o, const Pose& home,
                const std::function<Pose(const Pose&)>& target) {
  FlowSummary& s = run.summary();
  for (int cycle = 0; cycle < o.max_cycles; ++cycle) {
    Result<bool> captured = CaptureAt(robot, run, o.task_id, home);
    if (!captured.ok()) return captured.status();
    if (!*captured) return Status::Ok();
    int picked = 0;
    for (;;) {
      Result<RobotReply> pick = run.Call(daoai::kPickPose, o.task_id);
      if (!pick.ok()) return pick.status();
      if (!PickPoseOk(*pick)) break;
      ++picked;
      ++s.picks;
      if (pick->X_BT) {
        s.pick_poses.push_back(*pick->X_BT);
        robot.SetPose(target(*pick->X_BT));  // MoveL pick_pose
      }
      robot.SetPose(home);  // MoveL detection_pose
    }
    if (picked == 0) break;  // nothing more to pick from this bin
  }
  if (o.check_empty) {
    Result<RobotReply> empty = run.Call(daoai::kCheckEmptyBox, o.task_id);
    if (!empty.ok()) return empty.status();
    s.ok = empty->status == daoai::kBoxEmpty;
  }
  return Status::Ok();
}

Status PickFlow(RobotClient& robot, Runner& run, const FlowOptions& o) {
  return PickLoop(robot, run, o, DetectionPose(), [](const Pose& X_BT) { return X_BT; });
}

// seed 000 daoai_capture_and_process_2d() + daoai_get_picking_pose_2d(): as
// the pick flow, every pose in the plane frame; recv_daoai_data_2d() keeps
// the robot's current z (daoai_tcp_pose[2] = cur_pose[2]).
Status Pick2DFlow(RobotClient& robot, Runner& run, const FlowOptions& o) {
  return PickLoop(robot, run, o, PlaneCentrePose(), [&robot](const Pose& X_PT) {
    Pose moved = X_PT;
    moved.translation().z() = robot.pose().translation().z();  // the robot overwrites z
    return moved;
  });
}

Status PickPlaceFlow(RobotClient& robot, Runner& run, const FlowOptions& o) {
  FlowSummary& s = run.summary();
  for (int cycle = 0; cycle < o.max_cycles; ++cycle) {
    Result<bool> captured = CaptureAtDetectionPose(robot, run, o.task_id);
    if (!captured.ok()) return captured.status();
    if (!*captured) return Status::Ok();
    Result<RobotReply> pick = run.Call(daoai::kPickPose, o.task_id);
    if (!pick.ok()) return pick.status();
    if (!PickPoseOk(*pick)) return Status::Ok();
    ++s.picks;
    if (pick->X_BT) robot.SetPose(*pick->X_BT);
    captured = CaptureAtDetectionPose(robot, run, o.place_task_id);
    if (!captured.ok()) return captured.status();
    if (!*captured) return Status::Ok();
    Result<RobotReply> place = run.Call(daoai::kPickPose, o.place_task_id);
    if (!place.ok()) return place.status();
    if (place->status != daoai::kDropOffPose) {
      s.ok = false;
      return Status::Ok();
    }
    if (place->X_BT) robot.SetPose(*place->X_BT);  // MoveJ pick_pose (the drop-off)
  }
  return Status::Ok();
}

// seed 003's daoai_capture_and_process() then daoai_get_picking_pose() at
// `at`: the answer's pose, or none (the program stays in its stage).
Result<std::optional<Pose>> CaptureAndAsk(RobotClient& robot, Runner& run, int task, const Pose& at) {
  Result<bool> captured = CaptureAt(robot, run, task, at);
  if (!captured.ok()) return captured.status();
  if (!*captured) return std::optional<Pose>();
  Result<RobotReply> reply = run.Call(daoai::kPickPose, task);
  if (!reply.ok()) return reply.status();
  if (!PickPoseOk(*reply) || !reply->X_BT) return std::optional<Pose>();
  return std::optional<Pose>(*reply->X_BT);
}

// seed 003 "Robot Program", one pass of its stages per cycle: pick (task 0)
// from detection_pose, look at the part in the gripper (task 1) at
// adjust_det_pose (obj_in_tool), look at the place area (task 3) from
// place_det_pose (place_in_base), then tool_in_base = place_in_base *
// obj_in_Place * obj_in_tool^-1, reached through pre_drop_pose (0.1 m above).
// A stage without an answer ends the flow: the pick stage's as the pick
// flow's (nothing left), the other two as a failure.
Status PickCorrectPlaceFlow(RobotClient& robot, Runner& run, const FlowOptions& o) {
  FlowSummary& s = run.summary();
  if (!o.obj_in_place) return Status::InvalidArgument("pick-correct-place needs the taught obj_in_Place");
  for (int cycle = 0; cycle < o.max_cycles; ++cycle) {
    Result<std::optional<Pose>> pick = CaptureAndAsk(robot, run, o.task_id, DetectionPose());
    if (!pick.ok()) return pick.status();
    if (!*pick) return Status::Ok();
    ++s.picks;
    s.pick_poses.push_back(**pick);
    robot.SetPose(**pick);  // MoveJ pick_pose
    Result<std::optional<Pose>> obj_in_tool = CaptureAndAsk(robot, run, o.in_hand_task_id, AdjustDetectionPose());
    if (!obj_in_tool.ok()) return obj_in_tool.status();
    Result<std::optional<Pose>> place_in_base =
        *obj_in_tool ? CaptureAndAsk(robot, run, o.place_area_task_id, DetectionPose())
                     : Result<std::optional<Pose>>(std::optional<Pose>());
    if (!place_in_base.ok()) return place_in_base.status();
    if (!*obj_in_tool || !*place_in_base) {
      s.ok = false;
      return Status::Ok();
    }
    const Pose obj_in_base = **place_in_base * *o.obj_in_place;
    const Pose tool_in_base = obj_in_base * (**obj_in_tool).inverse();
    const Pose pre_drop = MakePose(Mat3::Identity(), Vec3(0, 0, 0.1)) * tool_in_base;
    robot.SetPose(pre_drop);      // MoveJ pre_drop_pose
    robot.SetPose(tool_in_base);  // MoveJ tool_in_base
    robot.SetPose(pre_drop);
    s.obj_in_tool.push_back(**obj_in_tool);
    s.place_in_base.push_back(**place_in_base);
    s.place_poses.push_back(tool_in_base);
  }
  return Status::Ok();
}

Status ManualCalibrationFlow(RobotClient& robot, Runner& run, const FlowOptions& o) {
  FlowSummary& s = run.summary();
  const Pose start_pose = o.calib_start_X_BF.value_or(DetectionPose());
  robot.SetPose(start_pose);
  Result<RobotReply> start = run.Call(daoai::kStartManualCalibration);
  if (!start.ok()) return start.status();
  if (start->status != daoai::kModeCalibration) {
    s.ok = false;
    return Status::Ok();
  }
  for (int i = 0; i < o.manual_poses; ++i) {
    // MoveJ Waypoint_i: deterministic turns of the flange about different
    // axes (a hand-eye calibration needs rotations) and small offsets.
    static const Vec3 kAxes[] = {Vec3(1, 0, 0), Vec3(0, 1, 0), Vec3(0, 0, 1), Vec3(1, 1, 0), Vec3(1, -1, 0),
                                 Vec3(0, 1, 1), Vec3(1, 0, -1), Vec3(1, 1, 1), Vec3(-1, 1, 1)};
    const double angle = (i % 2 == 0 ? 1.0 : -1.0) * (i == 0 ? 0.0 : 10.0 + 2.0 * (i % 3)) * M_PI / 180.0;
    const Pose X = start_pose * MakePose(Mat3(Eigen::AngleAxisd(angle, kAxes[i % 9].normalized())),
                                         Vec3(0.01 * (i % 3 - 1), 0.01 * (i / 3 % 3 - 1), 0.0));
    robot.SetPose(X);
    Result<RobotReply> acc = run.Call(daoai::kManualAccumulatePose);
    if (!acc.ok()) return acc.status();
    if (acc->status != daoai::kModeCalibration) {
      s.ok = false;
      return Status::Ok();
    }
  }
  // daoai_stop_manual_calibration(): seed 000 reads no answer, seed 004
  // reads UNKNOWN_COMMAND as the acknowledgement.
  if (robot.options().dialect == DaoaiDialect::kSocketV1) {
    Result<RobotReply> stop = run.Call(daoai::kStopManualCalibration);
    if (!stop.ok()) return stop.status();
    s.ok = stop->status == daoai::kUnknownCommand;
    return Status::Ok();
  }
  return run.Send(daoai::kStopManualCalibration);
}

Status AutoCalibrationFlow(RobotClient& robot, Runner& run, const FlowOptions& o, bool two_d) {
  FlowSummary& s = run.summary();
  const int32_t start_cmd = two_d ? daoai::kStart2DAutoCalibration : daoai::kStartAutoCalibration;
  const int32_t acc_cmd = two_d ? daoai::kAutoAccumulate2DPose : daoai::kAutoAccumulatePose;
  const int32_t mode = two_d ? daoai::kMode2DAutoCalibration : daoai::kModeAutoCalibration;
  const int32_t done = two_d ? daoai::kDone2DAutoCalibration : daoai::kDoneCalibration;
  // 2D: the tool-mounted marker touches the plane (z = 0 in P).
  Pose centre = PlaneCentrePose();
  centre.translation().z() = 0.0;
  robot.SetPose(o.calib_start_X_BF.value_or(two_d ? centre : DetectionPose()));  // MoveJ center_pose
  Result<RobotReply> start = run.Call(start_cmd);
  if (!start.ok()) return start.status();
  if (start->status != mode) {
    s.ok = false;
    return Status::Ok();
  }
  for (int i = 0; i < o.max_poses; ++i) {
    Result<RobotReply> acc = run.Call(acc_cmd);
    if (!acc.ok()) return acc.status();
    if (acc->status == done) return Status::Ok();
    if (acc->status != mode) {
      s.ok = false;
      return Status::Ok();
    }
    if (acc->X_BT) robot.SetPose(*acc->X_BT);  // MoveL calibra_pose
  }
  s.ok = false;  // never told to stop
  return Status::Ok();
}

Status GuidanceCalibrationFlow(RobotClient& robot, Runner& run, const FlowOptions& o) {
  FlowSummary& s = run.summary();
  robot.SetPose(o.calib_start_X_BF.value_or(DetectionPose()));
  if (robot.options().dialect != DaoaiDialect::kSocketV1) {
    // Seed 000: daoai_guidance_accumulate_calibration() sends
    // and reads nothing; the robot program sends one pose per waypoint.
    for (int i = 0; i < o.manual_poses; ++i) {
      if (Status st = run.Send(daoai::kGuidanceCalibration); !st.ok()) return st;
    }
    return Status::Ok();
  }
  for (int i = 0; i < o.max_poses; ++i) {
    Result<RobotReply> r = run.Call(daoai::kGuidanceCalibration);
    if (!r.ok()) return r.status();
    if (r->status == daoai::kDoneGuidanceCalibration) return Status::Ok();
    if (r->status != daoai::kGuidanceGood && r->status != daoai::kGuidanceBad) {
      s.ok = false;
      return Status::Ok();
    }
  }
  s.ok = false;
  return Status::Ok();
}

}  // namespace

const std::vector<std::string>& FlowNames() {
  static const std::vector<std::string> kNames = {
      "pick",        "pick-place",    "pick-correct-place", "calib-manual", "calib-auto", "calib-auto-2d",
      "calib-guidance", "empty-check", "teach",      "switch-config", "precision", "pick-2d"};
  return kNames;
}

Result<FlowSummary> RunFlow(RobotClient& robot, const FlowOptions& o, std::ostream& out) {
  Runner run(robot, out);
  FlowSummary& s = run.summary();
  Status st;
  if (o.flow == "pick") {
    st = PickFlow(robot, run, o);
  } else if (o.flow == "pick-2d") {
    st = Pick2DFlow(robot, run, o);
  } else if (o.flow == "pick-place") {
    st = PickPlaceFlow(robot, run, o);
  } else if (o.flow == "pick-correct-place") {
    st = PickCorrectPlaceFlow(robot, run, o);
  } else if (o.flow == "calib-manual") {
    st = ManualCalibrationFlow(robot, run, o);
  } else if (o.flow == "calib-auto") {
    st = AutoCalibrationFlow(robot, run, o, /*two_d=*/false);
  } else if (o.flow == "calib-auto-2d") {
    st = AutoCalibrationFlow(robot, run, o, /*two_d=*/true);
  } else if (o.flow == "calib-guidance") {
    st = GuidanceCalibrationFlow(robot, run, o);
  } else if (o.flow == "empty-check") {
    Result<RobotReply> r = run.Call(daoai::kCheckEmptyBox, o.task_id);
    st = r.status();
    if (r.ok()) s.ok = r->status == daoai::kBoxEmpty || r->status == daoai::kBoxNotEmpty;
  } else if (o.flow == "teach") {
    // daoai_teach_pose(): the robot stands at the taught grasp and sends it.
    st = run.Send(daoai::kSendPose, o.task_id);
  } else if (o.flow == "switch-config") {
    Result<RobotReply> r = run.Call(daoai::kSwitchConfig, o.config_id);
    st = r.status();
    if (r.ok()) s.ok = r->status == daoai::kSwitchConfigSuccess;
  } else if (o.flow == "precision") {
    Result<RobotReply> r = run.Call(daoai::kPrecisionCheck, o.task_id);
    st = r.status();
    if (r.ok()) s.ok = r->status == daoai::kPrecisionCheckSuccess;
  } else {
    return Status::InvalidArgument("unknown flow '" + o.flow + "'");
  }
  if (!st.ok()) return st;
  if (!s.latencies_ms.empty()) {
    std::vector<double> sorted = s.latencies_ms;
    std::sort(sorted.begin(), sorted.end());
    char line[160];
    std::snprintf(line, sizeof(line), "%s: %d steps, %d picks, median %.3f ms, max %.3f ms, %s\n",
                  o.flow.c_str(), s.steps, s.picks, sorted[sorted.size() / 2], sorted.back(),
                  s.ok ? "ok" : "FAILED");
    out << line;
  } else {
    out << o.flow << ": " << s.steps << " steps, " << (s.ok ? "ok" : "FAILED") << "\n";
  }
  return s;
}

}  // namespace bp
