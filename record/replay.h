// Replay: reruns the planner over a recorded session (or any directory of
// PCD / PLY / depth PNG files) and compares each result with what was
// recorded, for `binpick replay` and regression tests.
//
// Per capture of a session: the record's cloud.pcd (bit-exact depth, X_BC and
// intrinsics from its sidecar) is planned for the recorded task with the
// recorded robot pose and camera config; per-stage latency, detections and
// the grasp queue are reported, and compared with record.json: outcome,
// detection count, each detected part and each grasp in order (class, name,
// position within tolerance_mm, rotation within tolerance_deg). Records that
// are incomplete or corrupt are skipped with a warning and replay goes on.
#pragma once

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "core/cell.h"
#include "core/status.h"
#include "grasp/planner.h"
#include "pipeline/capture_source.h"

namespace bp {

struct ReplayOptions {
  // Cell to plan with. Empty: the session's cell.yaml (parsed as if it were
  // at the recorded cell path, so relative paths resolve the same), else the
  // embedded default cell for a plain directory.
  std::string cell_path;
  double tolerance_mm = 1.0;
  double tolerance_deg = 1.0;
  // Builds the planner; default: MakePlanner-like (Perception::Build and
  // BinPickingPlanner with in-memory taught grasps). Tests may inject one.
  std::function<Result<std::unique_ptr<GraspPlanner>>(const Cell&, std::unique_ptr<CaptureSource>)> make_planner;
};

struct CaptureReplay {
  std::string file;             // record directory or frame file
  int task_id = 0;
  bool replayed = false;        // false: frame or plan failed (error says why)
  std::string error;
  double plan_ms = 0.0;
  double recorded_plan_ms = -1.0;  // the recorded plan time; -1: none recorded
  PlanResult result;            // the replayed plan (stages = per-stage latency)
  bool compared = false;        // a recorded result existed
  PlanResult recorded;
  std::vector<std::string> differences;  // beyond tolerance; empty = same
  double max_position_diff_mm = 0.0;     // over parts and grasps
  double max_angle_diff_deg = 0.0;
};

struct ReplayReport {
  std::string dir;
  std::string cell;             // where the cell came from
  std::string cell_name;        // the cell's `name` (fleet reports group by it)
  bool session = false;         // a recorded session (else plain files)
  std::vector<CaptureReplay> captures;
  std::vector<std::string> skipped;  // incomplete / corrupt records, with the reason
  int differing = 0;            // captures with differences or that failed to replay
};

// @returns NotFound / InvalidArgument when `dir` or the cell cannot be used;
// per-capture problems are in the report, never a failed Result.
Result<ReplayReport> ReplayDirectory(const std::string& dir, const ReplayOptions& options);

// The report as JSON text (indented): `binpick replay --json`'s file and one
// session of a shard report (record/replay_fleet.h). Schema: docs/fleet.md.
std::string ReplayReportJson(const ReplayReport& report, const ReplayOptions& options);

}  // namespace bp
