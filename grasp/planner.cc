#include "grasp/planner.h"

#include "grasp/planner_factory.h"

namespace bp {

std::string_view ToString(PlanResult::Outcome outcome) {
  switch (outcome) {
    case PlanResult::Outcome::kGrasps: return "grasps";
    case PlanResult::Outcome::kNoObjects: return "no_objects";
    case PlanResult::Outcome::kNoCollisionFree: return "no_collision_free";
    case PlanResult::Outcome::kCaptureFailed: return "capture_failed";
  }
  return "?";
}

Result<std::unique_ptr<GraspPlanner>> MakePlanner(const Cell& /*cell*/) {
  return Status::Unavailable("perception pipeline not built yet: no grasp planner available");
}

}  // namespace bp
