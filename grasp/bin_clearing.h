// Closed-loop bin clearing in simulation (`binpick clear`): render -> detect
// -> take the first grasp -> remove that part from the pile and let the rest
// resettle, until the queue is empty; then the empty-box check. Each chosen
// grasp is judged against GROUND TRUTH (the true part meshes at their true
// poses and the bin), not against the estimated poses it was planned on.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "core/cell.h"
#include "core/status.h"
#include "pipeline/perception.h"

namespace bp {

struct ClearOptions {
  int task_id = 0;          // the cell's pick task to plan for
  // Pick tasks the simulated robot falls back to, in order, on a frame where
  // task_id has no grasp: a cell with a tool changer asks the suction task
  // first, then (after changing tools) a parallel-jaw task. Each fallback
  // plans on the same frame with its own gripper; its grasp is judged with
  // that gripper. Empty: no fallback.
  std::vector<int> fallback_task_ids;
  int max_cycles = 0;       // capture cycles per scene; <= 0: 3 * parts + 5
  // When not empty: a scene that ends with parts left writes its last frame
  // here as "clear_seed<N>_depth.png" with its intrinsics sidecar and
  // "clear_seed<N>_truth.json" (docs/file_formats.md), so that
  // `binpick eval --source files:DIR` replays exactly what perception missed.
  // The directory is created when missing.
  std::string save_left_dir;
};

struct SceneClearReport {
  uint64_t seed = 0;
  int parts_placed = 0;         // parts in the pile at the start
  int picks = 0;                // grasps taken
  int fallback_picks = 0;       // of which planned by a fallback task
  int cycles = 0;               // captures (one per pick, plus the last one)
  int truth_collisions = 0;     // chosen grasps colliding with the true scene
  int unmatched_picks = 0;      // grasps on no true part (a false detection)
  int parts_left = 0;           // true parts in the pile at the end
  bool said_empty = false;      // the empty-box answer at the end
  bool wrong_empty_answer = false;  // EMPTY with parts left, or NOT_EMPTY with none
  int64_t final_roi_points = 0;
  int64_t final_largest_region = 0;
  int final_detections = 0;
  std::string final_outcome;    // the last plan's outcome and filter summary
  std::vector<std::string> left;  // "instance 7 (l_bracket): part z axis (0.00, 1.00, 0.00), 83% visible"
  double plan_ms_total = 0;     // perception + planning over all cycles
  std::vector<std::string> collisions;  // "cycle 3: grasp hub_top@5 on instance 7: part"
  std::string saved_frame;      // the depth PNG written (ClearOptions::save_left_dir), else empty
};

struct ClearReport {
  std::vector<SceneClearReport> scenes;
  bool oracle = false;  // detections came from the ground-truth oracle
  // Totals.
  int parts_placed = 0, picks = 0, fallback_picks = 0, cycles = 0, truth_collisions = 0, unmatched_picks = 0,
      parts_left = 0, wrong_empty_answers = 0;
  // Appends `scene` and adds it to the totals.
  void Add(SceneClearReport scene);
  double CyclesPerPick() const { return picks > 0 ? static_cast<double>(cycles) / picks : 0.0; }
  double ClearedFraction() const {
    return parts_placed > 0 ? 1.0 - static_cast<double>(parts_left) / parts_placed : 1.0;
  }
};

// Clears one synthetic scene of `cell` (source forced to synthetic with
// simulate_picks, seed `seed`). `perception` detects in every frame.
Result<SceneClearReport> ClearScene(const Cell& cell, uint64_t seed, std::shared_ptr<const Perception> perception,
                                    const ClearOptions& options = {});

// Scenes seed, seed + 1, ..., seed + scenes - 1.
Result<ClearReport> ClearScenes(const Cell& cell, uint64_t seed, int scenes,
                                std::shared_ptr<const Perception> perception, bool oracle,
                                const ClearOptions& options = {});

}  // namespace bp
