// Robot programs of the seeds (000 "通信流程示例", 003 "Robot Program"),
// played over a RobotClient (the DaoAI socket, or Modbus registers through a
// RobotTransport): the robot simulator behind `binpick robot [--modbus]`.
// Each step prints one line: step, command, status, pose, remaining count,
// class and round-trip latency.
#pragma once

#include <optional>
#include <ostream>
#include <string>
#include <vector>

#include "comms/robot_client.h"

namespace bp {

struct FlowOptions {
  std::string flow = "pick";  // see FlowNames()
  int task_id = 0;            // pick / empty-check / precision task (payload_1)
  int place_task_id = 2;      // pick-place: the place task
  // pick-correct-place (seed 003 "抓取 - 物体姿态修正 - 放置"): the in_hand and
  // place_area tasks (the seed's daoai_switch_task(1) and (3)); task_id picks.
  int in_hand_task_id = 1;
  int place_area_task_id = 3;
  // pick-correct-place: the program's taught obj_in_Place, the part's pose in
  // base where it was placed when the place was taught (binpick's cell:
  // fixture taught pose * part_pose). Required by that flow.
  std::optional<Pose> obj_in_place;
  int config_id = 1;          // switch-config
  int max_cycles = 20;        // pick: capture cycles before giving up
  int max_poses = 50;         // calibrations: poses before giving up
  int manual_poses = 9;       // calib-manual: waypoints (seed: Waypoint_1..9)
  bool check_empty = true;    // pick: finish with the empty-box check
  // Calibrations: the pose they start from (default: the detection pose).
  std::optional<Pose> calib_start_X_BF;
};

struct FlowSummary {
  int steps = 0;
  int picks = 0;              // OBJECTS_FOUND / DROP_OFF_POSE received
  int last_status = 0;
  bool ok = true;             // the flow ended the way its robot program expects
  std::vector<double> latencies_ms;
  std::vector<Pose> pick_poses;  // every pick pose received, in order (pick, pick-2d, pick-correct-place)
  // pick-correct-place, per completed cycle: the tool pose the program
  // computed and moved to (tool_in_base), and the answers it came from.
  std::vector<Pose> place_poses;
  std::vector<Pose> obj_in_tool;    // in_hand answers
  std::vector<Pose> place_in_base;  // place_area answers
};

const std::vector<std::string>& FlowNames();
// @returns InvalidArgument for an unknown flow, Unavailable when the
// connection fails; protocol outcomes (no objects, empty box) are in the summary.
Result<FlowSummary> RunFlow(RobotClient& robot, const FlowOptions& options, std::ostream& out);

}  // namespace bp
