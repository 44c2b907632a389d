#include "grasp/place_cycles.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <numbers>
#include <optional>
#include <tuple>
#include <utility>

#include "grasp/bin_picking_planner.h"
#include "grasp/robot_targets.h"
#include "pipeline/pose_estimator.h"
#include "pipeline/synthetic_source.h"

namespace bp {
namespace {

constexpr double kRadToDeg = 180.0 / std::numbers::pi;

// Position (mm) and rotation (deg) between two part poses modulo symmetry.
std::pair<double, double> Error(const Pose& a, const Pose& b, const Symmetry& symmetry) {
  return {1000 * SymmetricTranslationError(a, b, symmetry), kRadToDeg * SymmetricRotationError(a, b, symmetry)};
}

PlaceCyclesReport::Spread SpreadOf(std::vector<double> v) {
  PlaceCyclesReport::Spread s;
  if (v.empty()) return s;
  std::sort(v.begin(), v.end());
  const auto at = [&](double q) { return v[std::min(v.size() - 1, static_cast<size_t>(std::ceil(q * v.size())) - 1)]; };
  s.median = v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
  s.p99 = at(0.99);
  s.max = v.back();
  return s;
}

// One pile: its source (owned by the planner) and the planner.
struct Pile {
  SyntheticSource* source = nullptr;
  std::unique_ptr<BinPickingPlanner> planner;
};

Result<Pile> MakePile(const Cell& cell, std::shared_ptr<const Perception> perception) {
  Result<std::unique_ptr<CaptureSource>> source = MakeSyntheticSource(cell);
  if (!source.ok()) return source.status();
  Pile pile;
  pile.source = dynamic_cast<SyntheticSource*>(source->get());
  BinPickingPlannerOptions options;
  options.teach_file = "-";
  Result<std::unique_ptr<BinPickingPlanner>> planner =
      BinPickingPlanner::Create(cell, std::move(perception), std::move(*source), options);
  if (!planner.ok()) return planner.status();
  pile.planner = std::move(*planner);
  return pile;
}

Result<PlanResult> CaptureAndPlan(BinPickingPlanner& planner, const TaskSpec& task, const std::optional<Pose>& X_BT) {
  const PlanRequest request{task, X_BT, 0};
  Result<CaptureHandle> scene = planner.Capture(request);
  if (!scene.ok()) return scene.status();
  return planner.Plan(request, **scene);
}

class CycleRunner {
 public:
  CycleRunner(const Cell& cell, const PlaceCyclesOptions& o, PlaceCyclesReport& report)
      : cell_(cell), o_(o), report_(report), pick_(*cell.FindTask(o.pick_task_id)),
        in_hand_(*cell.FindTask(o.in_hand_task_id)), place_area_(*cell.FindTask(o.place_area_task_id)),
        fixture_(*cell.FindFixture(place_area_.fixture)) {}

  // One cycle on `pile`; false when the pile has nothing left to pick.
  Result<bool> Run(Pile& pile, uint64_t scene_seed) {
    Result<PlanResult> picks = CaptureAndPlan(*pile.planner, pick_, std::nullopt);
    if (!picks.ok()) return picks.status();
    if (picks->grasps.empty()) return false;
    const Grasp grasp = picks->grasps.front();
    CountSent(pick_, grasp);
    pile.planner->NotifyHandedOut(pick_, grasp);
    const std::optional<HeldPartTruth> held = pile.source->held();
    if (!held) return false;  // the grasp's part matched no true part: a new pile
    PlaceCycle c;
    c.scene_seed = scene_seed;
    c.class_id = held->class_id;
    const Symmetry& symmetry = cell_.FindPart(held->class_id)->symmetry;
    std::tie(c.slip_mm, c.slip_deg) = Error(held->slip_T, Pose::Identity(), Symmetry{});
    const Pose X_TO_believed = grasp.X_BT.inverse() * grasp.X_BO;
    std::tie(c.grasp_error_mm, c.grasp_error_deg) = Error(X_TO_believed, held->X_TO, symmetry);
    if (Status s = Finish(pile, c, held->X_TO, X_TO_believed, symmetry); !s.ok()) return s;
    report_.cycles.push_back(c);
    return true;
  }

 private:
  // The in_hand and place_area stages of a held part; releases it.
  Status Finish(Pile& pile, PlaceCycle& c, const Pose& X_TO_true, const Pose& X_TO_believed,
                const Symmetry& symmetry) {
    Result<PlanResult> seen = CaptureAndPlan(*pile.planner, in_hand_, o_.X_BT_adjust);
    if (!seen.ok()) return seen.status();
    if (seen->grasps.empty()) return Missed(pile, c, "in_hand_missed", report_.in_hand_missed, seen->message);
    const Pose X_TO_measured = seen->grasps[0].X_BT;
    std::tie(c.in_hand_error_mm, c.in_hand_error_deg) = Error(X_TO_measured, X_TO_true, symmetry);
    pile.planner->NotifyHandedOut(in_hand_, seen->grasps[0]);

    const Pose X_BP = pile.source->fixture_truth(fixture_.name).value();
    Result<PlanResult> area = CaptureAndPlan(*pile.planner, place_area_, std::nullopt);
    if (!area.ok()) return area.status();
    if (area->grasps.empty()) return Missed(pile, c, "place_area_missed", report_.place_area_missed, area->message);
    const Grasp& offset = area->grasps[0];
    if (!CheckRobotTargets(cell_, place_area_, offset).ok()) {
      return Missed(pile, c, "outside_workspace", report_.refused,  // the handler's gate: never sent
                    CheckRobotTargets(cell_, place_area_, offset).message());
    }
    CountSent(place_area_, offset);
    // seed 003: tool_in_base = place_in_base * obj_in_Place * obj_in_tool^-1.
    const Pose obj_in_place = fixture_.X_BP_taught * fixture_.X_PO;
    const Pose wanted = X_BP * fixture_.X_PO;
    const Pose corrected = offset.X_BT * obj_in_place * X_TO_measured.inverse();
    const Pose uncorrected = offset.X_BT * obj_in_place * X_TO_believed.inverse();
    std::tie(c.place_error_mm, c.place_error_deg) = Error(corrected * X_TO_true, wanted, symmetry);
    std::tie(c.uncorrected_mm, c.uncorrected_deg) = Error(uncorrected * X_TO_true, wanted, symmetry);
    c.outcome = "placed";
    ++report_.placed;
    pile.planner->NotifyHandedOut(place_area_, offset);  // the part is let go
    return Status::Ok();
  }

  // A stage without an answer: the robot puts the part aside.
  Status Missed(Pile& pile, PlaceCycle& c, const char* outcome, int& counter, const std::string& why) {
    spdlog::info("place cycle {} (pile {}): {}: {}", report_.cycles.size(), c.scene_seed, outcome, why);
    c.outcome = outcome;
    ++counter;
    pile.source->NotifyReleased();
    return Status::Ok();
  }

  // Every pose the robot moves to on an answer, checked independently of
  // the handler's gate: the flange inside robot.workspace.
  void CountSent(const TaskSpec& task, const Grasp& grasp) {
    for (const Pose& X_BT : RobotTargets(task, grasp)) {
      ++report_.poses_sent;
      const GripperSpec* gripper = cell_.FindGripper(task.gripper);
      const Pose X_BF = gripper ? Pose(X_BT * gripper->X_FT.inverse()) : X_BT;
      if (!cell_.robot.workspace.contains(X_BF.translation())) ++report_.sent_outside;
    }
  }

  const Cell& cell_;
  const PlaceCyclesOptions& o_;
  PlaceCyclesReport& report_;
  const TaskSpec& pick_;
  const TaskSpec& in_hand_;
  const TaskSpec& place_area_;
  const FixtureSpec& fixture_;
};

Status CheckTasks(const Cell& cell, const PlaceCyclesOptions& o) {
  const auto expect = [&](int id, TaskSpec::Kind kind, const char* what) -> Status {
    const TaskSpec* t = cell.FindTask(id);
    if (t == nullptr || t->kind != kind) {
      return Status::InvalidArgument("place cycles: task " + std::to_string(id) + " is not a" + what + " task");
    }
    return Status::Ok();
  };
  if (Status s = expect(o.pick_task_id, TaskSpec::Kind::kPick, " pick"); !s.ok()) return s;
  if (Status s = expect(o.in_hand_task_id, TaskSpec::Kind::kInHand, "n in_hand"); !s.ok()) return s;
  if (Status s = expect(o.place_area_task_id, TaskSpec::Kind::kPlaceArea, " place_area"); !s.ok()) return s;
  if (o.cycles < 0) return Status::InvalidArgument("place cycles: cycles must be >= 0");
  return Status::Ok();
}

}  // namespace

Result<PlaceCyclesReport> RunPlaceCycles(const Cell& cell_in, std::shared_ptr<const Perception> perception,
                                         const PlaceCyclesOptions& o) {
  if (Status s = CheckTasks(cell_in, o); !s.ok()) return s;
  Cell cell = cell_in;
  cell.source.kind = SourceSpec::Kind::kSynthetic;
  cell.source.simulate_picks = true;
  PlaceCyclesReport report;
  CycleRunner runner(cell, o, report);
  uint64_t seed = o.seed;
  int empty_piles = 0;
  while (static_cast<int>(report.cycles.size()) < o.cycles) {
    cell.source.seed = seed;
    Result<Pile> pile = MakePile(cell, perception);
    if (!pile.ok()) return pile.status();
    ++report.piles;
    const size_t before = report.cycles.size();
    while (static_cast<int>(report.cycles.size()) < o.cycles) {
      Result<bool> more = runner.Run(*pile, seed);
      if (!more.ok()) return more.status();
      if (!*more) break;
    }
    // Piles that give nothing in a row: the cell cannot pick at all.
    empty_piles = report.cycles.size() == before ? empty_piles + 1 : 0;
    if (empty_piles >= 5) return Status::Unavailable("place cycles: 5 piles in a row gave no pick");
    ++seed;
  }
  std::vector<double> pm, pd, um, ud, im, id;
  for (const PlaceCycle& c : report.cycles) {
    if (c.outcome == "placed") {
      pm.push_back(c.place_error_mm);
      pd.push_back(c.place_error_deg);
      um.push_back(c.uncorrected_mm);
      ud.push_back(c.uncorrected_deg);
    }
    if (c.outcome == "placed" || c.outcome == "place_area_missed" || c.outcome == "outside_workspace") {
      im.push_back(c.in_hand_error_mm);
      id.push_back(c.in_hand_error_deg);
    }
  }
  report.place_mm = SpreadOf(pm);
  report.place_deg = SpreadOf(pd);
  report.uncorrected_mm = SpreadOf(um);
  report.uncorrected_deg = SpreadOf(ud);
  report.in_hand_mm = SpreadOf(im);
  report.in_hand_deg = SpreadOf(id);
  return report;
}

std::string PlaceCyclesReport::Describe() const {
  char line[512];
  std::string out;
  std::snprintf(line, sizeof(line),
                "%zu cycles on %d piles: %d placed, %d in-hand misses, %d place-area misses, %d refused "
                "(outside the workspace)\n",
                cycles.size(), piles, placed, in_hand_missed, place_area_missed, refused);
  out += line;
  const auto row = [&](const char* what, const Spread& mm, const Spread& deg) {
    std::snprintf(line, sizeof(line), "  %-28s median %6.2f mm %6.2f deg   p99 %6.2f mm %6.2f deg   max %6.2f mm %6.2f deg\n",
                  what, mm.median, deg.median, mm.p99, deg.p99, mm.max, deg.max);
    out += line;
  };
  row("place error, corrected:", place_mm, place_deg);
  row("place error, uncorrected:", uncorrected_mm, uncorrected_deg);
  row("in-hand pose error:", in_hand_mm, in_hand_deg);
  std::snprintf(line, sizeof(line), "  poses sent %d, outside robot.workspace %d\n", poses_sent, sent_outside);
  out += line;
  return out;
}

}  // namespace bp
