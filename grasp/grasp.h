// A grasp handed to a robot: where the tool centre point goes, how it gets
// there, and which part instance it takes. Frames (STYLE.md): B robot base,
// T tool centre point, O part. SI units.
#pragma once

#include <optional>
#include <string>
#include <vector>

#include "core/pose.h"

namespace bp {

struct Grasp {
  Pose X_BT = Pose::Identity();      // tool centre point in base at the grasp
  Pose X_BT_pre = Pose::Identity();  // pre-grasp (approach) pose of the tool in base
  Pose X_BO = Pose::Identity();      // the part instance in base, as detected
  int instance_id = -1;              // detected part instance (per capture)
  int class_id = 0;                  // part class (cell parts[].class_id)
  double score = 0.0;                // planner's ranking score, higher is better
  std::string name;                  // grasp name from the cell (parts[].grasps[].name)
  // Further poses in base the task may need (e.g. a place pose paired with a
  // pick); empty for plain picks.
  std::vector<Pose> related_X_B;
  // instance_id values of the same plan's detected parts (with a queued
  // grasp or without: PlanResult::ungrasped_touching) whose hand-out or
  // movement makes this grasp stale: parts touching this one, and parts its
  // swept gripper passes close to (GraspPlanningOptions::touch_distance,
  // approach_margin). GraspQueue::Pop withdraws it when one of them is
  // handed out or may move (docs/protocols.md, "Stale grasps"). Empty: no
  // part disturbs it (or the planner does not say).
  std::vector<int> stale_after;
  // Of stale_after, the parts that touch this one (within touch_distance at
  // their estimated poses; the relation is symmetric). When one of them may
  // move, this part may move too: GraspQueue then also withdraws the grasps
  // listing THIS part, transitively (docs/protocols.md, "Stale grasps").
  std::vector<int> touching;
  // Tool poses in base the robot program computes from this answer and moves
  // to, when the answer is not itself one (seed 003's place: tool_in_base
  // from place_area's offset). Checked like X_BT (grasp/robot_targets.h).
  std::vector<Pose> implied_X_BT;
  // The bin pose in base the grasp was planned in, when bin detection
  // measured it (PlanResult::bin found); nullopt: the cell's nominal
  // bin.pose. The failed-pick memory keeps spots in this bin frame.
  std::optional<Pose> X_BW;
  // A last resort (GraspCandidate::seal_only): a suction grasp on a
  // detection with alternative poses that lands off its grasp point were an
  // alternative true, offered only because the plan had no other grasp.
  // `binpick clear` names the failed ones (docs/tuning.md).
  bool last_resort = false;
  // Planned on a detection some of whose poses a failed last resort refuted
  // (PlanRequest::refuted): on the poses still live. The failed-pick
  // feedback serves it rather than withholding the spot (a new try there,
  // not the same one).
  bool reposed = false;
};

}  // namespace bp
