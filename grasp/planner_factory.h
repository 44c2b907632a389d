// Builds the product planner for a cell.
#pragma once

#include <memory>
#include <string>

#include "core/cell.h"
#include "core/status.h"
#include "grasp/planner.h"
#include "pipeline/capture_source.h"

namespace bp {

// @returns the planner the cell describes, or Unavailable while the
// perception pipeline is not built (binpickd then refuses to start).
// `hand_eye`: the live hand-eye transform for the capture source
// (MakeCaptureSource, pipeline/capture_source.h). `teach_file`: where taught
// grasps are kept (BinPickingPlannerOptions::teach_file; empty: next to the
// cell file, DefaultTeachFile).
Result<std::unique_ptr<GraspPlanner>> MakePlanner(const Cell& cell, HandEyeProvider hand_eye = {},
                                                  std::string teach_file = "");

}  // namespace bp
