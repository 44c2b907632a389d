#include "grasp/bin_clearing.h"

#include <spdlog/spdlog.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <system_error>
#include <utility>

#include "grasp/bin_picking_planner.h"
#include "grasp/empty_box.h"
#include "grasp/grasp_planning.h"
#include "pipeline/capture_source.h"
#include "pipeline/frame_io.h"

namespace bp {

Result<SceneClearReport> ClearScene(const Cell& base_cell, uint64_t seed, std::shared_ptr<const Perception> perception,
                                    const ClearOptions& options) {
  Cell cell = base_cell;
  cell.source.kind = SourceSpec::Kind::kSynthetic;
  cell.source.simulate_picks = true;
  cell.source.seed = seed;
  const TaskSpec* task = cell.FindTask(options.task_id);
  if (task == nullptr) return Status::InvalidArgument("clear: the cell has no task " + std::to_string(options.task_id));
  std::vector<const TaskSpec*> fallbacks;
  for (int id : options.fallback_task_ids) {
    const TaskSpec* fb = cell.FindTask(id);
    if (fb == nullptr) return Status::InvalidArgument("clear: the cell has no fallback task " + std::to_string(id));
    if (fb->kind != TaskSpec::Kind::kPick || id == task->id) {
      return Status::InvalidArgument("clear: fallback task " + std::to_string(id) +
                                     " must be a pick task other than task " + std::to_string(task->id));
    }
    fallbacks.push_back(fb);
  }
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
  std::optional<Frame> last_frame;  // kept only for save_left_dir
  for (int cycle = 0;; ++cycle) {
    auto scene = p.Capture(request);
    if (!scene.ok()) return scene.status();
    const Frame& frame = static_cast<const CapturedFrame&>(**scene).frame();
    if (!frame.truth) return Status::Internal("clear: the synthetic frame has no ground truth");
    truth_parts = frame.truth->parts;
    if (!options.save_left_dir.empty()) last_frame = frame;
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
    // Every candidate of a task's plan and why it was rejected (debug log).
    const auto log_candidates = [&](const TaskSpec& t, const PlanDetail& plan) {
      if (!spdlog::should_log(spdlog::level::debug)) return;
      for (const GraspCandidate& c : plan.plan.candidates) {
        spdlog::debug("seed {} cycle {} task {}: detection {} (truth {}) {} tilt {:.0f} deg: {}", seed, report.cycles,
                      t.id, c.detection, p.TruthInstanceOf(t.id, c.detection), c.name, c.tilt_rad * 180 / M_PI,
                      c.rejected ? ToString(*c.rejected) : "ok");
      }
    };
    log_candidates(*task, *detail);
    // The task whose grasp is taken: the primary one, else the first
    // fallback with a grasp on this frame. `last` stays the primary task's
    // plan: the final empty-box answer is the primary task's.
    const TaskSpec* used = task;
    const PlanResult* taken = &last;
    PlanResult fallback_result;
    if (last.grasps.empty() && report.cycles < max_cycles) {
      for (const TaskSpec* fb : fallbacks) {
        PlanRequest fb_request;
        fb_request.task = *fb;
        const auto t1 = std::chrono::steady_clock::now();
        auto fb_detail = p.PlanDetailed(fb_request, **scene);
        report.plan_ms_total += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t1).count();
        if (!fb_detail.ok()) return fb_detail.status();
        log_candidates(*fb, *fb_detail);
        if (!fb_detail->result.grasps.empty()) {
          used = fb;
          fallback_result = std::move(fb_detail->result);
          taken = &fallback_result;
          break;
        }
      }
    }
    if (taken->grasps.empty() || report.cycles >= max_cycles) break;

    // Judge the first grasp against the true scene.
    const Grasp& grasp = taken->grasps.front();
    const int instance = p.TruthInstanceOf(used->id, grasp.instance_id);
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
    if (auto hit = p.model().CheckAgainstParts(used->gripper, grasp.X_BT, truth, target)) {
      ++report.truth_collisions;
      std::string line = "cycle " + std::to_string(report.cycles) + ": task " + std::to_string(used->id) + " grasp " +
                         grasp.name + " on instance " + std::to_string(instance) + ": " + std::string(ToString(*hit));
      // How far the detection the grasp was planned on is from the truth.
      const size_t det = static_cast<size_t>(grasp.instance_id);
      if (target >= 0 && det < taken->parts.size()) {
        const Pose& est = taken->parts[det].X_BO;
        const Pose& real = truth[static_cast<size_t>(target)].X_BO;
        char error[96];
        std::snprintf(error, sizeof(error), " (its detection is %.1f mm, %.1f deg from the truth)",
                      1000 * (est.translation() - real.translation()).norm(),
                      Eigen::AngleAxisd(est.linear().transpose() * real.linear()).angle() * 180 / M_PI);
        line += error;
      }
      // Which true part it hits, how much of it the camera saw, and whether
      // a detection lies within 10 mm of it.
      for (size_t j = 0; j < truth.size(); ++j) {
        if (static_cast<int>(j) == target) continue;
        const Detection pair[] = {truth[j]};
        if (!p.model().CheckAgainstParts(used->gripper, grasp.X_BT, pair, -1)) continue;
        bool detected = false;
        for (const DetectedPart& d : taken->parts) {
          detected |= (d.X_BO.translation() - truth[j].X_BO.translation()).norm() < 0.01;
        }
        char hit_part[160];
        std::snprintf(hit_part, sizeof(hit_part), "; hits instance %d (%s, %.0f%% visible, %s)",
                      truth_parts[j].instance_id, truth_parts[j].class_name.c_str(),
                      100 * truth_parts[j].visible_fraction, detected ? "detected" : "not detected");
        line += hit_part;
      }
      report.collisions.push_back(std::move(line));
    }
    p.NotifyHandedOut(*used, grasp);
    ++report.picks;
    if (used != task) ++report.fallback_picks;
  }
  report.parts_left = static_cast<int>(truth_parts.size());
  if (report.parts_left > 0 && last_frame) {
    std::error_code ec;
    std::filesystem::create_directories(options.save_left_dir, ec);
    if (ec) return Status::Internal("clear: cannot create '" + options.save_left_dir + "': " + ec.message());
    const std::string path =
        (std::filesystem::path(options.save_left_dir) / ("clear_seed" + std::to_string(seed) + "_depth.png")).string();
    if (Status s = WriteDepthPng(*last_frame, path); !s.ok()) return s;
    if (Status s = WriteGroundTruthJson(*last_frame, CompanionPath(path, "truth.json")); !s.ok()) return s;
    report.saved_frame = path;
  }
  for (const PartTruth& t : truth_parts) {
    const Vec3 z = t.X_BO.linear().col(2);
    // The part axis nearest the base frame's up direction: how the part rests.
    const Vec3 up_O = t.X_BO.linear().transpose() * Vec3::UnitZ();
    Eigen::Index axis = 0;
    up_O.cwiseAbs().maxCoeff(&axis);
    const Vec3 at = 1000.0 * t.X_BO.translation();
    char line[240];
    std::snprintf(line, sizeof(line),
                  "instance %d (%s) at (%.0f, %.0f, %.0f) mm: part z axis (%.2f, %.2f, %.2f), up is part %c%c, "
                  "%.0f%% visible",
                  t.instance_id, t.class_name.c_str(), at.x(), at.y(), at.z(), z.x(), z.y(), z.z(),
                  up_O[axis] < 0 ? '-' : '+', static_cast<char>('x' + axis), 100.0 * t.visible_fraction);
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

void ClearReport::Add(SceneClearReport scene) {
  parts_placed += scene.parts_placed;
  picks += scene.picks;
  fallback_picks += scene.fallback_picks;
  cycles += scene.cycles;
  truth_collisions += scene.truth_collisions;
  unmatched_picks += scene.unmatched_picks;
  parts_left += scene.parts_left;
  wrong_empty_answers += scene.wrong_empty_answer ? 1 : 0;
  scenes.push_back(std::move(scene));
}

Result<ClearReport> ClearScenes(const Cell& cell, uint64_t seed, int scenes, std::shared_ptr<const Perception> perception,
                                bool oracle, const ClearOptions& options) {
  ClearReport report;
  report.oracle = oracle;
  for (int i = 0; i < scenes; ++i) {
    auto scene = ClearScene(cell, seed + static_cast<uint64_t>(i), perception, options);
    if (!scene.ok()) return scene.status();
    report.Add(std::move(*scene));
  }
  return report;
}

}  // namespace bp
