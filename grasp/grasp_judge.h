// Judging a grasp against the true scene, as a robot would experience it
// (binpick eval's grasp figure, binpick clear's picks; docs/perception.md,
// "How figures are measured").
//
// A grasp lands on its part when the tool centre is within max_position of
// the grasp's own point on a true part of the grasp's class (the point the
// grasp was planned at, in that part's frame, modulo the part's symmetry), and
// the tool's approach (+z of T) is within the gripper's compliance of the
// grasp's approach on that part. The grasp's approach is the cell grasp's
// (taught grasps: as planned), so a suction candidate turned toward vertical
// ("~v", GraspPlanningOptions::suction_compliance_deg) or round its approach
// ("~v+45", suction_turn_azimuths_deg) spends part of the cup's compliance by
// design and the pose error spends the rest.
#pragma once

#include <span>
#include <string>
#include <vector>

#include "core/cell.h"
#include "grasp/grasp.h"
#include "grasp/grasp_planning.h"
#include "pipeline/evaluation.h"
#include "pipeline/frame.h"

namespace bp {

struct GraspJudgeOptions {
  // Tool centre to the grasp point on the true part, metres: 2 mm, the
  // contact error a suction cup or a jaw of the default cell absorbs.
  double max_position = 0.002;
  // Suction: the cup's compliance (the planner's suction_compliance_deg).
  // Parallel jaws have none in the planner; the judge allows this, radians
  // (the strict pose tolerance's 5 deg).
  double parallel_jaw_approach = 5.0 * 3.14159265358979323846 / 180.0;
};

// Judges `grasp` (planned by `model` for `gripper` on a detection of
// grasp.class_id at grasp.X_BO) against the true parts. Fills every field of
// the outcome except `detection`.
GraspOutcome JudgeGrasp(const GraspPlanningModel& model, const std::string& gripper, const Grasp& grasp,
                        std::span<const PartTruth> truth, const GraspJudgeOptions& options = {});

// What the swept gripper of a pick hits in the true scene: the bin standing
// at X_BW and the true parts. The part the tool touches down on is checked
// as the plan checks a grasp's own part, with the gripper lifted by the
// planner's contact_margin (the cup meets its surface by design); every
// other part is checked whole. The part touched down on is the landing's
// part when the grasp lands at its grasp point (`outcome.on_part`), else
// the true part whose surface lies nearest the tool centre, if within
// contact_margin (a grasp planned on a wrong pose puts the cup on the part
// off its grasp point: a failed pick, not a collision with it), else none.
struct PickContact {
  std::optional<RejectReason> hit;  // nullopt: collision-free
  int touched = -1;                 // index into the truth of the part touched down on, -1 none
  std::vector<Detection> parts;     // the truth as detections, in its order (what `hit` was checked against)
};
PickContact CheckPickOnTruth(const GraspPlanningModel& model, const std::string& gripper, const Grasp& grasp,
                             std::span<const PartTruth> truth, const GraspOutcome& outcome, const Pose& X_BW);

}  // namespace bp
