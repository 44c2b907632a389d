#include "grasp/robot_targets.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstdio>

namespace bp {

std::vector<Pose> RobotTargets(const TaskSpec& task, const Grasp& grasp) {
  switch (task.kind) {
    case TaskSpec::Kind::kPick:
    case TaskSpec::Kind::kPrecision:
    case TaskSpec::Kind::kPlace:
      return {grasp.X_BT, grasp.X_BT_pre};
    case TaskSpec::Kind::kInHand:
    case TaskSpec::Kind::kPlaceArea:
      return grasp.implied_X_BT;
    case TaskSpec::Kind::kPick2D:
      return {};
  }
  return {};
}

Status CheckToolPose(const Cell& cell, const std::string& gripper, const Pose& X_BT) {
  const GripperSpec* spec = cell.FindGripper(gripper);
  const Pose X_BF = spec ? Pose(X_BT * spec->X_FT.inverse()) : X_BT;
  Status s = CheckWorkspace(cell.robot, X_BF);
  if (s.ok()) return s;
  const Vec3 t = X_BT.translation();
  const Eigen::AngleAxisd r(X_BT.linear());
  const Vec3 v = r.angle() * r.axis();
  char pose[160];
  std::snprintf(pose, sizeof(pose), "tool pose (%.3f, %.3f, %.3f m | rotation vector %.3f, %.3f, %.3f rad) puts the ",
                t.x(), t.y(), t.z(), v.x(), v.y(), v.z());
  return Status::OutOfRange(pose + s.message());
}

Status CheckRobotTargets(const Cell& cell, const TaskSpec& task, const Grasp& grasp) {
  for (const Pose& X_BT : RobotTargets(task, grasp)) {
    if (Status s = CheckToolPose(cell, task.gripper, X_BT); !s.ok()) return s;
  }
  return Status::Ok();
}

int DropUnreachable(const Cell& cell, const TaskSpec& task, PlanResult& result) {
  const size_t before = result.grasps.size();
  std::erase_if(result.grasps, [&](const Grasp& g) {
    const Status inside = CheckRobotTargets(cell, task, g);
    if (inside.ok()) return false;
    spdlog::error("task {}: {} on instance {} is not sent: {}", task.id, g.name.empty() ? "grasp" : g.name,
                  g.instance_id, inside.message());
    return true;
  });
  const int dropped = static_cast<int>(before - result.grasps.size());
  if (dropped > 0 && result.grasps.empty() && result.outcome == PlanResult::Outcome::kGrasps) {
    const bool seed003 = task.kind == TaskSpec::Kind::kInHand || task.kind == TaskSpec::Kind::kPlaceArea;
    result.outcome = seed003 ? PlanResult::Outcome::kNoObjects : PlanResult::Outcome::kNoCollisionFree;
    result.message += (result.message.empty() ? "" : "; ") + std::to_string(dropped) +
                      " answer(s) outside robot.workspace, none sent";
  }
  return dropped;
}

}  // namespace bp
