#include "grasp/bin_clearing.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <optional>
#include <random>
#include <system_error>
#include <utility>

#include "grasp/bin_picking_planner.h"
#include "grasp/empty_box.h"
#include "grasp/failed_picks.h"
#include "grasp/grasp_planning.h"
#include "grasp/grasp_queue.h"
#include "pipeline/capture_source.h"
#include "pipeline/evaluation.h"
#include "pipeline/frame_io.h"
#include "pipeline/pose_estimator.h"
#include "pipeline/synthetic_source.h"

namespace bp {

namespace {

// The pile as it is now (after the picks since the last capture), in base.
std::vector<PartTruth> PileTruth(const SyntheticSource& source) {
  std::vector<PartTruth> out;
  for (const PilePart& p : source.pile().parts()) {
    PartTruth t;
    t.instance_id = p.instance_id;
    t.class_id = p.class_id;
    t.class_name = source.pile().classes()[p.class_index].name;
    t.X_BO = source.X_BW() * p.X_WO;
    t.visible_fraction = 1.0;
    out.push_back(std::move(t));
  }
  return out;
}

const PartTruth* FindInstance(const std::vector<PartTruth>& parts, int instance) {
  for (const PartTruth& p : parts) {
    if (p.instance_id == instance) return &p;
  }
  return nullptr;
}

// The simulated robot's failed-pick reports (ClearOptions::feedback): one
// FailedPicks per task, as binpickd keeps them (comms/request_handler.cc).
class Feedback {
 public:
  Feedback(const Cell& cell, bool on) : cell_(cell), on_(on) {}
  // nullptr when the feedback is off.
  FailedPicks* For(const TaskSpec& task) {
    if (!on_) return nullptr;
    auto& f = by_task_[task.id];
    if (!f) f = std::make_unique<FailedPicks>(task.failed_picks, cell_.bin.X_BW);
    return f.get();
  }
  // A capture: every task's spots age.
  void OnCapture() {
    for (auto& [id, f] : by_task_) f->OnCapture();
  }

 private:
  const Cell& cell_;
  const bool on_;
  std::map<int, std::unique_ptr<FailedPicks>> by_task_;
};

// An ambiguous detection's other poses and its true pose X_BO_true, each
// as the turn from its X_BO (rotation vector in the part frame, deg, and the
// shift, mm), for the debug log: where the truth lies in the span of the
// poses the view allows. Empty when the detection is not ambiguous. Only a
// discrete symmetry's copies are tried (the nearest one is given); a
// revolute part's free spin and Symmetry::extra stay in the turn, unlike
// SymmetricRotationError, which gives the angle alone.
std::string TurnsFromBestPose(const Detection& d, const PartSpec& part, const Pose& X_BO_true) {
  if (d.alternatives_X_BO.empty()) return {};
  const auto turn = [&](const Pose& X) {
    Eigen::AngleAxisd best(Eigen::Matrix3d::Identity());
    Vec3 shift = Vec3::Zero();
    const int order = part.symmetry.kind == Symmetry::Kind::kDiscrete ? part.symmetry.order : 1;
    for (int k = 0; k < order; ++k) {
      const Pose rel = d.X_BO.inverse() * X * Pose(Eigen::AngleAxisd(2 * M_PI * k / order, part.symmetry.axis));
      const Eigen::AngleAxisd aa(rel.linear());
      if (k == 0 || aa.angle() < best.angle()) {
        best = aa;
        shift = rel.translation();
      }
    }
    const Vec3 r = best.axis() * best.angle() * 180 / M_PI;
    return fmt::format("({:.1f}, {:.1f}, {:.1f}) deg {:.1f} mm", r.x(), r.y(), r.z(), 1000 * shift.norm());
  };
  std::string line = "poses from X_BO: truth " + turn(X_BO_true) + "; others";
  for (const Pose& a : d.alternatives_X_BO) line += " " + turn(a);
  return line;
}

// What one task's plan of a capture made of one true part: the detections
// standing for it and its grasp candidates' verdicts (LeftCause).
struct PartLook {
  int detections = 0;     // detections matched to the part
  int other_class = 0;    // of which detected as another class
  int candidates = 0;
  int accepted = 0;       // candidates no filter refused
  int queued = 0;         // grasps on it in the plan after the feedback's screen
  std::array<int, kNumRejectReasons> rejected{};
};

struct TaskLook {
  int task_id = 0;
  std::map<int, PartLook> parts;  // true instance -> what the plan made of it
};

// `detail` as the task's queue would take it (after ScreenPlan).
TaskLook LookOf(const BinPickingPlanner& p, const TaskSpec& task, const PlanDetail& detail,
                const std::vector<PartTruth>& truth) {
  TaskLook look;
  look.task_id = task.id;
  std::vector<int> instance(detail.perception.detections.size(), -1);
  for (size_t i = 0; i < instance.size(); ++i) {
    instance[i] = p.TruthInstanceOf(task.id, static_cast<int>(i));
    if (instance[i] < 0) continue;
    PartLook& part = look.parts[instance[i]];
    ++part.detections;
    const PartTruth* t = FindInstance(truth, instance[i]);
    if (t != nullptr && t->class_id != detail.perception.detections[i].class_id) ++part.other_class;
  }
  const auto of = [&](int detection) -> PartLook* {
    if (detection < 0 || static_cast<size_t>(detection) >= instance.size() || instance[detection] < 0) return nullptr;
    return &look.parts[instance[detection]];
  };
  for (const GraspCandidate& c : detail.plan.candidates) {
    PartLook* part = of(c.detection);
    if (part == nullptr) continue;
    ++part->candidates;
    if (c.rejected) {
      ++part->rejected[static_cast<size_t>(*c.rejected)];
    } else {
      ++part->accepted;
    }
  }
  for (const Grasp& g : detail.result.grasps) {
    if (PartLook* part = of(g.instance_id)) ++part->queued;
  }
  return look;
}

// A task's plan as its queue would hold it: the failed-pick feedback's
// screen applied (the queue applies it at Replace too, to the same effect).
// A part whose grasp is screened out stays in the bin and passes staleness
// on (GraspQueue): it joins plan.ungrasped_touching, as the queue's own
// screen keeps it.
void ScreenPlan(Feedback& feedback, const TaskSpec& task, PlanResult& plan, SceneClearReport& report) {
  FailedPicks* f = feedback.For(task);
  if (f == nullptr) return;
  f->Seen(plan.parts, plan.bin ? std::optional<Pose>(plan.bin->X_BW) : std::nullopt);  // as binpickd's detection
  if (plan.grasps.empty()) return;
  const std::vector<Grasp> screened = f->Screen(plan.grasps);
  report.screened += static_cast<int>(screened.size());
  for (const Grasp& g : screened) {
    if (!g.touching.empty()) plan.ungrasped_touching[g.instance_id] = g.touching;
  }
  if (plan.grasps.empty()) plan.outcome = PlanResult::Outcome::kNoCollisionFree;
}

// The plan whose grasps the robot takes on this capture: the primary task's,
// else the first fallback task's with a grasp. `primary` is always the
// primary task's (the final empty-box answer is the primary task's).
struct CyclePlan {
  PlanResult primary;
  PlanResult taken;
  const TaskSpec* used = nullptr;
  std::vector<TaskLook> looks;  // every task planned on this capture, in order
};

// The first pose early (docs/protocols.md), checked on a plan whose head
// the planner told early: that head queued alone (GraspQueue::PublishHead)
// and handed out, then the plan merged in, must hand out the grasps the plan
// queued at once hands out, in the same order (none twice, none lost), with
// remaining counts that fall at every answer, the head's bound 1 exactly
// when nothing follows it. No feedback screen in either queue: the check is
// of the head and the merge.
bool EarlyHeadAgrees(const PlanHead& head, const PlanResult& plan) {
  using Handed = std::pair<int, std::string>;
  std::vector<Handed> want, got;
  GraspQueue direct;
  direct.Replace(plan, 1);
  for (GraspQueue::Popped p = direct.Pop(); p.grasp; p = direct.Pop()) want.emplace_back(p.grasp->instance_id, p.grasp->name);
  GraspQueue early;
  if (!early.PublishHead(head.grasp, head.max_queue, 1, nullptr, head.next ? &*head.next : nullptr)) return false;
  const GraspQueue::Popped first = early.Pop();
  if (!first.grasp || first.remaining != head.max_queue) return false;
  got.emplace_back(first.grasp->instance_id, first.grasp->name);
  int last = first.remaining;
  early.Replace(plan, 1);
  for (GraspQueue::Popped p = early.Pop(); p.grasp; p = early.Pop()) {
    if (p.remaining >= last) return false;
    last = p.remaining;
    got.emplace_back(p.grasp->instance_id, p.grasp->name);
  }
  return (head.max_queue == 1) == (got.size() == 1) && got == want;
}

// Plans `request` as binpickd does, the head told early (PlanWithHead), and
// counts the heads and those EarlyHeadAgrees refuses (an error log each).
Result<PlanDetail> PlanCheckingHead(BinPickingPlanner& p, const PlanRequest& request, const CapturedScene& scene,
                                    uint64_t seed, SceneClearReport& report) {
  std::optional<PlanHead> head;
  auto detail = p.PlanDetailed(request, scene, [&head](const PlanHead& h) { head = h; });
  if (!detail.ok() || !head) return detail;
  ++report.early_heads;
  if (!EarlyHeadAgrees(*head, detail->result)) {
    ++report.early_head_mismatches;
    spdlog::error("seed {} cycle {} task {}: the head told early (part {}, {}, bound {}) disagrees with its plan", seed,
                  report.cycles + 1, request.task.id, head->grasp.instance_id, head->grasp.name, head->max_queue);
  }
  return detail;
}

Result<CyclePlan> PlanCycle(BinPickingPlanner& p, const CapturedScene& scene, const TaskSpec& task,
                            const std::vector<const TaskSpec*>& fallbacks, uint64_t seed, Feedback& feedback,
                            SceneClearReport& report) {
  // Every candidate of a task's plan and why it was rejected (debug log).
  const auto log_candidates = [&](const TaskSpec& t, const PlanDetail& plan) {
    if (!spdlog::should_log(spdlog::level::debug)) return;
    const auto& truth = static_cast<const CapturedFrame&>(scene).frame().truth;
    for (size_t i = 0; i < plan.perception.detections.size(); ++i) {
      const Detection& d = plan.perception.detections[i];
      const int instance = p.TruthInstanceOf(t.id, static_cast<int>(i));
      const PartTruth* part = truth ? FindInstance(truth->parts, instance) : nullptr;
      const PartSpec* spec = part ? p.model().cell().FindPart(part->class_id) : nullptr;
      // The detection's pose against its truth, modulo symmetry (a gross
      // error: the right part in a wrong pose).
      const std::string off =
          spec != nullptr && part->class_id == d.class_id
              ? fmt::format(", off its truth {:.1f} mm / {:.1f} deg",
                            1000 * SymmetricTranslationError(d.X_BO, part->X_BO, spec->symmetry),
                            SymmetricRotationError(d.X_BO, part->X_BO, spec->symmetry) * 180 / M_PI)
              : std::string();
      spdlog::debug("seed {} cycle {} task {}: detection {} class {} (truth {}, class {}): score {:.3f}, visible {:.2f}, "
                    "rms {:.2f} mm, support {}, alternatives {}{}",
                    seed, report.cycles + 1, t.id, i, d.class_id, instance, part ? part->class_id : -1, d.score,
                    d.visible_fraction, 1000 * d.rms_residual, d.support.size(), d.alternatives_X_BO.size(), off);
      if (spec != nullptr) {
        const std::string turns = TurnsFromBestPose(d, *spec, part->X_BO);
        if (!turns.empty()) spdlog::debug("seed {} cycle {} task {}: detection {} {}", seed, report.cycles + 1, t.id, i, turns);
      }
    }
    for (const GraspCandidate& c : plan.plan.candidates) {
      // The cycle as the picks of this plan are logged (numbered from 1).
      const Vec3 at = 1000 * c.X_BT.translation();
      const Vec3 z = c.X_BT.linear().col(2);
      spdlog::debug("seed {} cycle {} task {}: detection {} (truth {}) {} tilt {:.0f} deg at ({:.0f}, {:.0f}, {:.0f}) mm "
                    "approach ({:.2f}, {:.2f}, {:.2f}): {}{}",
                    seed, report.cycles + 1, t.id, c.detection, p.TruthInstanceOf(t.id, c.detection), c.name,
                    c.tilt_rad * 180 / M_PI, at.x(), at.y(), at.z(), z.x(), z.y(), z.z(),
                    c.rejected ? ToString(*c.rejected) : "ok", c.seal_only ? " (seal only)" : "");
    }
  };
  // The poses the task's failed last resorts refuted (grasp/failed_picks.h).
  const auto refuted = [&feedback](const TaskSpec& t) {
    FailedPicks* f = feedback.For(t);
    return f ? f->Refuted() : std::vector<RefutedPose>{};
  };
  CyclePlan out;
  PlanRequest request;
  request.task = task;
  request.refuted = refuted(task);
  const auto t0 = std::chrono::steady_clock::now();
  auto detail = PlanCheckingHead(p, request, scene, seed, report);
  report.plan_ms_total += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  if (!detail.ok()) return detail.status();
  log_candidates(task, *detail);
  ScreenPlan(feedback, task, detail->result, report);
  const auto& truth = static_cast<const CapturedFrame&>(scene).frame().truth;
  const std::vector<PartTruth> no_truth;
  const std::vector<PartTruth>& parts = truth ? truth->parts : no_truth;
  out.looks.push_back(LookOf(p, task, *detail, parts));
  out.primary = detail->result;
  out.taken = detail->result;
  out.used = &task;
  if (!out.primary.grasps.empty()) return out;
  for (const TaskSpec* fb : fallbacks) {
    PlanRequest fb_request;
    fb_request.task = *fb;
    fb_request.refuted = refuted(*fb);
    const auto t1 = std::chrono::steady_clock::now();
    auto fb_detail = PlanCheckingHead(p, fb_request, scene, seed, report);
    report.plan_ms_total += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t1).count();
    if (!fb_detail.ok()) return fb_detail.status();
    log_candidates(*fb, *fb_detail);
    ScreenPlan(feedback, *fb, fb_detail->result, report);
    out.looks.push_back(LookOf(p, *fb, *fb_detail, parts));
    if (!fb_detail->result.grasps.empty()) {
      out.taken = std::move(fb_detail->result);
      out.used = fb;
      break;
    }
  }
  return out;
}

// A pick judged against the pile as it is now.
struct PickVerdict {
  bool success = false;
  int landed = -1;     // true instance the tool lands on (success: the part taken out)
  std::string cause;   // failure cause (bin_clearing.h)
  std::string line;    // the failure, for the report
};

// The grasp's verdict on one view of the pile: where it lands, and what the
// swept gripper hits (the bin where it truly stands, X_BW, another true
// part), if anything (CheckPickOnTruth).
struct Landing {
  GraspOutcome outcome;
  std::optional<RejectReason> hit;
  std::vector<Detection> parts;  // the pile as detections (for the collision report)
  int target = -1;               // index in `parts` of the part the tool touches down on, -1 none
};

Landing Land(const BinPickingPlanner& p, const TaskSpec& used, const Grasp& grasp, const std::vector<PartTruth>& pile,
             const Pose& X_BW, const GraspJudgeOptions& options) {
  Landing l;
  l.outcome = JudgeGrasp(p.model(), used.gripper, grasp, pile, options);
  PickContact contact = CheckPickOnTruth(p.model(), used.gripper, grasp, pile, l.outcome, X_BW);
  l.hit = contact.hit;
  l.target = contact.touched;
  l.parts = std::move(contact.parts);
  return l;
}

PickVerdict JudgePick(const BinPickingPlanner& p, const TaskSpec& used, const Grasp& grasp, int cycle,
                      const std::vector<PartTruth>& at_capture, const std::vector<PartTruth>& now,
                      const Pose& X_BW, const GraspJudgeOptions& options, SceneClearReport& report) {
  PickVerdict v;
  const Landing l = Land(p, used, grasp, now, X_BW, options);
  v.landed = l.outcome.truth_instance;
  if (l.hit) {
    ++report.truth_collisions;
    std::string line = "cycle " + std::to_string(cycle) + ": task " + std::to_string(used.id) + " grasp " + grasp.name +
                       " (detection " + std::to_string(grasp.instance_id) + ") on instance " +
                       std::to_string(l.outcome.truth_instance) + ": " + std::string(ToString(*l.hit));
    for (size_t j = 0; j < now.size(); ++j) {
      if (static_cast<int>(j) == l.target) continue;
      const Detection pair[] = {l.parts[j]};
      // The part alone: a grasp into the bin hits it whatever the part.
      if (!p.model().CheckAgainstParts(used.gripper, grasp.X_BT, pair, -1, X_BW, /*with_bin=*/false)) continue;
      line += "; hits instance " + std::to_string(now[j].instance_id) + " (" + now[j].class_name + ")";
    }
    report.collisions.push_back(std::move(line));
  }
  v.success = l.outcome.on_part && !l.hit;
  if (v.success) return v;
  // Stale: the pick would have succeeded on the pile as captured; what
  // changed since (earlier picks of the queue and the resettling) made it fail.
  const Landing then = Land(p, used, grasp, at_capture, X_BW, options);
  const bool stale = then.outcome.on_part && !then.hit;
  v.cause = stale ? "stale_queue" : l.hit ? "collision" : l.outcome.failure;
  char detail[200];
  std::snprintf(detail, sizeof(detail), "%s, %.1f mm / %.1f deg from instance %d's grasp point%s", v.cause.c_str(),
                1000 * l.outcome.position_error, l.outcome.approach_error * 180 / M_PI, l.outcome.truth_instance,
                stale ? " (it would have landed on the pile as captured)" : "");
  v.line = "cycle " + std::to_string(cycle) + ": task " + std::to_string(used.id) + " grasp " + grasp.name +
           " (detection " + std::to_string(grasp.instance_id) + (grasp.last_resort ? ", a last resort" : "") +
           (grasp.reposed ? ", on a pose left by a failed last resort" : "") + "): " + detail +
           (l.target >= 0 && now[l.target].instance_id != l.outcome.truth_instance
                ? "; the tool touches down on instance " + std::to_string(now[l.target].instance_id)
                : "");
  return v;
}

// "3, 7, 12" (debug log).
std::string JoinIds(const std::vector<int>& ids) {
  std::string out;
  for (int id : ids) out += (out.empty() ? "" : ", ") + std::to_string(id);
  return out;
}

// The parts the resettling after a pick moved, and how far (debug log).
void LogResettled(const std::vector<PartTruth>& before, const std::vector<PartTruth>& after) {
  for (const PartTruth& a : after) {
    const PartTruth* b = FindInstance(before, a.instance_id);
    if (b == nullptr) continue;
    const double moved = (a.X_BO.translation() - b->X_BO.translation()).norm();
    if (moved > 1e-4) spdlog::debug("  resettled: instance {} ({}) dropped {:.1f} mm", a.instance_id, a.class_name, 1000 * moved);
  }
}

// What serving one capture's queue needs besides the queue.
struct Serving {
  BinPickingPlanner& planner;
  SyntheticSource& pile;
  const TaskSpec& used;
  bool fallback = false;  // `used` is a fallback task
  FailedPicks* feedback = nullptr;
  std::mt19937_64& slip_rng;
  const std::vector<PartTruth>& at_capture;
  const ClearOptions& options;
};

// Takes the queue's grasps one by one like the seed robot (or only the
// first), each judged on the pile as it is now; a pick the judge lets
// succeed fails anyway with probability slip_rate. A failed pick is
// reported (feedback) and the queue screened again at once.
void ServeQueue(const Serving& s, GraspQueue& queue, SceneClearReport& report) {
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  for (GraspQueue::Popped popped = queue.Pop(); popped.grasp; popped = queue.Pop()) {
    report.withdrawn += static_cast<int>(popped.withdrawn.size());
    const int collisions_before = report.truth_collisions;
    PickVerdict v = JudgePick(s.planner, s.used, *popped.grasp, report.cycles, s.at_capture, PileTruth(s.pile),
                              s.pile.X_BW(), s.options.judge, report);
    ++report.attempts;
    GraspTally& tally = report.by_grasp[GraspBaseName(popped.grasp->name)];
    ++tally.attempts;
    tally.collisions += report.truth_collisions - collisions_before;
    const bool slip = uniform(s.slip_rng) < s.options.slip_rate;  // drawn for every pick
    if (v.success && slip) {
      v.success = false;
      v.cause = "slipped";
      v.line = "cycle " + std::to_string(report.cycles) + ": task " + std::to_string(s.used.id) + " grasp " +
               popped.grasp->name + " (detection " + std::to_string(popped.grasp->instance_id) +
               "): slipped off instance " + std::to_string(v.landed) + " (--slip); it stays";
      ++report.slipped;
    }
    spdlog::debug("seed {} cycle {}: task {} grasp {} on detection {} (stale after parts [{}], touching [{}]) lands on "
                  "instance {}: {}",
                  report.seed, report.cycles, s.used.id, popped.grasp->name, popped.grasp->instance_id,
                  JoinIds(popped.grasp->stale_after), JoinIds(popped.grasp->touching), v.landed,
                  v.success ? "picked" : v.cause);
    if (v.success) {
      ++report.picks;
      ++tally.picks;
      if (s.fallback) ++report.fallback_picks;
      const std::vector<PartTruth> before = PileTruth(s.pile);
      s.pile.NotifyPicked(v.landed);  // removes it and lets the rest resettle
      if (spdlog::should_log(spdlog::level::debug)) LogResettled(before, PileTruth(s.pile));
    } else {
      ++report.failed_picks;
      report.stale_failures += v.cause == "stale_queue" ? 1 : 0;
      ++report.failure_causes[v.cause];
      report.failures.push_back(v.line);
      if (s.feedback) {
        // What the robot can tell: it stopped on contact, the part slipped
        // off, or the vacuum never built.
        const PickFailure reason = v.cause == "collision" ? PickFailure::kCollision
                                   : v.cause == "slipped" ? PickFailure::kSlipped
                                                          : PickFailure::kNoVacuum;
        s.feedback->Report(*popped.grasp, reason);
        ++report.reported;
        report.screened += queue.Rescreen();
      }
    }
    if (!s.options.serve_queue) break;
  }
}

// "instance 7 (l_bracket) at (...) mm: part z axis (...), up is part +y, 83% visible"
std::string DescribeLeft(const PartTruth& t) {
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
  return line;
}

// Per true instance of a synthetic frame: the pixels its label covers (the
// render before noise and dropout) and, of those, the ones with a depth
// measurement.
struct Pixels {
  int labelled = 0;
  int measured = 0;
};
std::map<int, Pixels> PixelsOf(const Frame& frame) {
  std::map<int, Pixels> out;
  if (!frame.truth) return out;
  const LabelImage& labels = frame.truth->labels;
  const bool same = labels.width == frame.depth.width && labels.height == frame.depth.height;
  for (size_t i = 0; i < labels.data.size(); ++i) {
    const uint16_t l = labels.data[i];
    if (l == 0 || l == GroundTruth::kBinLabel) continue;
    Pixels& px = out[l];
    ++px.labelled;
    if (same && std::isfinite(frame.depth.data[i])) ++px.measured;
  }
  return out;
}

// Why part `t`, left at the end, stayed (SceneClearReport::left_causes),
// and what the last capture's plans made of it, for its `left` line.
std::pair<std::string, std::string> LeftCause(const PartTruth& t, const std::vector<TaskLook>& looks,
                                              const Pixels& pixels, const Pose& X_BW_true, const Vec3& bin_inner,
                                              bool cycle_cap) {
  const Vec3 in_bin = X_BW_true.inverse() * t.X_BO.translation();
  if (std::abs(in_bin.x()) > bin_inner.x() / 2 || std::abs(in_bin.y()) > bin_inner.y() / 2) {
    return {"out_of_bin", fmt::format("at ({:.0f}, {:.0f}, {:.0f}) mm in the bin", 1000 * in_bin.x(),
                                      1000 * in_bin.y(), 1000 * in_bin.z())};
  }
  std::string detail = fmt::format("{} of {} labelled pixels measured", pixels.measured, pixels.labelled);
  int detections = 0, other_class = 0, accepted = 0, queued = 0, candidates = 0;
  std::array<int, kNumRejectReasons> rejected{};
  for (const TaskLook& look : looks) {
    auto it = look.parts.find(t.instance_id);
    if (it == look.parts.end()) continue;
    const PartLook& part = it->second;
    detections += part.detections;
    other_class += part.other_class;
    accepted += part.accepted;
    queued += part.queued;
    candidates += part.candidates;
    std::string reasons;
    for (int r = 0; r < kNumRejectReasons; ++r) {
      rejected[r] += part.rejected[r];
      if (part.rejected[r] > 0) {
        reasons += fmt::format("{}{} {}", reasons.empty() ? "" : ", ", ToString(static_cast<RejectReason>(r)),
                               part.rejected[r]);
      }
    }
    detail += fmt::format("; task {}: {} detection(s){}, {} candidates, {} accepted, {} queued{}{}", look.task_id,
                          part.detections, part.other_class > 0 ? fmt::format(" ({} of another class)", part.other_class) : "",
                          part.candidates, part.accepted, part.queued, reasons.empty() ? "" : ": ", reasons);
  }
  if (cycle_cap) return {"cycle_cap", detail};
  if (detections == 0) return {"undetected", detail};
  if (other_class == detections) return {"wrong_class", detail};
  if (accepted > 0 && queued == 0) return {"refused_by_feedback", detail};
  if (candidates == 0) return {"no_grasp:no_candidates", detail};
  // The filters run in RejectReason's order, each candidate refused by the
  // first that fails: the last filter any candidate reached is the one that
  // stood between the part and a grasp (tilt refuses the grasps from below
  // on every pose, so the most frequent reason says little).
  int furthest = kNumRejectReasons - 1;
  while (furthest > 0 && rejected[furthest] == 0) --furthest;
  return {"no_grasp:" + std::string(ToString(static_cast<RejectReason>(furthest))), detail};
}

Status SaveLeft(const Frame& frame, const std::string& dir, uint64_t seed, SceneClearReport& report) {
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (ec) return Status::Internal("clear: cannot create '" + dir + "': " + ec.message());
  const std::string path = (std::filesystem::path(dir) / ("clear_seed" + std::to_string(seed) + "_depth.png")).string();
  if (Status s = WriteDepthPng(frame, path); !s.ok()) return s;
  if (Status s = WriteGroundTruthJson(frame, CompanionPath(path, "truth.json")); !s.ok()) return s;
  report.saved_frame = path;
  return Status::Ok();
}

}  // namespace

std::string GraspBaseName(const std::string& name) { return name.substr(0, name.find_first_of("@~")); }

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
  auto source = MakeSyntheticSource(cell);
  if (!source.ok()) return source.status();
  // The planner owns the source; clearing reads its pile between picks and
  // takes out the part a pick really landed on. One thread: no race with the
  // planner's own use.
  auto* pile = dynamic_cast<SyntheticSource*>(source->get());
  if (pile == nullptr) return Status::Internal("clear: the synthetic source is not a SyntheticSource");
  BinPickingPlannerOptions planner_options;
  planner_options.teach_file = "-";  // clearing never teaches
  planner_options.thorough_retry_ms = options.thorough_retry_ms;
  planner_options.thorough_retry_estimates = options.thorough_retry_estimates;
  planner_options.planning.part_margin = options.part_margin;
  planner_options.planning.dropout_ends_at_parts = options.dropout_ends_at_parts;
  planner_options.planning.hidden_behind_parts = options.hidden_behind_parts;
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
  std::vector<TaskLook> last_looks;  // the last capture's plans (LeftCause)
  std::map<int, Pixels> last_pixels;
  Pose X_BW_true = pile->X_BW();
  bool cycle_cap = false;
  Feedback feedback(cell, options.feedback);
  std::mt19937_64 slip_rng(options.slip_seed * 1000003u + seed);
  for (;;) {
    auto scene = p.Capture(request);
    if (!scene.ok()) return scene.status();
    const Frame& frame = static_cast<const CapturedFrame&>(**scene).frame();
    if (!frame.truth) return Status::Internal("clear: the synthetic frame has no ground truth");
    truth_parts = frame.truth->parts;
    last_pixels = PixelsOf(frame);
    if (frame.truth->X_BW) X_BW_true = *frame.truth->X_BW;
    if (!options.save_left_dir.empty()) last_frame = frame;
    if (report.cycles == 0) {
      report.parts_placed = static_cast<int>(truth_parts.size());
      if (max_cycles <= 0) max_cycles = 3 * report.parts_placed + 5;
    }
    feedback.OnCapture();  // before the plan is screened, as binpickd's RunDetection
    const int screened_before = report.screened;
    auto cycle = PlanCycle(p, **scene, *task, fallbacks, seed, feedback, report);
    if (!cycle.ok()) return cycle.status();
    ++report.cycles;
    last = cycle->primary;
    last_looks = std::move(cycle->looks);
    if (cycle->taken.grasps.empty()) {
      report.stopped_by_feedback = report.screened > screened_before;
      break;
    }
    if (report.cycles >= max_cycles) {
      cycle_cap = true;
      break;
    }

    const TaskSpec& used = *cycle->used;
    if (!options.withdraw_stale) {
      for (Grasp& g : cycle->taken.grasps) g.stale_after.clear();
    }
    GraspQueue queue;
    FailedPicks* screen = feedback.For(used);
    if (screen) queue.SetScreen([screen](std::deque<Grasp>& grasps) { return screen->Screen(grasps); });
    queue.Replace(cycle->taken);
    const Serving serving{p, *pile, used, &used != task, screen, slip_rng, truth_parts, options};
    ServeQueue(serving, queue, report);
  }
  // What is left: the pile as it is, with the last capture's visibility.
  std::vector<PartTruth> left = PileTruth(*pile);
  for (PartTruth& t : left) {
    if (const PartTruth* seen = FindInstance(truth_parts, t.instance_id)) t.visible_fraction = seen->visible_fraction;
  }
  report.parts_left = static_cast<int>(left.size());
  if (report.parts_left > 0 && last_frame) {
    if (Status s = SaveLeft(*last_frame, options.save_left_dir, seed, report); !s.ok()) return s;
  }
  for (const PartTruth& t : left) {
    const auto px = last_pixels.find(t.instance_id);
    auto [cause, detail] = LeftCause(t, last_looks, px == last_pixels.end() ? Pixels{} : px->second, X_BW_true,
                                     cell.bin.inner_size, cycle_cap);
    report.left.push_back(DescribeLeft(t) + "; " + cause + ", " + detail);
    ++report.left_by_cause[cause];
    report.left_causes.push_back(std::move(cause));
  }
  report.final_roi_points = last.roi_points;
  report.final_largest_region = last.largest_region_points;
  report.final_detections = last.detections;
  report.final_outcome = std::string(ToString(last.outcome)) + ": " + last.message;
  report.said_empty = IsBoxEmpty(task->empty_box, last);
  report.wrong_empty_answer = report.said_empty != (report.parts_left == 0);
  report.ended = report.parts_left == 0   ? "cleared"
                 : cycle_cap              ? "cycle_cap"
                 : report.stopped_by_feedback ? "feedback"
                                          : std::string(ToString(last.outcome));
  return report;
}

void ClearReport::Add(SceneClearReport scene) {
  parts_placed += scene.parts_placed;
  attempts += scene.attempts;
  picks += scene.picks;
  failed_picks += scene.failed_picks;
  stale_failures += scene.stale_failures;
  withdrawn += scene.withdrawn;
  slipped += scene.slipped;
  reported += scene.reported;
  screened += scene.screened;
  stopped_by_feedback += scene.stopped_by_feedback ? 1 : 0;
  for (const auto& [cause, n] : scene.failure_causes) failure_causes[cause] += n;
  for (const auto& [cause, n] : scene.left_by_cause) left_by_cause[cause] += n;
  ++ended[scene.ended];
  for (const auto& [name, t] : scene.by_grasp) by_grasp[name].Add(t);
  fallback_picks += scene.fallback_picks;
  cycles += scene.cycles;
  truth_collisions += scene.truth_collisions;
  parts_left += scene.parts_left;
  wrong_empty_answers += scene.wrong_empty_answer ? 1 : 0;
  early_heads += scene.early_heads;
  early_head_mismatches += scene.early_head_mismatches;
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
