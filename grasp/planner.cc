#include "grasp/planner.h"

#include <utility>

#include "grasp/planner_factory.h"

#include "grasp/bin_picking_planner.h"
#include "pipeline/capture_source.h"
#include "pipeline/perception.h"

namespace bp {

std::string_view ToString(PlanResult::Outcome outcome) {
  switch (outcome) {
    case PlanResult::Outcome::kGrasps: return "grasps";
    case PlanResult::Outcome::kNoObjects: return "no_objects";
    case PlanResult::Outcome::kNoCollisionFree: return "no_collision_free";
    case PlanResult::Outcome::kCaptureFailed: return "capture_failed";
    case PlanResult::Outcome::kPlannerFailed: return "planner_failed";
  }
  return "?";
}

Result<std::unique_ptr<GraspPlanner>> MakePlanner(const Cell& cell, HandEyeProvider hand_eye, std::string teach_file) {
  Result<std::unique_ptr<Perception>> perception = Perception::Build(cell);
  if (!perception.ok()) return perception.status();
  Result<std::unique_ptr<CaptureSource>> source = MakeCaptureSource(cell, std::move(hand_eye));
  if (!source.ok()) return source.status();
  BinPickingPlannerOptions options;
  options.teach_file = std::move(teach_file);
  auto planner = BinPickingPlanner::Create(cell, std::shared_ptr<const Perception>(std::move(*perception)),
                                           std::move(*source), options);
  if (!planner.ok()) return planner.status();
  return std::unique_ptr<GraspPlanner>(std::move(*planner));
}

}  // namespace bp
