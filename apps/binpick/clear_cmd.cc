// binpick clear: closed-loop bin clearing on synthetic scenes (issue 4 §6,
// issue 37 §6). render -> detect -> take the queue's grasps like the seed
// robot program -> each pick judged against the true pile (grasp/bin_clearing.h):
// a successful one removes its part and the rest resettles, a failed one is
// listed with its cause; until a capture gives no grasp; then the empty-box
// check. Prints one line per scene and a summary; --json writes the whole
// report.
//
// --oracle replaces perception with the ground-truth oracle (TruthPerception):
// the numbers then measure grasp planning and the loop, NOT perception, and
// every line says so.
#include <cstdio>
#include <cstdlib>

#include <spdlog/spdlog.h>
#include <fstream>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "apps/binpick/command.h"
#include "core/cell.h"
#include "grasp/bin_clearing.h"
#include "pipeline/perception.h"
#include "pipeline/truth_perception.h"

namespace bp::cli {
namespace {

struct ClearCliOptions {
  std::string cell_path;
  int scenes = 1;
  uint64_t seed = 1;
  std::string json_out;
  bool oracle = false;
  int task_id = 0;
  std::vector<int> fallback_task_ids;
  std::string save_left_dir;
  double thorough_retry_ms = ClearOptions{}.thorough_retry_ms;
  int thorough_retry_estimates = ClearOptions{}.thorough_retry_estimates;
  double part_margin_mm = 1000 * ClearOptions{}.part_margin;
  bool dropout_ends_at_parts = ClearOptions{}.dropout_ends_at_parts;
  bool hidden_behind_parts = ClearOptions{}.hidden_behind_parts;
  bool capture_every_pick = false;
  bool keep_stale = false;
  bool variety = false;
  double slip = 0.0;
  uint64_t slip_seed = 1;
  bool no_feedback = false;
  BinCliOptions bin;
};

int Error(const Status& s) {
  std::fprintf(stderr, "binpick clear: %s\n", s.ToString().c_str());
  switch (s.code()) {
    case Status::Code::kInvalidArgument:
    case Status::Code::kNotFound:
    case Status::Code::kCorruption:
    case Status::Code::kOutOfRange: return kExitBadInput;
    default: return kExitFailure;
  }
}

nlohmann::ordered_json ToJson(const std::map<std::string, GraspTally>& by_grasp) {
  nlohmann::ordered_json j = nlohmann::ordered_json::object();
  for (const auto& [name, t] : by_grasp) {
    j[name] = {{"attempts", t.attempts}, {"picks", t.picks}, {"collisions", t.collisions}};
  }
  return j;
}

nlohmann::ordered_json ToJson(const ClearReport& r) {
  nlohmann::ordered_json j;
  j["detector"] = r.oracle ? "ground-truth oracle (does not measure perception)" : "perception";
  nlohmann::ordered_json scenes = nlohmann::ordered_json::array();
  for (const SceneClearReport& s : r.scenes) {
    scenes.push_back({{"seed", s.seed},
                      {"parts", s.parts_placed},
                      {"attempts", s.attempts},
                      {"picks", s.picks},
                      {"failed_picks", s.failed_picks},
                      {"stale_failures", s.stale_failures},
                      {"withdrawn", s.withdrawn},
                      {"slipped", s.slipped},
                      {"failures_reported", s.reported},
                      {"screened_by_feedback", s.screened},
                      {"stopped_by_feedback", s.stopped_by_feedback},
                      {"early_heads", s.early_heads},
                      {"early_head_mismatches", s.early_head_mismatches},
                      {"failure_causes", s.failure_causes},
                      {"by_grasp", ToJson(s.by_grasp)},
                      {"fallback_picks", s.fallback_picks},
                      {"cycles", s.cycles},
                      {"truth_collisions", s.truth_collisions},
                      {"parts_left", s.parts_left},
                      {"empty_answer", s.said_empty ? "EMPTY" : "NOT_EMPTY"},
                      {"wrong_empty_answer", s.wrong_empty_answer},
                      {"final_roi_points", s.final_roi_points},
                      {"final_largest_region", s.final_largest_region},
                      {"final_detections", s.final_detections},
                      {"final_outcome", s.final_outcome},
                      {"plan_ms_total", s.plan_ms_total},
                      {"collisions", s.collisions},
                      {"failures", s.failures},
                      {"saved_frame", s.saved_frame},
                      {"ended", s.ended},
                      {"left", s.left},
                      {"left_causes", s.left_causes}});
  }
  j["scenes"] = scenes;
  j["total"] = {{"scenes", r.scenes.size()},
                {"parts", r.parts_placed},
                {"attempts", r.attempts},
                {"picks", r.picks},
                {"failed_picks", r.failed_picks},
                {"stale_failures", r.stale_failures},
                {"withdrawn", r.withdrawn},
                {"slipped", r.slipped},
                {"failures_reported", r.reported},
                {"screened_by_feedback", r.screened},
                {"stopped_by_feedback", r.stopped_by_feedback},
                {"early_heads", r.early_heads},
                {"early_head_mismatches", r.early_head_mismatches},
                {"failure_causes", r.failure_causes},
                {"by_grasp", ToJson(r.by_grasp)},
                {"fallback_picks", r.fallback_picks},
                {"cycles", r.cycles},
                {"cycles_per_pick", r.CyclesPerPick()},
                {"truth_collisions", r.truth_collisions},
                {"parts_left", r.parts_left},
                {"cleared_fraction", r.ClearedFraction()},
                {"wrong_empty_answers", r.wrong_empty_answers},
                {"left_by_cause", r.left_by_cause},
                {"ended", r.ended}};
  return j;
}

int Run(const ClearCliOptions& opt) {
  if (const char* level = std::getenv("BINPICK_LOG_LEVEL")) spdlog::set_level(spdlog::level::from_str(level));
  Result<Cell> cell = LoadCellOrDefault(opt.cell_path);
  if (!cell.ok()) return Error(cell.status());
  if (opt.variety && !cell->source.variety) cell->source.variety = VarietySpec{};
  ApplyBinOptions(opt.bin, *cell);
  std::shared_ptr<const Perception> perception;
  if (opt.oracle) {
    perception = std::make_shared<TruthPerception>(*cell);
  } else {
    auto built = Perception::Build(*cell);
    if (!built.ok()) return Error(built.status());
    perception = std::move(*built);
  }
  const char* tag = opt.oracle ? " [ORACLE detections: not measuring perception]" : "";
  ClearOptions options;
  options.task_id = opt.task_id;
  options.fallback_task_ids = opt.fallback_task_ids;
  options.save_left_dir = opt.save_left_dir;
  options.serve_queue = !opt.capture_every_pick;
  options.withdraw_stale = !opt.keep_stale;
  options.thorough_retry_ms = opt.thorough_retry_ms;
  options.thorough_retry_estimates = opt.thorough_retry_estimates;
  options.part_margin = opt.part_margin_mm / 1000;
  options.dropout_ends_at_parts = opt.dropout_ends_at_parts;
  options.hidden_behind_parts = opt.hidden_behind_parts;
  options.slip_rate = opt.slip;
  options.slip_seed = opt.slip_seed;
  options.feedback = !opt.no_feedback;
  ClearReport report;
  report.oracle = opt.oracle;
  for (int i = 0; i < opt.scenes; ++i) {
    const uint64_t seed = opt.seed + static_cast<uint64_t>(i);
    auto scene = ClearScene(*cell, seed, perception, options);
    if (!scene.ok()) return Error(scene.status());
    const SceneClearReport& s = *scene;
    std::printf("scene seed=%llu: %d parts, %d picks (%d by a fallback task), %d failed (%d stale), %d withdrawn, "
                "%d cycles, %d truth collisions, %d left, %s%s, %.0f ms planning%s\n",
                static_cast<unsigned long long>(seed), s.parts_placed, s.picks, s.fallback_picks, s.failed_picks,
                s.stale_failures, s.withdrawn, s.cycles, s.truth_collisions, s.parts_left, s.said_empty ? "EMPTY" : "NOT_EMPTY",
                s.wrong_empty_answer ? " (WRONG)" : "", s.plan_ms_total, tag);
    for (const std::string& c : s.collisions) std::printf("  collision: %s\n", c.c_str());
    for (const std::string& f : s.failures) std::printf("  failed pick: %s\n", f.c_str());
    if (s.slipped > 0 || s.reported > 0) {
      std::printf("  feedback: %d slipped, %d failures reported, %d grasps withheld or refused%s\n", s.slipped,
                  s.reported, s.screened, s.stopped_by_feedback ? ", stopped: every grasp left refused" : "");
    }
    if (s.parts_left > 0) std::printf("  last plan: %s\n", s.final_outcome.c_str());
    for (const std::string& l : s.left) std::printf("  left: %s\n", l.c_str());
    if (!s.saved_frame.empty()) std::printf("  saved: %s\n", s.saved_frame.c_str());
    report.Add(std::move(*scene));
    std::fflush(stdout);
  }
  std::string causes;
  for (const auto& [cause, n] : report.failure_causes) causes += (causes.empty() ? " (" : ", ") + cause + " " + std::to_string(n);
  if (!causes.empty()) causes += ")";
  std::printf("total: %zu scenes, %d parts, %d successful picks (%d by a fallback task), %d failed picks%s, "
              "%d grasps withdrawn as stale, %.2f cycles/pick, %d truth collisions, %d left (%.2f%% cleared by successful picks), "
              "%d wrong empty answers%s\n",
              report.scenes.size(), report.parts_placed, report.picks, report.fallback_picks, report.failed_picks,
              causes.c_str(), report.withdrawn, report.CyclesPerPick(), report.truth_collisions, report.parts_left,
              100.0 * report.ClearedFraction(), report.wrong_empty_answers, tag);
  std::printf("feedback %s: slip rate %.3f, %d picks slipped, %d failures reported, %d grasps withheld or refused, "
              "%d scenes stopped with every grasp left refused\n",
              options.feedback ? "on" : "off", options.slip_rate, report.slipped, report.reported, report.screened,
              report.stopped_by_feedback);
  // Where the parts left went (SceneClearReport::left_causes) and why the scenes ended.
  const auto counts = [](const std::map<std::string, int>& m) {
    std::string out;
    for (const auto& [key, n] : m) out += (out.empty() ? "" : ", ") + key + " " + std::to_string(n);
    return out.empty() ? std::string("none") : out;
  };
  std::printf("parts left by cause: %s; scenes ended: %s\n", counts(report.left_by_cause).c_str(),
              counts(report.ended).c_str());
  std::string grasps;
  for (const auto& [name, t] : report.by_grasp) {
    grasps += (grasps.empty() ? "" : ", ") + name + " " + std::to_string(t.picks) + "/" + std::to_string(t.attempts) +
              (t.collisions > 0 ? " (" + std::to_string(t.collisions) + " collisions)" : "");
  }
  std::printf("by grasp (picks/taken): %s\n", grasps.c_str());
  std::printf("first pose early: %d plans told their head early, %d of those disagree with their full plan\n",
              report.early_heads, report.early_head_mismatches);
  if (!opt.json_out.empty()) {
    std::ofstream out(opt.json_out);
    out << ToJson(report).dump(2) << "\n";
    if (!out) return Error(Status::Internal("cannot write '" + opt.json_out + "'"));
  }
  const bool pass = report.truth_collisions == 0 && report.wrong_empty_answers == 0 && report.early_head_mismatches == 0;
  return pass ? kExitOk : kExitFailure;
}

}  // namespace

Command ClearCommand() {
  Command c;
  c.name = "clear";
  c.help = "Clear synthetic bins in closed loop (detect, pick, resettle) and report collisions and leftovers";
  c.setup = [](CLI::App& sub) {
    auto opt = std::make_shared<ClearCliOptions>();
    sub.add_option("--cell", opt->cell_path, "cell file (default: the embedded default cell)");
    sub.add_option("--scenes", opt->scenes, "number of scenes")->required()->check(CLI::PositiveNumber);
    sub.add_option("--seed", opt->seed, "seed of the first scene (scene i uses seed + i)")->required();
    sub.add_option("--json", opt->json_out, "write the report as JSON");
    sub.add_option("--task", opt->task_id, "the cell's pick task to plan for")->capture_default_str();
    sub.add_option("--fallback-task", opt->fallback_task_ids,
                   "a pick task to try on the same frame when --task has no grasp (a robot with a tool changer; "
                   "repeat for more, tried in order; the default cell's task 4 uses its parallel jaw)");
    sub.add_option("--save-left", opt->save_left_dir,
                   "write the last frame of every scene that ends with parts left to this directory (depth PNG, "
                   "intrinsics, ground truth), for `binpick eval --source files:DIR`");
    sub.add_option("--thorough-retry-ms", opt->thorough_retry_ms,
                   "time cap of the planner's thorough perception retry, ms (hit only on a slow or loaded "
                   "machine: a large one makes the run repeatable whatever the load)")
        ->capture_default_str()
        ->check(CLI::PositiveNumber);
    sub.add_option("--thorough-retry-estimates", opt->thorough_retry_estimates,
                   "budget of the planner's thorough perception retry in pose estimates, the same at any load "
                   "(0: no count, the time cap alone)")
        ->capture_default_str()
        ->check(CLI::NonNegativeNumber);
    sub.add_option("--part-margin-mm", opt->part_margin_mm,
                   "the distance the plan keeps the swept gripper from the other detected parts, mm "
                   "(GraspPlanningOptions::part_margin: a neighbour detected a few tenths of a mm off is not grazed)")
        ->capture_default_str()
        ->check(CLI::NonNegativeNumber);
    sub.add_option("--dropout-ends-at-parts", opt->dropout_ends_at_parts,
                   "true: an unseen dropout ray beside an unexplained point ends at a detected part's surface; "
                   "false: at the farthest depth measured near it (GraspPlanningOptions::dropout_ends_at_parts)")
        ->capture_default_str();
    sub.add_option("--hidden-behind-parts", opt->hidden_behind_parts,
                   "true: the space a detected part hides from the camera, where it could hold a part, is an "
                   "obstacle for the other parts' grasps; false: free (GraspPlanningOptions::hidden_behind_parts)")
        ->capture_default_str();
    sub.add_flag("--variety", opt->variety,
                 "draw each scene's camera pose, intrinsics, noise and drop style from its seed (the cell's "
                 "source.variety, else the defaults; docs/synthetic.md)");
    AddBinOptions(sub, &opt->bin);
    sub.add_flag("--capture-every-pick", opt->capture_every_pick,
                 "capture again after every pick instead of serving the whole queue first");
    sub.add_flag("--keep-stale", opt->keep_stale,
                 "serve the grasps a pick makes stale instead of withdrawing them as binpickd does (docs/protocols.md, "
                 "\"Stale grasps\"): measures what the withdrawal saves");
    sub.add_option("--slip", opt->slip,
                   "fraction of the picks that would succeed which the simulated robot fails at random (the part "
                   "slips off and stays); reported like a robot's failed pick (command 60)")
        ->capture_default_str()
        ->check(CLI::Range(0.0, 1.0));
    sub.add_option("--slip-seed", opt->slip_seed, "seed of the slips (with each scene's seed)")->capture_default_str();
    sub.add_flag("--no-feedback", opt->no_feedback,
                 "the simulated robot does not report its failed picks (docs/protocols.md \"Failed-pick feedback\"): "
                 "measures what the feedback buys");
    sub.add_flag("--oracle", opt->oracle,
                 "use ground-truth detections instead of perception (does NOT measure perception)");
    return [opt] { return Run(*opt); };
  };
  return c;
}

}  // namespace bp::cli
