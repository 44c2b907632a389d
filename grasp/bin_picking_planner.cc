#include "grasp/bin_picking_planner.h"

#include <spdlog/spdlog.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <utility>

#include "grasp/failed_picks.h"
#include "pipeline/pose_estimator.h"

namespace bp {
namespace {

// How far an in_hand answer may stand from the part held as binpick believes
// it (the pick's grasp against its detected part, or the last in_hand
// answer), modulo the part's symmetry, before it is not trusted. A part
// slips in the gripper by millimetres and degrees (the simulator's slip is
// at most 10 mm / 10 deg; the pick's belief is off by up to 13 mm / 10 deg
// at p99, docs/tuning.md), while a pose estimate turned over on a part seen
// from below is about 180 deg off. Beyond either limit binpick cannot tell
// which of the two is wrong, and a place 180 deg wrong is worse than a stop:
// the answer is NO_OBJECT_FOUND. Set from those bounds, not tuned.
constexpr double kInHandMaxDeviationM = 0.03;
constexpr double kInHandMaxDeviationRad = 45.0 * M_PI / 180.0;

// Of a detection's poses (X_BO and its alternatives, PoseHypothesis::
// alternatives), the one in the tool frame T nearest to X_TO_held: least
// rotation error modulo symmetry, then least translation error (degrees
// and millimetres weighed 1:1). @returns X_TO.
Pose NearestToHeld(const Pose& X_BT, const Detection& det, const Pose& X_TO_held, const Symmetry& symmetry) {
  const Pose X_TB = X_BT.inverse();
  Pose best = X_TB * det.X_BO;
  double best_cost = std::numeric_limits<double>::infinity();
  auto consider = [&](const Pose& X_BO) {
    const Pose X_TO = X_TB * X_BO;
    const double cost = SymmetricRotationError(X_TO, X_TO_held, symmetry) * 180.0 / M_PI +
                        1000.0 * SymmetricTranslationError(X_TO, X_TO_held, symmetry);
    if (cost < best_cost) {
      best_cost = cost;
      best = X_TO;
    }
  };
  consider(det.X_BO);
  for (const Pose& X_BO : det.alternatives_X_BO) consider(X_BO);
  return best;
}

// Match detections to ground truth (synthetic frames only): the true
// instance most of the detection's support points show in the label image
// (robust to a wrong pose estimate), else the nearest true part of its class.
// Says in the plan whether its thorough retry ran out of budget.
void NoteRetryBudget(int budget_estimates, double budget_ms, PlanDetail& detail) {
  if (detail.retry_estimates_skipped == 0) return;
  const std::string count = budget_estimates > 0 ? std::to_string(budget_estimates) + " estimates / " : "";
  detail.result.message += " (thorough retry stopped at its budget of " + count +
                           std::to_string(std::lround(budget_ms)) + " ms, " +
                           std::to_string(detail.retry_estimates_skipped) + " estimates not run)";
}

std::vector<int> MatchTruth(const Frame& frame, const PerceptionResult& per) {
  std::vector<int> truth(per.detections.size(), -1);
  if (frame.truth) {
    const LabelImage& labels = frame.truth->labels;
    const bool labelled = frame.organized() && labels.width == frame.depth.width && labels.height == frame.depth.height;
    const Pose X_CB = frame.X_BC.inverse();
    for (size_t d = 0; d < per.detections.size(); ++d) {
      if (labelled) {
        std::map<int, int> votes;
        for (int32_t i : per.detections[d].support) {
          if (i < 0 || static_cast<size_t>(i) >= per.roi_points_B.size()) continue;
          const Vec3 p_C = X_CB * per.roi_points_B[i].cast<double>();
          if (p_C.z() <= 0) continue;
          const int u = static_cast<int>(std::lround(frame.intrinsics.fx * p_C.x() / p_C.z() + frame.intrinsics.cx));
          const int v = static_cast<int>(std::lround(frame.intrinsics.fy * p_C.y() / p_C.z() + frame.intrinsics.cy));
          if (u < 0 || v < 0 || u >= labels.width || v >= labels.height) continue;
          const uint16_t l = labels.at(u, v);
          if (l != 0 && l != GroundTruth::kBinLabel) ++votes[l];
        }
        int best_votes = 0;
        for (const auto& [label, n] : votes) {
          if (n > best_votes) {
            best_votes = n;
            truth[d] = label;
          }
        }
        if (truth[d] >= 0) continue;
      }
      double best = 0.03;  // m: farther than this is not the same part
      for (const PartTruth& t : frame.truth->parts) {
        if (t.class_id != per.detections[d].class_id) continue;
        const double dist = (t.X_BO.translation() - per.detections[d].X_BO.translation()).norm();
        if (dist < best) {
          best = dist;
          truth[d] = t.instance_id;
        }
      }
    }
  }
  return truth;
}

}  // namespace

std::string DefaultTeachFile(const Cell& cell) {
  if (cell.path.empty() || cell.path.front() == '<') return {};
  std::filesystem::path p(cell.path);
  p.replace_extension(".taught.yaml");
  return p.string();
}

Result<std::unique_ptr<BinPickingPlanner>> BinPickingPlanner::Create(const Cell& cell,
                                                                     std::shared_ptr<const Perception> perception,
                                                                     std::unique_ptr<CaptureSource> source,
                                                                     BinPickingPlannerOptions options) {
  if (!perception || !source) return Status::InvalidArgument("grasp planner: perception and source are required");
  if (!(options.thorough_retry_ms > 0) || !std::isfinite(options.thorough_retry_ms)) {
    return Status::InvalidArgument("grasp planner: thorough_retry_ms must be a finite number of milliseconds > 0");
  }
  if (options.thorough_retry_estimates < 0) {
    return Status::InvalidArgument("grasp planner: thorough_retry_estimates must be >= 0 (0: no count)");
  }
  // A support sample stands for its perception grid cell (GraspPlanningOptions::support_grid_spacing).
  if (options.planning.support_grid_spacing > 0) {
    options.planning.support_grid_spacing = perception->options().grid_spacing;
  }
  auto model = GraspPlanningModel::Build(cell, options.planning);
  if (!model.ok()) return model.status();
  std::string teach_file = options.teach_file.empty() ? DefaultTeachFile(cell) : options.teach_file;
  if (teach_file == "-") teach_file.clear();
  auto teach = std::make_unique<TeachStore>(teach_file);
  if (Status s = teach->Load(); !s.ok()) return s;
  std::unique_ptr<BinPickingPlanner> planner(new BinPickingPlanner());
  for (const TaskSpec& task : cell.tasks) {
    if (task.kind != TaskSpec::Kind::kInHand || planner->tool_meshes_.count(task.gripper) > 0) continue;
    const GripperSpec* gripper = cell.FindGripper(task.gripper);
    if (gripper == nullptr || gripper->mesh.empty()) continue;  // the cell loader names a missing gripper
    Result<TriangleMesh> mesh = LoadMesh(gripper->mesh);
    if (!mesh.ok()) return mesh.status();
    planner->tool_meshes_[task.gripper] = std::make_shared<const TriangleMesh>(std::move(*mesh));
  }
  planner->cell_ = cell;
  planner->options_ = options;
  planner->perception_ = std::move(perception);
  planner->model_ = std::move(*model);
  planner->teach_ = std::move(teach);
  planner->source_ = std::move(source);
  return planner;
}

BinPickingPlanner::~BinPickingPlanner() = default;

Result<CaptureHandle> BinPickingPlanner::Capture(const PlanRequest& request) {
  CaptureRequest capture;
  capture.config_id = request.camera_config_id;
  capture.X_BF = request.X_BF;
  if (request.task.kind == TaskSpec::Kind::kInHand) {
    capture.view = CaptureRequest::View::kInHand;
    capture.gripper = request.task.gripper;
  } else if (LooksAtFixture(request.task)) {
    capture.view = CaptureRequest::View::kFixture;
    capture.fixture = request.task.fixture;
  }
  Result<Frame> frame = Status::Unavailable("not captured");
  {
    std::lock_guard lock(source_mutex_);
    frame = source_->Capture(capture);
  }
  if (!frame.ok()) return frame.status();
  // bin.detect: required: a capture into the bin whose bin is not found
  // fails, with the detection's reason. The frame keeps the detection:
  // perception (and a thorough retry) report it instead of measuring again.
  if (capture.view == CaptureRequest::View::kBin && cell_.bin.detect.mode == BinDetectSpec::Mode::kRequired) {
    auto bin = std::make_shared<const BinDetection>(DetectBin(*frame, cell_.bin));
    if (!bin->found) return Status::Unavailable("bin not found (bin.detect: required): " + bin->reason);
    frame->bin = std::move(bin);
  }
  return CaptureHandle(std::make_shared<const CapturedFrame>(std::move(*frame)));
}

Result<PlanResult> BinPickingPlanner::Plan(const PlanRequest& request, const CapturedScene& scene) {
  return PlanWithHead(request, scene, {});
}

Result<PlanResult> BinPickingPlanner::PlanWithHead(const PlanRequest& request, const CapturedScene& scene,
                                                   const HeadReady& on_head) {
  Result<PlanDetail> detail = PlanDetailed(request, scene, on_head);
  if (!detail.ok()) return detail.status();
  return std::move(detail->result);
}

Result<PlanDetail> BinPickingPlanner::PlanDetailed(const PlanRequest& request, const CapturedScene& scene,
                                                   const HeadReady& on_head) {
  const auto* captured = dynamic_cast<const CapturedFrame*>(&scene);
  if (captured == nullptr) return Status::InvalidArgument("grasp planner: scene was not captured by this planner");
  const Frame& frame = captured->frame();
  const TaskSpec& task = request.task;
  PlanDetail detail;
  PlanResult& result = detail.result;
  double grasps_ms = -1, retry_ms = -1;
  std::vector<StageTiming> first_timings;
  std::optional<std::vector<int>> head_truth;  // MatchTruth of the perception a head was published from

  if (task.kind == TaskSpec::Kind::kInHand || LooksAtFixture(task)) {
    if (Status s = PlanElsewhere(request, frame, detail); !s.ok()) return s;
    first_timings = detail.perception.timings;
  } else {
    Result<PerceptionResult> perception = perception_->Run(frame, task.part_classes);
    if (!perception.ok()) return perception.status();
    detail.perception = std::move(*perception);
    first_timings = detail.perception.timings;
    // The head leaves with what the queued grasp will carry (the measured
    // bin), and the task's state is what its hand-out and a teach refer to
    // before the head can reach a robot.
    HeadReady head_ready;
    if (on_head) {
      head_ready = [&](const PlanHead& head) {
        PlanHead h = head;
        if (detail.perception.bin && detail.perception.bin->found) {
          h.grasp.X_BW = detail.perception.bin->X_BW;
          if (h.next) h.next->X_BW = detail.perception.bin->X_BW;
        }
        head_truth = MatchTruth(frame, detail.perception);
        Remember(task.id, detail.perception, *head_truth, &h.grasp);
        on_head(h);
      };
    }
    PlanPick(request, frame, detail, &grasps_ms, &retry_ms, head_ready);
  }
  NoteRetryBudget(options_.thorough_retry_estimates, options_.thorough_retry_ms, detail);

  // The perception the plan is made from (a thorough retry may replace it).
  const PerceptionResult& per = detail.perception;
  result.roi_points = per.roi_point_count;
  result.image_pixels = static_cast<int64_t>(frame.intrinsics.width) * frame.intrinsics.height;
  result.largest_region_points = per.largest_region_points;
  result.bin = per.bin;
  result.fill = per.fill;
  // The grasps stand in the measured bin (failed-pick spots are kept in its frame).
  if (per.bin && per.bin->found) {
    for (Grasp& g : result.grasps) g.X_BW = per.bin->X_BW;
  }
  result.detections = static_cast<int>(per.detections.size());
  for (const Detection& d : per.detections) result.parts.push_back({d.class_id, d.X_BO, d.score});
  for (const StageTiming& st : first_timings) result.stages.push_back({st.stage, st.ms});
  if (grasps_ms >= 0) result.stages.push_back({"grasps", grasps_ms});
  if (retry_ms >= 0) result.stages.push_back({"thorough_retry", retry_ms});  // perception + grasps, used or not

  Remember(task.id, per, head_truth && !detail.thorough_retry ? std::move(*head_truth) : MatchTruth(frame, per),
           result.grasps.empty() ? nullptr : &result.grasps.front());
  return detail;
}

void BinPickingPlanner::Remember(int task_id, const PerceptionResult& per, std::vector<int> truth,
                                 const Grasp* first) {
  std::lock_guard lock(state_mutex_);
  TaskState& state = tasks_[task_id];
  state.detections.clear();
  for (const Detection& d : per.detections) {
    Detection copy;
    copy.class_id = d.class_id;
    copy.X_BO = d.X_BO;
    copy.score = d.score;
    state.detections.push_back(std::move(copy));
  }
  state.truth_instance = std::move(truth);
  state.held_X_BO.reset();
  // Until a grasp is handed out, teaching refers to the first part of the queue.
  if (first != nullptr) {
    state.held_X_BO = first->X_BO;
    state.held_class = first->class_id;
  } else if (!per.detections.empty()) {
    state.held_X_BO = per.detections.front().X_BO;
    state.held_class = per.detections.front().class_id;
  }
}

void BinPickingPlanner::PlanPick(const PlanRequest& request, const Frame& frame, PlanDetail& detail, double* grasps_ms,
                                 double* retry_ms, const HeadReady& on_head) const {
  const TaskSpec& task = request.task;
  PlanResult& result = detail.result;
  std::vector<TaughtGrasp> taught = teach_->All();
  // Grasps on the poses failed last resorts left (grasp/failed_picks.h).
  // `head` (the first run's only: a thorough retry runs when that found
  // none) is told with the same flags as the queue's grasps.
  const auto plan_grasps = [&](PerceptionResult& perception, const HeadReady& head) {
    const std::vector<bool> reposed =
        ApplyRefutedPoses(request.refuted, cell_, BinPoseOf(perception, cell_.bin), perception.detections);
    const auto mark = [&reposed](Grasp& g) {
      g.reposed = g.instance_id >= 0 && static_cast<size_t>(g.instance_id) < reposed.size() &&
                  reposed[static_cast<size_t>(g.instance_id)];
    };
    HeadReady marked;
    if (head) {
      marked = [&head, &mark](const PlanHead& h) {
        PlanHead copy = h;
        mark(copy.grasp);
        if (copy.next) mark(*copy.next);
        head(copy);
      };
    }
    GraspPlan plan = PlanGrasps(*model_, task, perception, taught, &frame, marked);
    for (Grasp& g : plan.queue) mark(g);
    return plan;
  };
  auto t0 = std::chrono::steady_clock::now();
  detail.plan = plan_grasps(detail.perception, on_head);
  *grasps_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  const bool nothing_to_pick = detail.plan.outcome == PlanResult::Outcome::kNoObjects ||
                               detail.plan.outcome == PlanResult::Outcome::kNoCollisionFree;
  if (options_.thorough_retry && nothing_to_pick && detail.perception.largest_region_points > 0) {
    t0 = std::chrono::steady_clock::now();
    // The retry's grasp stage is budgeted at what the normal one took.
    Result<PerceptionResult> again =
        perception_->RunThorough(frame, task.part_classes, RetryBudget(RetryClockMs(), *grasps_ms));
    if (again.ok()) {
      detail.retry_estimates_skipped = again->estimates_skipped;
      GraspPlan plan = plan_grasps(*again, {});
      spdlog::debug("task {}: thorough retry: {} -> {} detections ({} estimates run, {} not, {:.0f} ms), {}", task.id,
                    detail.plan.stats.Describe(), again->detections.size(), again->estimator_calls,
                    again->estimates_skipped,
                    std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count(),
                    plan.stats.Describe());
      // Adopted when it gives grasps, and also when it finds parts where
      // the normal run found none: the answer is then "no collision-free
      // grasp" for the parts it found, not "no object".
      if (plan.outcome == PlanResult::Outcome::kGrasps ||
          (detail.plan.outcome == PlanResult::Outcome::kNoObjects &&
           plan.outcome == PlanResult::Outcome::kNoCollisionFree)) {
        detail.perception = std::move(*again);
        detail.plan = std::move(plan);
        detail.thorough_retry = true;
      }
    }
    *retry_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  }
  result.outcome = detail.plan.outcome;
  result.grasps = detail.plan.queue;
  result.ungrasped_touching = detail.plan.ungrasped_touching;
  result.message = detail.plan.stats.Describe();
  if (result.outcome == PlanResult::Outcome::kNoObjects && !detail.perception.reason.empty()) {
    result.message = detail.perception.reason;
  }
  if (detail.thorough_retry) result.message += " (after a thorough perception retry)";
}

PerceptionBudget BinPickingPlanner::RetryBudget(double started_ms, double reserve_ms) const {
  PerceptionBudget budget;
  budget.deadline_ms = started_ms + options_.thorough_retry_ms - std::max(0.0, reserve_ms);
  budget.now_ms = options_.retry_clock_ms;
  budget.max_estimates = options_.thorough_retry_estimates;
  return budget;
}

double BinPickingPlanner::RetryClockMs() const {
  return options_.retry_clock_ms ? options_.retry_clock_ms() : SteadyClockMs();
}

Status BinPickingPlanner::PlanElsewhere(const PlanRequest& request, const Frame& frame, PlanDetail& detail) const {
  const TaskSpec& task = request.task;
  PerceptionRegion region;
  region.box_R = task.roi;
  std::vector<int> classes = task.part_classes;
  const FixtureSpec* fixture = nullptr;
  if (task.kind == TaskSpec::Kind::kInHand) {
    if (!request.X_BF) {
      return Status::InvalidArgument("in-hand task " + std::to_string(task.id) + " needs the robot's tool pose");
    }
    region.X_BR = *request.X_BF;  // X_BT: the box moves with the tool
    region.support = false;       // a held part may sit tilted across the cup's lip
    // The gripper is in view: its points are no part's. Dropping them lets
    // the box reach below the tool centre point, where a part held on its
    // side hangs (a tee held on its run with the branch toward the flange:
    // its branch is the only cue to its turn about the run).
    if (auto mesh = tool_meshes_.find(task.gripper); mesh != tool_meshes_.end()) region.clear_mesh_R = mesh->second;
  } else {
    fixture = cell_.FindFixture(task.fixture);
    if (fixture == nullptr) return Status::Internal("task " + std::to_string(task.id) + ": no fixture " + task.fixture);
    region.X_BR = fixture->X_BP_taught;
    classes = {fixture->class_id};
  }
  Result<PerceptionResult> perception = perception_->Run(frame, classes, PerceptionEffort::kNormal, region);
  if (!perception.ok()) return perception.status();
  if (perception->detections.empty() && perception->largest_region_points > 0) {
    // As for picks: a thorough run before answering "nothing there".
    Result<PerceptionResult> again = perception_->RunThorough(frame, classes, RetryBudget(RetryClockMs(), 0.0),
                                                              region);
    if (again.ok()) detail.retry_estimates_skipped = again->estimates_skipped;
    if (again.ok() && !again->detections.empty()) {
      perception = std::move(again);
      detail.thorough_retry = true;
    }
  }
  detail.perception = std::move(*perception);
  PlanResult& result = detail.result;
  const PerceptionResult& per = detail.perception;
  int best = -1;
  for (int d = 0; d < static_cast<int>(per.detections.size()); ++d) {
    if (best < 0 || per.detections[d].score > per.detections[best].score) best = d;
  }
  if (best < 0) {
    result.outcome = PlanResult::Outcome::kNoObjects;
    result.message = per.reason.empty() ? "nothing detected" : per.reason;
    return Status::Ok();
  }
  const Detection& det = per.detections[best];
  const std::optional<HeldPart> held = this->held();
  Grasp g;
  g.X_BO = det.X_BO;
  g.instance_id = best;
  g.class_id = det.class_id;
  g.score = det.score;
  if (task.kind == TaskSpec::Kind::kInHand) {
    g.name = "in_hand";
    g.X_BT = request.X_BF->inverse() * det.X_BO;  // X_TO
    g.X_BT_pre = g.X_BT;
    const PartSpec* part = cell_.FindPart(det.class_id);
    if (held && held->class_id == det.class_id && part != nullptr) {
      // An ambiguous view (a tee seen from below with its branch behind the
      // cup) explains its alternatives as well as X_BO: the part held is
      // the one nearest to what binpick believes it holds.
      g.X_BT = NearestToHeld(*request.X_BF, det, held->X_TO, part->symmetry);
      g.X_BO = *request.X_BF * g.X_BT;
      g.X_BT_pre = g.X_BT;
      const double off_m = SymmetricTranslationError(g.X_BT, held->X_TO, part->symmetry);
      const double off_rad = SymmetricRotationError(g.X_BT, held->X_TO, part->symmetry);
      if (off_m > kInHandMaxDeviationM || off_rad > kInHandMaxDeviationRad) {
        char why[200];
        std::snprintf(why, sizeof(why),
                      "in-hand pose %.1f mm / %.1f deg from the part held as %s (limits %.0f mm / %.0f deg): "
                      "not trusted, the estimate may have the part turned over",
                      1000 * off_m, off_rad * 180 / M_PI, held->measured ? "last measured" : "picked",
                      1000 * kInHandMaxDeviationM, kInHandMaxDeviationRad * 180 / M_PI);
        spdlog::warn("task {}: {}", task.id, why);
        result.outcome = PlanResult::Outcome::kNoObjects;
        result.message = why;
        return Status::Ok();
      }
    }
  } else if (task.kind == TaskSpec::Kind::kPlaceArea) {
    g.name = "place_offset";
    g.X_BT = det.X_BO * fixture->X_BP_taught.inverse();  // X_off
    g.X_BT_pre = g.X_BT;
    g.related_X_B.push_back(det.X_BO);
    // seed 003: tool_in_base = place_in_base * obj_in_Place * inv(obj_in_tool).
    if (held) g.implied_X_BT.push_back(g.X_BT * fixture->X_BP_taught * fixture->X_PO * held->X_TO.inverse());
  } else {
    if (!held) {
      result.outcome = PlanResult::Outcome::kNoObjects;
      result.message = "fixture " + fixture->name + " found, but no part was handed out to place";
      return Status::Ok();
    }
    const GripperSpec* gripper = cell_.FindGripper(task.gripper);
    g.name = "drop_off";
    g.X_BT = det.X_BO * fixture->X_PO * held->X_TO.inverse();
    g.X_BT_pre = g.X_BT * MakePose(Mat3::Identity(), Vec3(0, 0, -(gripper ? gripper->approach_distance : 0.0)));
    g.related_X_B.push_back(det.X_BO);
    g.class_id = held->class_id;
  }
  result.outcome = PlanResult::Outcome::kGrasps;
  result.grasps.push_back(std::move(g));
  return Status::Ok();
}

std::optional<BinPickingPlanner::HeldPart> BinPickingPlanner::held() const {
  std::lock_guard lock(state_mutex_);
  return held_;
}

int BinPickingPlanner::TruthInstanceOf(int task_id, int detection) const {
  std::lock_guard lock(state_mutex_);
  auto it = tasks_.find(task_id);
  if (it == tasks_.end() || detection < 0 || detection >= static_cast<int>(it->second.truth_instance.size())) {
    return -1;
  }
  return it->second.truth_instance[detection];
}

void BinPickingPlanner::NotifyHandedOut(const TaskSpec& task, const Grasp& grasp) {
  int instance = -1;
  const bool pick = task.kind == TaskSpec::Kind::kPick || task.kind == TaskSpec::Kind::kPick2D;
  {
    std::lock_guard lock(state_mutex_);
    TaskState& state = tasks_[task.id];
    state.held_X_BO = grasp.X_BO;
    state.held_class = grasp.class_id;
    if (grasp.instance_id >= 0 && grasp.instance_id < static_cast<int>(state.truth_instance.size())) {
      instance = state.truth_instance[grasp.instance_id];
    }
    if (task.kind == TaskSpec::Kind::kPick) {
      held_ = HeldPart{grasp.class_id, grasp.X_BT.inverse() * grasp.X_BO, false};
    } else if (task.kind == TaskSpec::Kind::kInHand) {
      held_ = HeldPart{grasp.class_id, grasp.X_BT, true};
    } else if (LooksAtFixture(task)) {
      held_.reset();
    }
  }
  if (LooksAtFixture(task)) {
    std::lock_guard lock(source_mutex_);
    source_->NotifyReleased();
    return;
  }
  // Only picks take a part out of the bin (in-hand results do not).
  if (instance < 0 || !pick) return;
  std::lock_guard lock(source_mutex_);
  // 2D picks' X_BT is in the robot's plane frame: no tool pose in base.
  source_->NotifyPicked(instance, task.kind == TaskSpec::Kind::kPick ? std::optional<Pose>(grasp.X_BT) : std::nullopt);
}

Status BinPickingPlanner::Teach(const TeachRequest& request) {
  TaughtGrasp g;
  {
    std::lock_guard lock(state_mutex_);
    auto it = tasks_.find(request.task.id);
    if (it == tasks_.end() || !it->second.held_X_BO) {
      return Status::NotFound("task " + std::to_string(request.task.id) + " has no detected part to teach on");
    }
    g.class_id = it->second.held_class;
    g.X_OG = it->second.held_X_BO->inverse() * request.X_BT;
  }
  g.gripper = request.task.gripper;
  return teach_->Add(std::move(g));
}

}  // namespace bp
