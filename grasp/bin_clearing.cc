#include "grasp/bin_clearing.h"

#include <spdlog/spdlog.h>

#include <chrono>
#include <cstdio>
#include <utility>

#include "grasp/bin_picking_planner.h"
#include "grasp/empty_box.h"
#include "grasp/grasp_planning.h"
#include "pipeline/capture_source.h"

namespace bp {

Result<SceneClearReport> ClearScene(const Cell& base_cell, uint64_t seed, std::shared_ptr<const Perception> perception,
                                    const ClearOptions& options) {
  Cell cell = base_cell;
  cell.source.kind = SourceSpec::Kind::kSynthetic;
  cell.source.simulate_picks = true;
  cell.source.seed = seed;
  const TaskSpec* task = cell.FindTask(options.task_id);
  if (task == nullptr) return Status::InvalidArgument("clear: the cell has no task " + std::to_string(options.task_id));
  auto source = MakeCaptureSource(cell);
  if (!source.ok()) return source.status();
  BinPickingPlannerOptions planner_options;
  planner_options.teach_file = "-";  // clearing never teaches
  auto planner = BinPickingPlanner::Create(cell, std::move(perception), std::move(*source), planner_options);
  if (!planner.ok()) return planner.status();
  BinPickingPlanner& p = **planner;

  SceneClearReport report;
  report.seed = seed;
  PlanRequest request;
  request.task = *task;
  int max_cycles = options.max_cycles;
  PlanResult last;
  std::vector<PartTruth> truth_parts;
  for (int cycle = 0;; ++cycle) {
    auto scene = p.Capture(request);
    if (!scene.ok()) return scene.status();
    const Frame& frame = static_cast<const CapturedFrame&>(**scene).frame();
    if (!frame.truth) return Status::Internal("clear: the synthetic frame has no ground truth");
    truth_parts = frame.truth->parts;
    if (cycle == 0) {
      report.parts_placed = static_cast<int>(truth_parts.size());
      if (max_cycles <= 0) max_cycles = 3 * report.parts_placed + 5;
    }
    const auto t0 = std::chrono::steady_clock::now();
    auto detail = p.PlanDetailed(request, **scene);
    report.plan_ms_total += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    if (!detail.ok()) return detail.status();
    ++report.cycles;
    last = detail->result;
    if (spdlog::should_log(spdlog::level::debug)) {
      for (const GraspCandidate& c : detail->plan.candidates) {
        spdlog::debug("seed {} cycle {}: detection {} (truth {}) {} tilt {:.0f} deg: {}", seed, report.cycles,
                      c.detection, p.TruthInstanceOf(task->id, c.detection), c.name, c.tilt_rad * 180 / M_PI,
                      c.rejected ? ToString(*c.rejected) : "ok");
      }
    }
    if (last.grasps.empty() || report.cycles >= max_cycles) break;

    // Judge the first grasp against the true scene.
    const Grasp& grasp = last.grasps.front();
    const int instance = p.TruthInstanceOf(task->id, grasp.instance_id);
    std::vector<Detection> truth;
    int target = -1;
    for (const PartTruth& t : truth_parts) {
      Detection d;
      d.class_id = t.class_id;
      d.X_BO = t.X_BO;
      if (t.instance_id == instance) target = static_cast<int>(truth.size());
      truth.push_back(std::move(d));
    }
    if (target < 0) ++report.unmatched_picks;
    if (auto hit = p.model().CheckAgainstParts(task->gripper, grasp.X_BT, truth, target)) {
      ++report.truth_collisions;
      report.collisions.push_back("cycle " + std::to_string(report.cycles) + ": grasp " + grasp.name +
                                  " on instance " + std::to_string(instance) + ": " + std::string(ToString(*hit)));
    }
    p.NotifyHandedOut(*task, grasp);
    ++report.picks;
  }
  report.parts_left = static_cast<int>(truth_parts.size());
  for (const PartTruth& t : truth_parts) {
    const Vec3 z = t.X_BO.linear().col(2);
    char line[200];
    std::snprintf(line, sizeof(line), "instance %d (%s): part z axis (%.2f, %.2f, %.2f), %.0f%% visible",
                  t.instance_id, t.class_name.c_str(), z.x(), z.y(), z.z(), 100.0 * t.visible_fraction);
    report.left.push_back(line);
  }
  report.final_roi_points = last.roi_points;
  report.final_largest_region = last.largest_region_points;
  report.final_detections = last.detections;
  report.final_outcome = std::string(ToString(last.outcome)) + ": " + last.message;
  report.said_empty = IsBoxEmpty(task->empty_box, last);
  report.wrong_empty_answer = report.said_empty != (report.parts_left == 0);
  return report;
}

Result<ClearReport> ClearScenes(const Cell& cell, uint64_t seed, int scenes, std::shared_ptr<const Perception> perception,
                                bool oracle, const ClearOptions& options) {
  ClearReport report;
  report.oracle = oracle;
  for (int i = 0; i < scenes; ++i) {
    auto scene = ClearScene(cell, seed + static_cast<uint64_t>(i), perception, options);
    if (!scene.ok()) return scene.status();
    report.parts_placed += scene->parts_placed;
    report.picks += scene->picks;
    report.cycles += scene->cycles;
    report.truth_collisions += scene->truth_collisions;
    report.unmatched_picks += scene->unmatched_picks;
    report.parts_left += scene->parts_left;
    report.wrong_empty_answers += scene->wrong_empty_answer ? 1 : 0;
    report.scenes.push_back(std::move(*scene));
  }
  return report;
}

}  // namespace bp
