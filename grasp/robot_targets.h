// Every pose binpick sends a robot to is checked against the robot's
// workspace before it is sent (issue 44; docs/protocols.md "Workspace"): a
// pose outside is never sent, the robot gets the protocol's failure code and
// the log names the pose and the limit it broke.
//
// The robot moves its tool centre point; the workspace bounds its flange:
// X_BF = X_BT * X_FT^-1 with the task's gripper (identity when the cell does
// not describe it).
#pragma once

#include <string>
#include <vector>

#include "core/cell.h"
#include "core/status.h"
#include "grasp/grasp.h"
#include "grasp/planner.h"

namespace bp {

// The tool poses in base an answer of `task` with `grasp` sends the robot to:
//   pick, precision, place  X_BT and X_BT_pre (seed 000: MoveL pick_pose; the
//                           drop-off is moved to like a pick pose);
//   in_hand, place_area     grasp.implied_X_BT (their X_BT is a relative pose:
//                           X_TO, the offset X_off);
//   pick_2d                 none: its poses are in the robot's plane frame,
//                           which binpick does not know in base.
std::vector<Pose> RobotTargets(const TaskSpec& task, const Grasp& grasp);

// OK when the flange is inside cell.robot.workspace at every RobotTargets
// pose; else OutOfRange: "tool pose (x, y, z | rx, ry, rz) puts the flange at
// (...) m ... outside robot.workspace: z -0.300 < min -0.200".
Status CheckRobotTargets(const Cell& cell, const TaskSpec& task, const Grasp& grasp);

// The same for one tool pose of the task's gripper.
Status CheckToolPose(const Cell& cell, const std::string& gripper, const Pose& X_BT);

// The gate a plan passes before its grasps are queued for the robot: removes
// every grasp CheckRobotTargets refuses, each logged (task, instance, the
// pose and the limit it broke). When none is left of a plan that had some,
// the outcome says so in the task's vocabulary: kNoCollisionFree (no safe
// pose: seed 000's NO_COLLISION_FREE_POSE, 4) for pick, precision and place;
// kNoObjects for in_hand and place_area, whose answers seed 003 lists as 2
// or 3 only. @returns the grasps removed.
int DropUnreachable(const Cell& cell, const TaskSpec& task, PlanResult& result);

}  // namespace bp
