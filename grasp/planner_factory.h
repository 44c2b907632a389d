// Builds the product planner for a cell.
#pragma once

#include <memory>

#include "core/cell.h"
#include "core/status.h"
#include "grasp/planner.h"

namespace bp {

// @returns the planner the cell describes, or Unavailable while the
// perception pipeline is not built (binpickd then refuses to start).
Result<std::unique_ptr<GraspPlanner>> MakePlanner(const Cell& cell);

}  // namespace bp
