// Closed-loop bin clearing in simulation (`binpick clear`), like the seed
// robot program: capture -> detect -> queue -> take the queue's grasps one by
// one (or only the first, ClearOptions::serve_queue = false) -> capture
// again, until a capture gives no grasp; then the empty-box check.
//
// Each pick is judged like a robot would experience it, against GROUND TRUTH
// at the time of the pick (the pile as earlier picks of the same queue left
// it), not against the estimated poses it was planned on: it succeeds only
// when the grasp lands on a true part at its grasp point (grasp/grasp_judge.h)
// and the swept gripper collides with nothing (bin, other true parts). A
// successful pick removes the part it landed on and the rest resettles; a
// failed pick removes nothing and is listed with its cause:
//   stale_queue  the pick would have succeeded on the pile as captured: an
//                earlier pick of the queue (and the resettling) made it fail;
//   collision    the gripper hits the bin or another true part;
//   off_part / approach / no_part   the judge's causes (a wrong pose).
#pragma once

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "core/cell.h"
#include "core/status.h"
#include "grasp/bin_picking_planner.h"
#include "grasp/grasp_judge.h"
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
  // true: a capture's whole queue is served before the next capture (the
  // seed robot program: pick poses until NO_OBJECT_FOUND); false: one pick
  // per capture.
  bool serve_queue = true;
  // true: the queue withdraws the grasps a pick makes stale (Grasp::stale_after,
  // as binpickd's queue does: docs/protocols.md, "Stale grasps"); false: they
  // are served and judged (to measure what the withdrawal saves).
  bool withdraw_stale = true;
  // The planner's thorough retry budget (BinPickingPlannerOptions::
  // thorough_retry_estimates, thorough_retry_ms): a count of estimates, the
  // same at any load, under a time cap (hit only on a slow or loaded
  // machine; a large one makes a clear repeatable whatever the load).
  int thorough_retry_estimates = BinPickingPlannerOptions{}.thorough_retry_estimates;
  double thorough_retry_ms = BinPickingPlannerOptions{}.thorough_retry_ms;
  // The plan's margin from the other detected parts, m
  // (GraspPlanningOptions::part_margin; `--part-margin-mm`, to measure it).
  double part_margin = GraspPlanningOptions{}.part_margin;
  // GraspPlanningOptions::dropout_ends_at_parts (`--dropout-ends-at-parts`,
  // to measure it).
  bool dropout_ends_at_parts = GraspPlanningOptions{}.dropout_ends_at_parts;
  // GraspPlanningOptions::hidden_behind_parts (`--hidden-behind-parts`, to
  // measure it).
  bool hidden_behind_parts = GraspPlanningOptions{}.hidden_behind_parts;
  GraspJudgeOptions judge;
  // Fraction in [0, 1] of the picks the judge lets succeed that the
  // simulated robot fails anyway, at random (`--slip`: the vacuum breaks, the
  // part slips off the cup); the part stays where it was. Drawn once per
  // pick from a generator seeded with slip_seed and the scene's seed.
  double slip_rate = 0.0;
  uint64_t slip_seed = 1;
  // true: the simulated robot reports every failed pick (judged or slipped)
  // as a robot reports it to binpickd (command 60, docs/protocols.md
  // "Failed-pick feedback"): one FailedPicks per task with the task's rule,
  // aged by every capture, screening the task's plans and its queue after
  // each report. false: nothing is reported (what the feedback buys).
  bool feedback = true;
};

// A grasp's taken picks (its name without the "@N" / "~v" suffixes:
// "hub_side@12~v" counts as "hub_side"), to weigh each grasp's share of the
// picks against its share of the collisions.
struct GraspTally {
  int attempts = 0;    // grasps taken
  int picks = 0;       // successful picks
  int collisions = 0;  // truth collisions (failed picks with cause collision, or a stale one that also hit)
  void Add(const GraspTally& o) {
    attempts += o.attempts;
    picks += o.picks;
    collisions += o.collisions;
  }
};

// "hub_side@12~v" -> "hub_side": the cell's grasp name.
std::string GraspBaseName(const std::string& name);

struct SceneClearReport {
  uint64_t seed = 0;
  int parts_placed = 0;         // parts in the pile at the start
  int attempts = 0;             // grasps taken (picks + failed_picks)
  int picks = 0;                // successful picks: a part left the bin
  int failed_picks = 0;         // grasps that took nothing (the part stays)
  int stale_failures = 0;       // of which failed on a queue made stale by an earlier pick
  int withdrawn = 0;            // queued grasps withdrawn as stale before they were served
  int slipped = 0;              // of the failed picks, slips (ClearOptions::slip_rate)
  int reported = 0;             // failed picks reported (ClearOptions::feedback)
  int screened = 0;             // grasps withheld or refused by the failed-pick feedback
  // The scene ended because the feedback refused every grasp left (the
  // robot was answered NO_COLLISION_FREE_POSE rather than sent back there).
  bool stopped_by_feedback = false;
  int fallback_picks = 0;       // successful picks planned by a fallback task
  int cycles = 0;               // captures
  int truth_collisions = 0;     // grasps colliding with the true scene
  int parts_left = 0;           // true parts in the pile at the end
  bool said_empty = false;      // the empty-box answer at the end
  bool wrong_empty_answer = false;  // EMPTY with parts left, or NOT_EMPTY with none
  int64_t final_roi_points = 0;
  int64_t final_largest_region = 0;
  int final_detections = 0;
  std::string final_outcome;    // the last plan's outcome and filter summary
  std::vector<std::string> left;  // "instance 7 (l_bracket): part z axis (0.00, 1.00, 0.00), 83% visible; undetected, ..."
  // Why each part left stayed, parallel to `left`, read from the last
  // capture's plans (the primary task's and every fallback's it tried; the
  // pile left is the pile that capture saw):
  //   out_of_bin           its origin lies outside the true bin's inner box (knocked out)
  //   cycle_cap            the scene ended at ClearOptions::max_cycles
  //   undetected           no detection of any task's plan stands for it
  //   wrong_class          detected, but only as another class
  //   refused_by_feedback  it had a grasp, and the failed-pick feedback refused it
  //   no_grasp:REASON      detected, every candidate refused; REASON the last
  //                        filter (in the filters' order, RejectReason) any
  //                        of its candidates over the tasks reached,
  //                        "no_candidates" when it had none
  std::vector<std::string> left_causes;
  // Why the scene ended: "cleared" (nothing left), "no_objects" /
  // "no_collision_free" (the primary task's last outcome when no task had a
  // grasp), "feedback" (every grasp left refused), "cycle_cap".
  std::string ended;
  double plan_ms_total = 0;     // perception + planning over all cycles
  std::vector<std::string> collisions;  // "cycle 3: task 0 grasp hub_top@5 (detection 2) on instance 7: part; hits ..."
  // Every failed pick: "cycle 3: task 0 grasp run_top@1~v (detection 4): off_part, 7.3 mm / 2.1 deg from instance 9's grasp point"
  // (", a last resort" after the detection: Grasp::last_resort; ", on a pose
  // left by a failed last resort": Grasp::reposed)
  std::vector<std::string> failures;
  std::map<std::string, int> failure_causes;  // cause -> failed picks
  std::map<std::string, int> left_by_cause;   // left_causes counted
  std::map<std::string, GraspTally> by_grasp;  // GraspBaseName -> its picks
  std::string saved_frame;      // the depth PNG written (ClearOptions::save_left_dir), else empty
  // Plans whose head was told early (every plan is made as binpickd makes
  // it, GraspPlanner::PlanWithHead), and of those, the ones whose head,
  // handed out alone and merged with its plan, does not hand out what the
  // plan queued at once does (docs/protocols.md "The first pose early").
  int early_heads = 0;
  int early_head_mismatches = 0;
};

struct ClearReport {
  std::vector<SceneClearReport> scenes;
  bool oracle = false;  // detections came from the ground-truth oracle
  // Totals.
  int parts_placed = 0, attempts = 0, picks = 0, failed_picks = 0, stale_failures = 0, withdrawn = 0, fallback_picks = 0, cycles = 0,
      truth_collisions = 0, parts_left = 0, wrong_empty_answers = 0, slipped = 0, reported = 0, screened = 0,
      stopped_by_feedback = 0, early_heads = 0, early_head_mismatches = 0;
  std::map<std::string, int> failure_causes;
  std::map<std::string, int> left_by_cause;
  std::map<std::string, int> ended;  // SceneClearReport::ended -> scenes
  std::map<std::string, GraspTally> by_grasp;
  // Appends `scene` and adds it to the totals.
  void Add(SceneClearReport scene);
  double CyclesPerPick() const { return picks > 0 ? static_cast<double>(cycles) / picks : 0.0; }
  // Parts taken out by successful picks, over parts placed.
  double ClearedFraction() const { return parts_placed > 0 ? static_cast<double>(picks) / parts_placed : 1.0; }
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
