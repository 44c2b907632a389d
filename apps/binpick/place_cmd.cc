// `binpick place`: seed 003's pick -> correct in hand -> place cycles in
// simulation, scored against the truth (grasp/place_cycles.h).
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <memory>

#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>

#include "apps/binpick/command.h"
#include "core/cell.h"
#include "grasp/place_cycles.h"
#include "pipeline/perception.h"
#include "pipeline/truth_perception.h"

namespace bp::cli {
namespace {

struct PlaceCliOptions {
  std::string cell_path;
  PlaceCyclesOptions cycles;
  double slip_mm = 10;
  double slip_deg = 10;
  std::string json_out;
  bool oracle = false;
};

nlohmann::ordered_json ToJson(const PlaceCyclesReport& r, bool oracle) {
  nlohmann::ordered_json j;
  j["detector"] = oracle ? "ground-truth oracle (does not measure perception)" : "perception";
  nlohmann::ordered_json cycles = nlohmann::ordered_json::array();
  for (const PlaceCycle& c : r.cycles) {
    cycles.push_back({{"scene_seed", c.scene_seed},
                      {"class_id", c.class_id},
                      {"outcome", c.outcome},
                      {"slip", {c.slip_mm, c.slip_deg}},
                      {"grasp_error", {c.grasp_error_mm, c.grasp_error_deg}},
                      {"in_hand_error", {c.in_hand_error_mm, c.in_hand_error_deg}},
                      {"place_error", {c.place_error_mm, c.place_error_deg}},
                      {"uncorrected_place_error", {c.uncorrected_mm, c.uncorrected_deg}}});
  }
  j["cycles"] = cycles;
  const auto spread = [](const PlaceCyclesReport::Spread& s) {
    return nlohmann::ordered_json{{"median", s.median}, {"p99", s.p99}, {"max", s.max}};
  };
  j["total"] = {{"cycles", r.cycles.size()},
                {"piles", r.piles},
                {"placed", r.placed},
                {"in_hand_missed", r.in_hand_missed},
                {"place_area_missed", r.place_area_missed},
                {"refused", r.refused},
                {"poses_sent", r.poses_sent},
                {"sent_outside_workspace", r.sent_outside},
                {"place_error_mm", spread(r.place_mm)},
                {"place_error_deg", spread(r.place_deg)},
                {"uncorrected_mm", spread(r.uncorrected_mm)},
                {"uncorrected_deg", spread(r.uncorrected_deg)},
                {"in_hand_error_mm", spread(r.in_hand_mm)},
                {"in_hand_error_deg", spread(r.in_hand_deg)}};
  return j;
}

int Run(const PlaceCliOptions& opt) {
  if (const char* level = std::getenv("BINPICK_LOG_LEVEL")) spdlog::set_level(spdlog::level::from_str(level));
  Result<Cell> cell = LoadCellOrDefault(opt.cell_path);
  if (!cell.ok()) return Fail("place", cell.status());
  cell->source.slip_translation = opt.slip_mm / 1000;
  cell->source.slip_rotation_deg = opt.slip_deg;
  std::shared_ptr<const Perception> perception;
  if (opt.oracle) {
    perception = std::make_shared<TruthPerception>(*cell);
  } else {
    auto built = Perception::Build(*cell);
    if (!built.ok()) return Fail("place", built.status());
    perception = std::move(*built);
  }
  Result<PlaceCyclesReport> report = RunPlaceCycles(*cell, perception, opt.cycles);
  if (!report.ok()) return Fail("place", report.status());
  for (size_t i = 0; i < report->cycles.size(); ++i) {
    const PlaceCycle& c = report->cycles[i];
    std::printf("cycle %3zu pile %llu class %d: %-17s slip %5.2f mm %5.2f deg, grasp off %5.2f mm %5.2f deg, "
                "in hand %5.2f mm %5.2f deg, placed %5.2f mm %5.2f deg (uncorrected %5.2f mm %5.2f deg)\n",
                i, static_cast<unsigned long long>(c.scene_seed), c.class_id, c.outcome.c_str(), c.slip_mm,
                c.slip_deg, c.grasp_error_mm, c.grasp_error_deg, c.in_hand_error_mm, c.in_hand_error_deg,
                c.place_error_mm, c.place_error_deg, c.uncorrected_mm, c.uncorrected_deg);
  }
  std::printf("%s%s", report->Describe().c_str(),
              opt.oracle ? "  [ORACLE detections: not measuring perception]\n" : "");
  if (!opt.json_out.empty()) {
    std::ofstream out(opt.json_out);
    out << ToJson(*report, opt.oracle).dump(2) << "\n";
    if (!out) return Fail("place", Status::Internal("cannot write '" + opt.json_out + "'"));
  }
  return report->sent_outside == 0 ? kExitOk : kExitFailure;
}

}  // namespace

Command PlaceCommand() {
  Command c;
  c.name = "place";
  c.help = "Seed 003's pick -> correct in hand -> place cycles on synthetic piles, place error against the truth";
  c.setup = [](CLI::App& sub) {
    auto opt = std::make_shared<PlaceCliOptions>();
    sub.add_option("--cell", opt->cell_path, "cell file (default: the embedded default cell)");
    sub.add_option("--cycles", opt->cycles.cycles, "pick -> correct -> place cycles")->capture_default_str();
    sub.add_option("--seed", opt->cycles.seed, "seed of the first pile (the next piles take seed + 1, ...)")
        ->capture_default_str();
    sub.add_option("--pick-task", opt->cycles.pick_task_id,
                   "the cell's pick task (the default cell's 7 places every part it picks: place_on)")
        ->capture_default_str();
    sub.add_option("--slip-mm", opt->slip_mm, "the part slips in the gripper by up to this (mm)")
        ->check(CLI::Range(0.0, 100.0))
        ->capture_default_str();
    sub.add_option("--slip-deg", opt->slip_deg, "... and turns by up to this (deg)")
        ->check(CLI::Range(0.0, 45.0))
        ->capture_default_str();
    sub.add_option("--json", opt->json_out, "write every cycle and the totals as JSON");
    sub.add_flag("--oracle", opt->oracle,
                 "use ground-truth detections instead of perception (does NOT measure perception)");
    return [opt] { return Run(*opt); };
  };
  return c;
}

}  // namespace bp::cli
