// binpick eval: renders N synthetic scenes (seeds S, S+1, ...) or reads
// frames with ground truth from a directory, runs the perception pipeline,
// plans the task's grasps on its detections (PlanGrasps, as the planner does,
// without its thorough retry) and scores both strictly (pipeline/evaluation.h,
// grasp/grasp_judge.h). Progress on stderr, a table on stdout, the same
// figures with every detection's and grasp's pose and verdict in JSON with
// --json.
#include <algorithm>
#include <array>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <limits>
#include <map>
#include <set>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>
#include <spdlog/spdlog.h>
#include <tbb/task_arena.h>

#include "apps/binpick/command.h"
#include "core/cell.h"
#include "core/mesh.h"
#include "grasp/grasp_judge.h"
#include "grasp/grasp_planning.h"
#include "pipeline/bin_detection.h"
#include "pipeline/capture_source.h"
#include "pipeline/evaluation.h"
#include "pipeline/file_source.h"
#include "pipeline/fill_level.h"
#include "pipeline/frame_io.h"
#include "pipeline/perception.h"
#include "pipeline/pose_estimator.h"
#include "pipeline/pose_json.h"
#include "pipeline/synthetic_source.h"

namespace bp::cli {
namespace {

// Debug diagnostics only: each class's pose estimator with `options`, built
// on first use (hundreds of ms per part).
struct DiagnosticEstimators {
  PoseEstimatorOptions options;
  std::map<int, std::unique_ptr<PoseEstimator>> built;
};
// Null if the class's mesh does not load.
const PoseEstimator* DiagnosticEstimator(const Cell& cell, int class_id, DiagnosticEstimators& diagnostics) {
  auto& built = diagnostics.built;
  auto it = built.find(class_id);
  if (it == built.end()) {
    std::unique_ptr<PoseEstimator> est;
    for (const PartSpec& part : cell.parts) {
      if (part.class_id != class_id) continue;
      Result<TriangleMesh> mesh = LoadMesh(part.mesh);
      if (!mesh.ok()) break;
      auto e = PoseEstimator::Build(*mesh, part.symmetry, diagnostics.options);
      if (e.ok()) est = std::move(e).value();
    }
    it = built.emplace(class_id, std::move(est)).first;
  }
  return it->second.get();
}

struct EvalCliOptions {
  std::string cell_path;
  int scenes = 10;
  uint64_t seed = 1;
  std::string json_path;
  std::string detections_path;  // every frame's detections and counts, full precision
  std::string source;  // "" = synthetic, "files:DIR"
  int config_id = 0;
  int threads = 2;
  int num_parts = 0;  // 0 = the cell's
  double tol_mm = 5.0;
  double tol_deg = 5.0;
  int task_id = 0;    // the pick task whose grasps are judged; < 0: no grasps
  bool dropout_ends_at_parts = GraspPlanningOptions{}.dropout_ends_at_parts;
  bool sideways_turns = true;  // false: GraspPlanningOptions::suction_turn_azimuths_deg empty ("~v" alone)
  bool variety = false;
  BinCliOptions bin;
  double normal_angle_deg = -1.0;
  double max_jump = -1.0;
  double context = -1.0;
  double min_score = -1.0;
  int min_segment = -1;
  double min_segment_spacing = PerceptionOptions{}.min_segment_spacing;
  double convex = -2.0;
  bool regions = false;
  bool thorough = false;
  bool bin_only = false;  // --bin-only: the bin detection stage alone on each frame
  double second_look = PerceptionOptions{}.second_look_below;
  double fit_rms = PerceptionOptions{}.max_fit_rms_sigmas;
  double max_free_space = PerceptionOptions{}.max_free_space_fraction;
  double max_penetration = PerceptionOptions{}.max_support_penetration;
  double ambiguity_net_gain = PerceptionOptions{}.ambiguity_net_gain;
  double own_turn_gain = PerceptionOptions{}.own_turn_gain;
  double own_turn_min_foreign = PerceptionOptions{}.own_turn_min_foreign;
  double smooth = PerceptionOptions{}.smoothing_target_sigma;
  bool second_look_skip_tried = PerceptionOptions{}.second_look_skip_tried;
  int second_look_min_points = 0;  // --second-look-min-points; 0: the default
  bool turns_below_bar = PerceptionOptions{}.turns_below_bar;
  bool residual_regions = PerceptionOptions{}.residual_regions;
  bool residual_across_jumps = PerceptionOptions{}.residual_across_jumps;
  bool residual_own_normals = PerceptionOptions{}.residual_own_normals;
  bool enclosing_parts = PerceptionOptions{}.enclosing_parts;
  double ambiguous_min_visible = PerceptionOptions{}.ambiguous_min_visible;
  double one_plane_min_visible = PerceptionOptions{}.one_plane_min_visible;
  double near_centre_min_shared = PerceptionOptions{}.near_centre_min_shared;
  double planar_view_min_share = PerceptionOptions{}.planar_view_min_share;
  bool unmeasured_no_evidence = PerceptionOptions{}.unmeasured_is_no_evidence;
  bool causes = false;  // --causes: misses and false positives by cause
};

// FNV-1a over the values: a fingerprint of a long label vector.
uint64_t Fingerprint(const std::vector<int32_t>& values) {
  uint64_t h = 1469598103934665603ull;
  for (int32_t v : values) {
    h ^= static_cast<uint32_t>(v);
    h *= 1099511628211ull;
  }
  return h;
}

// One frame's detections (poses, scores, support) and the pipeline's counts,
// at full precision: two builds that detect the same give the same JSON.
nlohmann::json DetectionsJson(int frame, const PerceptionResult& r) {
  nlohmann::json detections = nlohmann::json::array();
  for (const Detection& d : r.detections) {
    std::vector<double> X(d.X_BO.matrix().data(), d.X_BO.matrix().data() + 16);
    detections.push_back({{"class_id", d.class_id},
                          {"X_BO", X},
                          {"score", d.score},
                          {"visible_fraction", d.visible_fraction},
                          {"rms_residual", d.rms_residual},
                          {"support", d.support}});
  }
  return {{"frame", frame},
          {"detections", detections},
          {"roi_points", r.roi_point_count},
          {"largest_region_points", r.largest_region_points},
          {"segment_of_point", Fingerprint(r.segment_of_point)},
          {"views", r.views},
          {"views_explained", r.views_explained},
          {"estimator_calls", r.estimator_calls},
          {"second_looks", r.second_looks},
          {"coarse_refined", r.coarse_refined},
          {"coarse_skipped", r.coarse_skipped},
          {"depth_noise_sigma", r.depth_noise_sigma},
          {"reason", r.reason}};
}

void Progress(int done, int total, double last_ms) {
  constexpr int kWidth = 30;
  const int filled = total > 0 ? done * kWidth / total : kWidth;
  std::fprintf(stderr, "\r[%s%s] %d/%d  last %.0f ms", std::string(static_cast<size_t>(filled), '#').c_str(),
               std::string(static_cast<size_t>(kWidth - filled), '.').c_str(), done, total, last_ms);
  if (done == total) std::fprintf(stderr, "\n");
  std::fflush(stderr);
}

// One frame as JSON: every true part, every detection and every grasp with
// its pose and verdict, so that another tool can re-score the run.
nlohmann::ordered_json FrameJson(const std::string& name, const Frame& frame, const PerceptionResult& result,
                                 const FrameEvaluation& fe, const EvalOptions& options) {
  nlohmann::ordered_json j;
  j["frame"] = name;
  j["source"] = frame.source;
  j["X_BC"] = PoseToJson(frame.X_BC);
  nlohmann::ordered_json truth = nlohmann::ordered_json::array();
  for (const PartTruth& p : frame.truth->parts) {
    truth.push_back({{"instance", p.instance_id},
                     {"class_id", p.class_id},
                     {"visible_fraction", p.visible_fraction},
                     {"target", p.visible_fraction >= options.min_visible_fraction},
                     {"X_BO", PoseToJson(p.X_BO)}});
  }
  j["truth"] = std::move(truth);
  nlohmann::ordered_json dets = nlohmann::ordered_json::array();
  for (const DetectionOutcome& o : fe.detections) {
    const Detection& d = result.detections[o.detection];
    dets.push_back({{"detection", o.detection},
                    {"class_id", d.class_id},
                    {"score", d.score},
                    {"verdict", ToString(o.verdict)},
                    {"truth_instance", o.truth_instance},
                    {"near_instance", o.near_instance},
                    {"translation_error_mm", 1000.0 * o.translation_error},
                    {"rotation_error_deg", o.rotation_error * 180.0 / M_PI},
                    {"alternatives", o.alternatives},
                    {"carried", o.carried},
                    {"visible_fraction", d.visible_fraction},
                    {"X_BO", PoseToJson(d.X_BO)}});
    // The poses the detection carries as ambiguous (Detection::alternatives_X_BO).
    nlohmann::ordered_json alternatives = nlohmann::ordered_json::array();
    for (const Pose& X_BO : d.alternatives_X_BO) alternatives.push_back(PoseToJson(X_BO));
    dets.back()["alternatives_X_BO"] = std::move(alternatives);
  }
  j["detections"] = std::move(dets);
  nlohmann::ordered_json grasps = nlohmann::ordered_json::array();
  for (const GraspOutcome& g : fe.grasps) {
    grasps.push_back({{"detection", g.detection},
                      {"class_id", g.class_id},
                      {"name", g.name},
                      {"on_part", g.on_part},
                      {"failure", g.failure},
                      {"truth_instance", g.truth_instance},
                      {"position_error_mm", 1000.0 * g.position_error},
                      {"approach_error_deg", g.approach_error * 180.0 / M_PI},
                      {"X_BT", PoseToJson(g.X_BT)}});
  }
  j["grasps"] = std::move(grasps);
  nlohmann::ordered_json stages = nlohmann::ordered_json::array();
  for (const StageTiming& st : fe.timings) stages.push_back({{"stage", st.stage}, {"ms", st.ms}});
  j["latency_ms"] = std::move(stages);
  return j;
}

nlohmann::ordered_json ToJson(const EvalReport& report, const SegmentationFigures& seg, const EvalCliOptions& opt,
                              nlohmann::ordered_json frames) {
  nlohmann::ordered_json j;
  j["frames"] = report.frames;
  j["seed"] = opt.seed;
  j["source"] = opt.source.empty() ? "synthetic" : opt.source;
  j["tolerance"] = {{"mm", opt.tol_mm}, {"deg", opt.tol_deg}, {"gross_relative_distance", 0.25}};
  for (const ClassFigures& c : report.classes) {
    j["classes"].push_back({{"name", c.name},
                            {"targets", c.targets},
                            {"found", c.found},
                            {"detections", c.detections},
                            {"true_positives", c.true_positives},
                            {"gross_errors", c.gross_errors},
                            {"gross_carried", c.gross_carried},
                            {"duplicates", c.duplicates},
                            {"false_positives", c.false_positives},
                            {"recall", c.recall},
                            {"precision", c.precision},
                            {"gross_fraction", c.gross_fraction},
                            {"translation_error_mm", {{"median", c.t_median_mm}, {"p95", c.t_p95_mm}}},
                            {"rotation_error_deg",
                             {{"median", c.r_median_deg},
                              {"p95", c.r_p95_deg},
                              {"near_p95", c.r_near_p95_deg},
                              {"near_max", c.r_near_max_deg}}},
                            {"adds_lt_10pct_diameter", c.adds_ok_fraction}});
  }
  const GraspFigures& g = report.grasps;
  j["grasps"] = {{"task", opt.task_id},
                 {"frames", g.frames},
                 {"frames_with_grasp", g.frames_with_grasp},
                 {"first_on_part", g.first_on_part},
                 {"first_on_part_fraction", g.first_fraction},
                 {"grasps", g.grasps},
                 {"on_part", g.on_part},
                 {"on_part_fraction", g.all_fraction},
                 {"failures", g.failures}};
  j["per_frame"] = std::move(frames);
  for (const StageFigures& s : report.stages) {
    j["latency_ms"].push_back({{"stage", s.stage}, {"median", s.median_ms}, {"p95", s.p95_ms}});
  }
  j["segmentation"] = {{"parts", seg.parts},
                       {"split", seg.split},
                       {"merged", seg.merged},
                       {"split_rate", seg.parts ? static_cast<double>(seg.split) / seg.parts : 0.0},
                       {"merged_rate", seg.parts ? static_cast<double>(seg.merged) / seg.parts : 0.0},
                       {"segments", seg.segments}};
  return j;
}

void PrintTable(const EvalReport& report, const SegmentationFigures& seg, const EvalCliOptions& opt) {
  std::printf("%d frames; strict: within %.1f mm and %.1f deg (modulo symmetry); recall over parts >= 50%% visible\n",
              report.frames, opt.tol_mm, opt.tol_deg);
  std::printf("%-16s %7s %6s %5s %6s %5s %4s %4s %8s %8s %8s %8s %8s\n", "class", "targets", "recall", "dets",
              "prec", "gross", "dup", "fp", "t_med_mm", "r_med_dg", "r_p95_dg", "nr_p95dg", "nr_max");
  for (const ClassFigures& c : report.classes) {
    std::printf("%-16s %7d %6.3f %5d %6.3f %5d %4d %4d %8.3f %8.3f %8.3f %8.2f %8.2f\n", c.name.c_str(), c.targets,
                c.recall, c.detections, c.precision, c.gross_errors, c.duplicates, c.false_positives, c.t_median_mm,
                c.r_median_deg, c.r_p95_deg, c.r_near_p95_deg, c.r_near_max_deg);
  }
  std::printf("(t/r over true positives; nr_*: rotation error over true positives and gross errors)\n");
  std::printf("gross errors carried with the true pose among their alternatives:");
  for (const ClassFigures& c : report.classes) std::printf(" %s %d / %d", c.name.c_str(), c.gross_carried, c.gross_errors);
  std::printf("\n");
  const GraspFigures& g = report.grasps;
  if (g.frames > 0) {
    std::string failures;
    for (const auto& [cause, n] : g.failures) failures += " " + cause + " " + std::to_string(n);
    std::printf("\ngrasps (task %d): first grasp on its part %d / %d frames (%.4f), all grasps %d / %d (%.4f)%s%s\n",
                opt.task_id, g.first_on_part, g.frames_with_grasp, g.first_fraction, g.on_part, g.grasps,
                g.all_fraction, failures.empty() ? "" : "; failed:", failures.c_str());
  }
  std::printf("\n%-10s %10s %10s\n", "stage", "median_ms", "p95_ms");
  for (const StageFigures& s : report.stages) std::printf("%-10s %10.2f %10.2f\n", s.stage.c_str(), s.median_ms, s.p95_ms);
  if (seg.parts > 0) {
    std::printf("\nsegmentation: %d target parts, split %.3f, merged %.3f, %d segments\n", seg.parts,
                static_cast<double>(seg.split) / seg.parts, static_cast<double>(seg.merged) / seg.parts, seg.segments);
  }
}

// --causes: the misses and false positives by cause (pipeline/evaluation.h,
// MissCause / FalseCause), per class and in all.
void PrintCauses(const CauseFigures& causes, const std::vector<EvalPartModel>& models) {
  const auto name_of = [&](int class_id) {
    for (const EvalPartModel& m : models) {
      if (m.class_id == class_id) return m.name;
    }
    return std::to_string(class_id);
  };
  const auto print = [&](const char* what, const auto& by_class, int n, auto cause_name) {
    std::array<int, 8> all{};
    int total = 0;
    for (const auto& [c, counts] : by_class) {
      for (int k = 0; k < n; ++k) {
        all[static_cast<size_t>(k)] += counts[static_cast<size_t>(k)];
        total += counts[static_cast<size_t>(k)];
      }
    }
    std::printf("\n%s by cause: %d\n", what, total);
    for (int k = 0; k < n; ++k) {
      std::string per_class;
      for (const auto& [c, counts] : by_class) {
        per_class += fmt::format("{}{} {}", per_class.empty() ? "" : ", ", name_of(c), counts[static_cast<size_t>(k)]);
      }
      std::printf("  %-20s %5d  (%s)\n", cause_name(k), all[static_cast<size_t>(k)], per_class.c_str());
    }
  };
  print("misses (targets no detection matched)", causes.misses, kMissCauses,
        [](int k) { return ToString(static_cast<MissCause>(k)); });
  print("false positives (on the part their support lies on)", causes.false_positives, kFalseCauses,
        [](int k) { return ToString(static_cast<FalseCause>(k)); });
}

nlohmann::ordered_json CausesJson(const CauseFigures& causes) {
  nlohmann::ordered_json j;
  for (const auto& [c, counts] : causes.misses) {
    for (int k = 0; k < kMissCauses; ++k) {
      j["misses"][std::to_string(c)][ToString(static_cast<MissCause>(k))] = counts[static_cast<size_t>(k)];
    }
  }
  for (const auto& [c, counts] : causes.false_positives) {
    for (int k = 0; k < kFalseCauses; ++k) {
      j["false_positives"][std::to_string(c)][ToString(static_cast<FalseCause>(k))] = counts[static_cast<size_t>(k)];
    }
  }
  j["missed"] = nlohmann::ordered_json::array();
  for (const MissRecord& m : causes.missed) {
    j["missed"].push_back(
        {{"frame", m.frame}, {"instance", m.instance_id}, {"class", m.class_id}, {"cause", ToString(m.cause)}});
  }
  return j;
}

// The perception settings: the cell's, with the tuning flags that were given.
PerceptionOptions PerceptionOptionsFrom(const EvalCliOptions& opt) {
  PerceptionOptions popt;
  popt.threads = opt.threads;
  if (opt.normal_angle_deg >= 0) popt.segment_normal_angle_deg = opt.normal_angle_deg;
  if (opt.max_jump > 0) popt.segment_max_jump = opt.max_jump;
  if (opt.context >= 0) popt.context_relative_radius = opt.context;
  if (opt.min_score >= 0) popt.min_detection_score = opt.min_score;
  if (opt.min_segment >= 0) popt.min_segment_points = opt.min_segment;
  popt.min_segment_spacing = opt.min_segment_spacing;
  if (opt.convex > -2.0) popt.segment_convex_tolerance = opt.convex;
  if (opt.regions) popt.match_regions = true;
  popt.second_look_below = opt.second_look;
  if (opt.second_look_min_points > 0) popt.second_look_min_points = opt.second_look_min_points;
  popt.max_fit_rms_sigmas = opt.fit_rms;
  popt.max_free_space_fraction = opt.max_free_space;
  popt.max_support_penetration = opt.max_penetration;
  popt.ambiguity_net_gain = opt.ambiguity_net_gain;
  popt.own_turn_gain = opt.own_turn_gain;
  popt.own_turn_min_foreign = opt.own_turn_min_foreign;
  popt.smoothing_target_sigma = opt.smooth;
  popt.second_look_skip_tried = opt.second_look_skip_tried;
  popt.residual_regions = opt.residual_regions;
  popt.residual_across_jumps = opt.residual_across_jumps;
  popt.residual_own_normals = opt.residual_own_normals;
  popt.enclosing_parts = opt.enclosing_parts;
  popt.ambiguous_min_visible = opt.ambiguous_min_visible;
  popt.one_plane_min_visible = opt.one_plane_min_visible;
  popt.near_centre_min_shared = opt.near_centre_min_shared;
  popt.planar_view_min_share = opt.planar_view_min_share;
  popt.unmeasured_is_no_evidence = opt.unmeasured_no_evidence;
  popt.second_look_search.unmeasured_is_no_evidence = opt.unmeasured_no_evidence;
  popt.turns_below_bar = opt.turns_below_bar;
  popt.second_look_search.turns_below_bar = opt.turns_below_bar;
  popt.thorough_search.turns_below_bar = opt.turns_below_bar;
  return popt;
}

// Frame i of the run: scene seed + i of the synthetic source, or files[i]
// (which must carry its ground truth).
Result<Frame> EvalFrame(const Cell& cell, const EvalCliOptions& opt, const std::vector<std::string>& files, int i) {
  if (files.empty()) {
    Cell scene_cell = cell;
    scene_cell.source.kind = SourceSpec::Kind::kSynthetic;
    scene_cell.source.seed = opt.seed + static_cast<uint64_t>(i);
    auto source = MakeSyntheticSource(scene_cell);
    if (!source.ok()) return source.status();
    CaptureRequest request;
    request.config_id = opt.config_id;
    return (*source)->Capture(request);
  }
  const std::string& file = files[static_cast<size_t>(i)];
  std::string assumption;
  Result<Frame> frame = LoadFrameForPerception(file, cell, cell.camera.X_BC, &assumption);
  if (!assumption.empty()) spdlog::warn("{}", assumption);
  if (frame.ok() && !frame->truth) return Status::NotFound(file + ": no ground-truth JSON beside it");
  return frame;
}

// --log-level debug, for a missed part: the ROI points on its pixels of the
// label image (before noise), how the segmentation cut them (segments, the
// largest one's share of them and of its own points), and how the truth
// verifies on them alone: tells a part the segmentation lost from one the
// pose search did not find and from one whose true pose scores below the bar.
void LogMissedPartOwnPoints(const Cell& cell, int i, const Frame& frame, const PerceptionResult& result,
                            const PartTruth& p,
                            DiagnosticEstimators& diagnostic_estimators) {
  const std::vector<int> owners = RoiPointOwners(frame, result);
  if (owners.empty()) return;
  std::vector<Eigen::Vector3f> own;
  for (size_t k = 0; k < owners.size(); ++k) {
    if (owners[k] == p.instance_id) own.push_back(result.roi_points_B[k]);
  }
  const PartCut cut = CutOfPart(p.instance_id, owners, result.segment_of_point);
  std::string scored = "not scored";
  const PoseEstimator* est = DiagnosticEstimator(cell, p.class_id, diagnostic_estimators);
  if (est != nullptr && !own.empty()) {
    SceneView view;
    view.points_B = own;
    view.X_BC = frame.X_BC;
    view.depth = &frame.depth;
    view.intrinsics = frame.intrinsics;
    const Result<PoseHypothesis> t = est->Score(view, p.X_BO);
    if (t.ok()) {
      scored = fmt::format("score {:.3f}, visible {}, occluded {}, supported {}, free space {}, unmeasured {}",
                           t->score, t->visible_points, t->occluded_points, t->supported_points,
                           t->free_space_points, t->unmeasured_points);
    }
    // The estimator (default options) on these points alone: what an ideal
    // segmentation would have given it.
    const Result<PoseEstimates> e = est->Estimate(view);
    if (e.ok() && !e->hypotheses.empty()) {
      const PoseHypothesis& b = e->hypotheses.front();
      const PartSpec* spec = cell.FindPart(p.class_id);
      const Symmetry sym = spec != nullptr ? spec->symmetry : Symmetry{};
      scored += fmt::format("; estimate alone: score {:.3f}, off {:.1f} mm {:.1f} deg", b.score,
                            1000.0 * (b.X_BO.translation() - p.X_BO.translation()).norm(),
                            SymmetricRotationError(b.X_BO, p.X_BO, sym) * 180.0 / M_PI);
    } else {
      scored += fmt::format("; estimate alone: none ({})", e.ok() ? e->no_result_reason : e.status().message());
    }
  }
  spdlog::debug("frame {} missed inst {}: own points {}, unsegmented {}, in {} segments, the largest holds {:.2f} "
                "of them and they {:.2f} of it; truth on own points: {}",
                i, p.instance_id, own.size(), cut.unsegmented, cut.segments, cut.largest_share, cut.largest_purity,
                scored);
}

// --log-level debug: each visible part no detection matched, and how a
// same-class detection near it is off and how the truth and it score on its
// support.
void LogMissedParts(const Cell& cell, int i, const Frame& frame, const PerceptionResult& result,
                    const FrameEvaluation& fe,
                    DiagnosticEstimators& diagnostic_estimators) {
  std::vector<int> matched;
  for (const DetectionOutcome& d : fe.detections) matched.push_back(d.truth_instance);
  for (const PartTruth& p : frame.truth->parts) {
    if (p.visible_fraction < EvalOptions{}.min_visible_fraction) continue;
    if (std::find(matched.begin(), matched.end(), p.instance_id) != matched.end()) continue;
    const Eigen::Vector3d z = p.X_BO.rotation().col(2);
    spdlog::debug("frame {} missed inst {} class {} vis {:.2f} at ({:.0f}, {:.0f}, {:.0f}) mm, z axis ({:.2f}, {:.2f}, "
                  "{:.2f})",
                  i, p.instance_id, p.class_id, p.visible_fraction, p.X_BO.translation().x() * 1000,
                  p.X_BO.translation().y() * 1000, p.X_BO.translation().z() * 1000, z.x(), z.y(), z.z());
    LogMissedPartOwnPoints(cell, i, frame, result, p, diagnostic_estimators);
    // A detection of the same class near it: how it is off, in the part's
    // frame, and how the truth and it verify against its support.
    for (const Detection& d : result.detections) {
      if (d.class_id != p.class_id || (d.X_BO.translation() - p.X_BO.translation()).norm() > 0.1) continue;
      const Pose X_TD = p.X_BO.inverse() * d.X_BO;
      const Eigen::AngleAxisd aa(X_TD.rotation());
      spdlog::debug("frame {} missed inst {}: detection score {:.2f} is off by {:.0f} deg about ({:.2f}, {:.2f}, "
                    "{:.2f}) and ({:.1f}, {:.1f}, {:.1f}) mm in the part frame",
                    i, p.instance_id, d.score, aa.angle() * 180 / M_PI, aa.axis().x(), aa.axis().y(),
                    aa.axis().z(), X_TD.translation().x() * 1000, X_TD.translation().y() * 1000,
                    X_TD.translation().z() * 1000);
      const PoseEstimator* est = DiagnosticEstimator(cell, p.class_id, diagnostic_estimators);
      if (est == nullptr) continue;
      std::vector<Eigen::Vector3f> support;
      for (int32_t k : d.support) support.push_back(result.roi_points_B[static_cast<size_t>(k)]);
      SceneView view;
      view.points_B = support;
      view.X_BC = frame.X_BC;
      if (frame.organized()) {
        view.depth = &frame.depth;
        view.intrinsics = frame.intrinsics;
      }
      for (const auto& [what, X] : {std::pair{"truth", p.X_BO}, std::pair{"detection", d.X_BO}}) {
        const Result<PoseHypothesis> h = est->Score(view, X);
        if (!h.ok()) continue;
        spdlog::debug("frame {} missed inst {}: {} on the detection's support: score {:.3f}, visible {}, "
                      "occluded {}, supported {}, free space {}",
                      i, p.instance_id, what, h->score, h->visible_points, h->occluded_points,
                      h->supported_points, h->free_space_points);
      }
    }
  }
}

// --log-level debug: each detection with its verdict, its nearest true part
// and the detection it shares most support with.
void LogDetections(int i, const Frame& frame, const PerceptionResult& result, const FrameEvaluation& fe) {
  std::vector<bool> true_detection(result.detections.size(), false);
  for (const DetectionOutcome& o : fe.detections) true_detection[o.detection] = o.truth_instance >= 0;
  for (size_t di = 0; di < result.detections.size(); ++di) {
    const Detection& d = result.detections[di];
    double best = 1e9;
    const PartTruth* near = nullptr;
    for (const PartTruth& p : frame.truth->parts) {
      const double dist = (p.X_BO.translation() - d.X_BO.translation()).norm();
      if (dist < best) {
        best = dist;
        near = &p;
      }
    }
    // The other detection sharing most of its support, and how much.
    std::string shares;
    if (!d.support.empty()) {
      std::set<int32_t> mine(d.support.begin(), d.support.end());
      size_t best_shared = 0, best_k = 0;
      for (size_t k = 0; k < result.detections.size(); ++k) {
        if (k == di) continue;
        size_t n = 0;
        for (int32_t s : result.detections[k].support) n += mine.count(s);
        if (n > best_shared) {
          best_shared = n;
          best_k = k;
        }
      }
      if (best_shared > 0) {
        shares = fmt::format(", shares {:.0f}% of its support with class {} score {:.2f}",
                             100.0 * static_cast<double>(best_shared) / static_cast<double>(d.support.size()),
                             result.detections[best_k].class_id, result.detections[best_k].score);
      }
    }
    if (near != nullptr) {
      spdlog::debug("frame {} det class {} score {:.2f} rms {:.3f} vis {:.2f} support {} at ({:.1f}, {:.1f}, {:.1f}) mm ({}) -> "
                    "nearest inst {} class {} vis {:.2f} at {:.1f} mm{}",
                    i, d.class_id, d.score, d.rms_residual * 1000, d.visible_fraction, d.support.size(), 1000 * d.X_BO.translation().x(),
                    1000 * d.X_BO.translation().y(), 1000 * d.X_BO.translation().z(),
                    true_detection[di] ? "true" : "false positive", near->instance_id,
                    near->class_id, near->visible_fraction, best * 1000, shares);
    }
  }
}

// --log-level debug, for a gross detection: its pose, each of its
// alternatives and the true pose verified on the part's own points (its
// pixels of the label image) against the whole depth image: whether the
// view holds evidence for the truth the search did not use (the truth
// explains more) or none (it explains as much or less), and the counts
// behind it (visible, occluded, unmeasured samples).
void LogGrossOwnPoints(const Cell& cell, int i, const Frame& frame, const PerceptionResult& result,
                       const FrameEvaluation& fe,
                       DiagnosticEstimators& diagnostic_estimators) {
  std::vector<int> owners;
  for (const DetectionOutcome& o : fe.detections) {
    if (o.verdict != DetectionVerdict::kGross) continue;
    if (owners.empty()) owners = RoiPointOwners(frame, result);
    const PartTruth* p = nullptr;
    for (const PartTruth& t : frame.truth->parts) {
      if (t.instance_id == o.near_instance) p = &t;
    }
    const PoseEstimator* est = p != nullptr ? DiagnosticEstimator(cell, p->class_id, diagnostic_estimators) : nullptr;
    if (est == nullptr) continue;
    std::vector<Eigen::Vector3f> own;
    for (size_t k = 0; k < owners.size(); ++k) {
      if (owners[k] == p->instance_id) own.push_back(result.roi_points_B[k]);
    }
    SceneView view;
    view.points_B = own;
    view.X_BC = frame.X_BC;
    view.depth = &frame.depth;
    view.intrinsics = frame.intrinsics;
    // Verified as given, and the best of it turned about the part's x axis
    // (a tee's run) by up to 4 deg either side, within the tolerance: the
    // truth is not fitted to the noisy points the detections are fitted to.
    const auto net = [&](const Pose& X) {
      const Result<PoseHypothesis> h = est->Score(view, X);
      if (!h.ok()) return std::string("-");
      int best = h->supported_points - h->free_space_points;
      for (int deg = -4; deg <= 4; ++deg) {
        Pose T = Pose::Identity();
        T.linear() = Eigen::AngleAxisd(deg * M_PI / 180.0, Eigen::Vector3d::UnitX()).toRotationMatrix();
        const Result<PoseHypothesis> t = est->Score(view, X * T);
        if (t.ok()) best = std::max(best, t->supported_points - t->free_space_points);
      }
      return fmt::format("{}-{} ({} visible, {} occluded, {} unmeasured; {} best turned)", h->supported_points,
                         h->free_space_points, h->visible_points, h->occluded_points, h->unmeasured_points, best);
    };
    const Detection& d = result.detections[o.detection];
    std::string alts;
    for (const Pose& X : d.alternatives_X_BO) alts += " " + net(X);
    spdlog::debug("frame {} gross det {} inst {} (off {:.1f} deg): own points {}, supported-free: truth {}, "
                  "detection {}, alternatives{}",
                  i, o.detection, p->instance_id, o.rotation_error * 180.0 / M_PI, own.size(), net(p->X_BO),
                  net(d.X_BO), alts);
  }
}

// --log-level debug: the frame's pipeline counts, its missed parts, its gross
// detections and its detections.
void LogFrameDiagnostics(const Cell& cell, int i, const Frame& frame, const PerceptionResult& result,
                         const FrameEvaluation& fe,
                         DiagnosticEstimators& diagnostic_estimators) {
  spdlog::debug("frame {}: {} views ({} explained), {} estimator calls, {} coarse poses refined, {} second "
                "looks ({} coarse poses skipped), depth noise {:.3f} mm at {:.3f} m",
                i, result.views, result.views_explained, result.estimator_calls, result.coarse_refined,
                result.second_looks, result.coarse_skipped,
                result.depth_noise_sigma * 1000, result.depth_noise_at);
  LogMissedParts(cell, i, frame, result, fe, diagnostic_estimators);
  LogGrossOwnPoints(cell, i, frame, result, fe, diagnostic_estimators);
  LogDetections(i, frame, result, fe);
}

// Bin detection against the true bin pose (frames whose truth has one).
struct BinFigures {
  int frames = 0;                     // frames where the stage ran and the truth knows the bin
  std::vector<double> mm, deg;        // pose error of each found bin
  std::vector<std::string> failures;  // "seed S: reason" of each bin not found
};

// The figure of one frame (JSON) and its share of `figures`.
nlohmann::ordered_json NoteBin(const std::optional<BinDetection>& detection, const Frame& frame,
                               const std::string& name, BinFigures& figures) {
  nlohmann::ordered_json j;
  if (!detection || !frame.truth || !frame.truth->X_BW) return j;
  const BinDetection& bin = *detection;
  ++figures.frames;
  j["found"] = bin.found;
  j["ms"] = bin.ms;
  if (!bin.found) {
    j["reason"] = bin.reason;
    figures.failures.push_back(name + ": " + bin.reason);
    return j;
  }
  const Pose d = frame.truth->X_BW->inverse() * bin.X_BW;
  const double mm = 1e3 * d.translation().norm(), deg = Eigen::AngleAxisd(d.linear()).angle() * 180.0 / M_PI;
  figures.mm.push_back(mm);
  figures.deg.push_back(deg);
  j["error_mm"] = mm;
  j["error_deg"] = deg;
  j["offset_mm"] = 1e3 * bin.offset;
  j["offset_deg"] = bin.offset_deg;
  j["rim_points"] = bin.rim_points;
  return j;
}

// The q-quantile (nearest rank) of `v`; 0 when empty.
double Quantile(std::vector<double> v, double q) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<size_t>(q * static_cast<double>(v.size() - 1) + 0.5))];
}

nlohmann::ordered_json BinSummary(const BinFigures& f) {
  nlohmann::ordered_json j;
  j["frames"] = f.frames;
  j["found"] = static_cast<int>(f.mm.size());
  j["error_mm"] = {{"median", Quantile(f.mm, 0.5)}, {"p95", Quantile(f.mm, 0.95)}, {"max", Quantile(f.mm, 1.0)}};
  j["error_deg"] = {{"median", Quantile(f.deg, 0.5)}, {"p95", Quantile(f.deg, 0.95)}, {"max", Quantile(f.deg, 1.0)}};
  j["failures"] = f.failures;
  return j;
}

void PrintBin(const BinFigures& f) {
  if (f.frames == 0) return;
  std::printf("bin detection: %d frames, %zu found; pose error vs truth median %.2f mm / %.3f deg, p95 %.2f mm / "
              "%.3f deg, max %.2f mm / %.3f deg\n",
              f.frames, f.mm.size(), Quantile(f.mm, 0.5), Quantile(f.deg, 0.5), Quantile(f.mm, 0.95),
              Quantile(f.deg, 0.95), Quantile(f.mm, 1.0), Quantile(f.deg, 1.0));
  for (const std::string& failure : f.failures) std::printf("  bin not found: %s\n", failure.c_str());
}

// --bin-only: the bin detection stage (pipeline/bin_detection.h) alone on
// each frame, as perception runs it first (on the raw frame), scored against
// the truth's bin pose; nothing else runs, so piles of hundreds of parts
// (--parts, --fill) are measured in seconds per frame.
int RunBinOnly(const Cell& cell, const EvalCliOptions& opt, const std::vector<std::string>& files) {
  BinFigures figures;
  nlohmann::ordered_json frames_json = nlohmann::ordered_json::array();
  std::vector<double> ms, means, tops;
  const int total = files.empty() ? opt.scenes : static_cast<int>(files.size());
  Progress(0, total, 0.0);
  for (int i = 0; i < total; ++i) {
    Result<Frame> frame = EvalFrame(cell, opt, files, i);
    if (!frame.ok()) return Fail("eval", frame.status());
    const std::string name = files.empty() ? "seed " + std::to_string(opt.seed + static_cast<uint64_t>(i))
                                           : files[static_cast<size_t>(i)];
    const std::optional<BinDetection> bin = DetectBin(*frame, cell.bin);
    ms.push_back(bin->ms);
    nlohmann::ordered_json j = NoteBin(bin, *frame, name, figures);
    if (!j.is_null()) {
      j["frame"] = name;
      // How full the bin is: the fill level (pipeline/fill_level.h) of the
      // frame's points over the true bin's ROI floor.
      std::vector<Eigen::Vector3f> points_B = frame->PointsInCamera();
      const Eigen::Affine3f X_BC = frame->X_BC.cast<float>();
      for (Eigen::Vector3f& p : points_B) p = X_BC * p;
      const Eigen::Vector2d half =
          cell.bin.inner_size.head<2>() / 2 - Eigen::Vector2d::Constant(cell.roi.wall_margin);
      const FillLevel fill = MeasureFillLevel(points_B, *frame->truth->X_BW, half);
      j["parts"] = frame->truth->parts.size();
      j["fill_mean_mm"] = 1e3 * fill.mean_height;
      j["fill_max_mm"] = 1e3 * fill.max_height;
      j["occupied"] = fill.occupied_fraction;
      means.push_back(fill.mean_height / cell.bin.inner_size.z());
      tops.push_back(fill.max_height / cell.bin.inner_size.z());
      frames_json.push_back(std::move(j));
    }
    Progress(i + 1, total, bin->ms);
  }
  PrintBin(figures);
  std::printf("bin stage: median %.2f ms, p95 %.2f ms; fill level of the bin's inner height: mean height median "
              "%.0f%%, max height median %.0f%% (least %.0f%%, most %.0f%%)\n",
              Quantile(ms, 0.5), Quantile(ms, 0.95), 100 * Quantile(means, 0.5), 100 * Quantile(tops, 0.5),
              100 * Quantile(tops, 0.0), 100 * Quantile(tops, 1.0));
  if (!opt.json_path.empty()) {
    std::ofstream out(opt.json_path);
    nlohmann::ordered_json j;
    j["bin_detection"] = BinSummary(figures);
    j["frames"] = std::move(frames_json);
    out << j.dump(2) << "\n";
    if (!out) return Fail("eval", Status::Internal("cannot write '" + opt.json_path + "'"));
  }
  return kExitOk;
}

int Run(const EvalCliOptions& opt) {
  const std::string cmd = "eval";
  Result<Cell> cell = LoadCellOrDefault(opt.cell_path);
  if (!cell.ok()) return Fail(cmd, cell.status());
  if (opt.num_parts > 0) cell->source.num_parts = opt.num_parts;
  if (opt.variety && !cell->source.variety) cell->source.variety = VarietySpec{};
  ApplyBinOptions(opt.bin, *cell);
  cell->source.simulate_picks = false;

  std::vector<std::string> files;
  if (!opt.source.empty()) {
    if (opt.source.rfind("files:", 0) != 0) {
      return Fail(cmd, Status::InvalidArgument("--source must be files:DIR, got '" + opt.source + "'"));
    }
    Result<std::vector<std::string>> listed = ListFrameFiles(opt.source.substr(6));
    if (!listed.ok()) return Fail(cmd, listed.status());
    files = std::move(*listed);
  } else if (opt.scenes < 1) {
    return Fail(cmd, Status::InvalidArgument("--scenes must be >= 1"));
  }

  if (opt.bin_only) return RunBinOnly(*cell, opt, files);
  auto perception = Perception::Build(*cell, PerceptionOptionsFrom(opt));
  if (!perception.ok()) return Fail(cmd, perception.status());
  auto models = LoadEvalModels(*cell);
  if (!models.ok()) return Fail(cmd, models.status());
  if (!(opt.tol_mm > 0) || !(opt.tol_deg > 0)) {
    return Fail(cmd, Status::InvalidArgument("--tol-mm and --tol-deg must be > 0"));
  }
  EvalOptions eval_options;
  eval_options.translation_tolerance = opt.tol_mm / 1000.0;
  eval_options.rotation_tolerance = opt.tol_deg * M_PI / 180.0;
  // The grasp stage: the task's grasps on each frame's detections.
  const TaskSpec* task = nullptr;
  std::shared_ptr<const GraspPlanningModel> grasp_model;
  if (opt.task_id >= 0) {
    task = cell->FindTask(opt.task_id);
    if (task == nullptr || task->kind != TaskSpec::Kind::kPick) {
      return Fail(cmd, Status::InvalidArgument("--task " + std::to_string(opt.task_id) + " is not a pick task of the cell"));
    }
    GraspPlanningOptions planning;
    planning.dropout_ends_at_parts = opt.dropout_ends_at_parts;
    if (!opt.sideways_turns) planning.suction_turn_azimuths_deg.clear();
    auto built = GraspPlanningModel::Build(*cell, planning);
    if (!built.ok()) return Fail(cmd, built.status());
    grasp_model = std::move(*built);
  }
  nlohmann::ordered_json frames_json = nlohmann::ordered_json::array();

  tbb::task_arena arena(opt.threads);
  DiagnosticEstimators diagnostic_estimators{ReferenceEstimatorOptions((*perception)->options()), {}};  // debug, --causes
  std::vector<FrameEvaluation> evaluations;
  SegmentationFigures seg_total;
  CauseFigures causes;
  BinFigures bin_figures;
  int withheld_ambiguous = 0;  // PerceptionResult::withheld_ambiguous over the frames
  int withheld_one_plane = 0;  // PerceptionResult::withheld_one_plane over the frames
  nlohmann::json frame_detections = nlohmann::json::array();
  const int total = files.empty() ? opt.scenes : static_cast<int>(files.size());
  Progress(0, total, 0.0);
  for (int i = 0; i < total; ++i) {
    Result<Frame> frame = EvalFrame(*cell, opt, files, i);
    if (!frame.ok()) return Fail(cmd, frame.status());
    Result<PerceptionResult> result = Status::Internal("not run");
    const PerceptionEffort effort = opt.thorough ? PerceptionEffort::kThorough : PerceptionEffort::kNormal;
    arena.execute([&] { result = (*perception)->Run(*frame, {}, effort); });
    if (!result.ok()) return Fail(cmd, result.status());
    if (result->detections.empty()) spdlog::info("frame {}: {}", i, result->reason);
    withheld_ambiguous += result->withheld_ambiguous;
    withheld_one_plane += result->withheld_one_plane;
    const std::string frame_name = files.empty() ? "seed " + std::to_string(opt.seed + static_cast<uint64_t>(i))
                                                 : files[static_cast<size_t>(i)];
    nlohmann::ordered_json bin_json = NoteBin(result->bin, *frame, frame_name, bin_figures);
    evaluations.push_back(EvaluateFrame(*result, *frame->truth, *models, eval_options));
    if (task != nullptr) {
      FrameEvaluation& fe = evaluations.back();
      const auto t0 = std::chrono::steady_clock::now();
      GraspPlan plan;
      arena.execute([&] { plan = PlanGrasps(*grasp_model, *task, *result, {}, &*frame); });
      fe.timings.push_back({"grasps", std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count()});
      fe.grasps_planned = true;
      for (const Grasp& g : plan.queue) {
        GraspOutcome o = JudgeGrasp(*grasp_model, task->gripper, g, frame->truth->parts);
        o.detection = g.instance_id;
        fe.grasps.push_back(std::move(o));
      }
    }
    if (!opt.json_path.empty()) {
      const std::string name = files.empty() ? "seed " + std::to_string(opt.seed + static_cast<uint64_t>(i))
                                             : files[static_cast<size_t>(i)];
      frames_json.push_back(FrameJson(name, *frame, *result, evaluations.back(), eval_options));
      if (!bin_json.is_null()) frames_json.back()["bin"] = std::move(bin_json);
      frames_json.back()["withheld_ambiguous"] = result->withheld_ambiguous;
      frames_json.back()["withheld_one_plane"] = result->withheld_one_plane;
    }
    if (!opt.detections_path.empty()) frame_detections.push_back(DetectionsJson(i, *result));
    if (spdlog::should_log(spdlog::level::debug)) {
      LogFrameDiagnostics(*cell, i, *frame, *result, evaluations.back(), diagnostic_estimators);
    }
    if (opt.causes) {
      // The true pose verified on the part's own points by the pipeline's
      // rule (ReferenceEstimatorOptions, as --log-level debug scores it).
      const auto truth_score = [&](const PartTruth& p, const std::vector<Eigen::Vector3f>& own) {
        const PoseEstimator* est = DiagnosticEstimator(*cell, p.class_id, diagnostic_estimators);
        if (est == nullptr) return std::numeric_limits<double>::quiet_NaN();
        SceneView view;
        view.points_B = own;
        view.X_BC = frame->X_BC;
        view.depth = &frame->depth;
        view.intrinsics = frame->intrinsics;
        const Result<PoseHypothesis> t = est->Score(view, p.X_BO);
        return t.ok() ? t->score : std::numeric_limits<double>::quiet_NaN();
      };
      AddFrameCauses(*frame, *result, evaluations.back(), truth_score, causes, eval_options, i);
    }
    const SegmentationFigures seg = EvaluateSegmentation(*frame, *result, *cell);
    seg_total.parts += seg.parts;
    seg_total.split += seg.split;
    seg_total.merged += seg.merged;
    seg_total.segments += seg.segments;
    Progress(i + 1, total, result->TotalMs());
  }
  const EvalReport report = Summarize(evaluations, *models);
  PrintTable(report, seg_total, opt);
  std::printf("withheld as ambiguous and mostly hidden (PerceptionOptions::ambiguous_min_visible): %d\n",
              withheld_ambiguous);
  std::printf("withheld as seen on one plane and mostly hidden (PerceptionOptions::one_plane_min_visible): %d\n",
              withheld_one_plane);
  if (opt.causes) PrintCauses(causes, *models);
  PrintBin(bin_figures);
  if (!opt.json_path.empty()) {
    std::ofstream out(opt.json_path);
    nlohmann::ordered_json j = ToJson(report, seg_total, opt, std::move(frames_json));
    if (bin_figures.frames > 0) j["bin_detection"] = BinSummary(bin_figures);
    if (opt.causes) j["causes"] = CausesJson(causes);
    out << j.dump(2) << "\n";
    if (!out) return Fail(cmd, Status::Internal("cannot write '" + opt.json_path + "'"));
  }
  if (!opt.detections_path.empty()) {
    std::ofstream out(opt.detections_path);
    out << frame_detections.dump(1) << "\n";
    if (!out) return Fail(cmd, Status::Internal("cannot write '" + opt.detections_path + "'"));
  }
  return kExitOk;
}

// The grasp stage's options: the task and the planner's switches.
void AddGraspStageOptions(CLI::App& sub, EvalCliOptions& opt) {
  sub.add_option("--task", opt.task_id,
                 "pick task whose grasps are planned on the detections and judged against the truth (-1: none)")
      ->capture_default_str();
  sub.add_option("--dropout-ends-at-parts", opt.dropout_ends_at_parts,
                 "grasp stage: true, an unseen dropout ray ends at a detected part's surface; "
                 "false, at the farthest depth measured near it")
      ->capture_default_str();
  sub.add_option("--sideways-turns", opt.sideways_turns,
                 "grasp stage: true, a suction candidate too steep for its ~v turn to reach vertical also gets "
                 "the turns of suction_turn_azimuths_deg; false, ~v alone")
      ->capture_default_str();
}

}  // namespace

Command EvalCommand() {
  return Command{"eval", "Score the perception pipeline against ground truth (synthetic scenes or files)",
                 [](CLI::App& sub) -> std::function<int()> {
                   auto opt = std::make_shared<EvalCliOptions>();
                   sub.add_option("--cell", opt->cell_path, "cell file (default: the embedded default cell)");
                   sub.add_option("--scenes", opt->scenes, "synthetic scenes to render")->capture_default_str();
                   sub.add_option("--seed", opt->seed, "seed of the first scene (then seed+1, ...)")
                       ->capture_default_str();
                   sub.add_option("--json", opt->json_path, "also write the figures as JSON to this file");
                   sub.add_option("--detections", opt->detections_path,
                                  "write every frame's detections (poses, scores, support) and the pipeline's "
                                  "counts to this JSON file at full precision (regression checks: diff two runs)");
                   sub.add_option("--source", opt->source, "files:DIR to score frames with truth JSON beside them");
                   sub.add_option("--config", opt->config_id, "camera config id (0 = cell default)");
                   sub.add_option("--threads", opt->threads, "oneTBB arena size")->capture_default_str();
                   sub.add_option("--parts", opt->num_parts, "parts per synthetic scene (0 = the cell's)");
                   sub.add_option("--tol-mm", opt->tol_mm,
                                  "strict match: largest translation error, mm (modulo symmetry)")
                       ->capture_default_str();
                   sub.add_option("--tol-deg", opt->tol_deg,
                                  "strict match: largest rotation error, degrees (modulo symmetry)")
                       ->capture_default_str();
                   sub.add_flag("--variety", opt->variety,
                                "draw each scene's camera pose, intrinsics, noise and drop style from its seed "
                                "(the cell's source.variety, else the defaults; docs/synthetic.md)");
                   AddBinOptions(sub, &opt->bin);
                   AddGraspStageOptions(sub, *opt);
                   sub.add_option("--normal-angle", opt->normal_angle_deg,
                                  "segmentation normal-angle threshold, degrees (tuning)");
                   sub.add_option("--max-jump", opt->max_jump, "segmentation neighbour distance, metres (tuning)");
                   sub.add_option("--context", opt->context,
                                  "context radius around segments, fraction of the part diameter (tuning)");
                   sub.add_option("--min-score", opt->min_score, "detection score threshold (tuning)");
                   sub.add_option("--min-segment", opt->min_segment, "smallest segment matched, grid points (tuning)");
                   sub.add_option("--min-segment-spacing", opt->min_segment_spacing,
                                  "grid spacing at which --min-segment is counted, metres; a coarser frame's grid "
                                  "needs as many points as cover the same area (-1: the cell camera's view spacing, "
                                  "0: the same count on every frame; PerceptionOptions::min_segment_spacing; tuning)")
                       ->capture_default_str();
                   sub.add_option("--convex", opt->convex, "convex-crease tolerance, < 0 off (tuning)");
                   sub.add_flag("--match-regions", opt->regions, "also match multi-segment regions (tuning)");
                   sub.add_option("--second-look", opt->second_look,
                                  "match views whose best score is below this again with a wider coarse search "
                                  "(PerceptionOptions::second_look_below; 0 = off, tuning)")
                       ->check(CLI::Range(0.0, 2.0));
                   sub.add_option("--turns-below-bar", opt->turns_below_bar,
                                  "1: a pose below the bar of a part nearly round about an axis is turned about it "
                                  "before it is rejected (PerceptionOptions::turns_below_bar; tuning)");
                   sub.add_option("--second-look-min-points", opt->second_look_min_points,
                                  "smallest view (grid points) the second look matches again "
                                  "(PerceptionOptions::second_look_min_points; 0 = the default, tuning)")
                       ->check(CLI::Range(0, 100000));
                   sub.add_option("--fit-rms", opt->fit_rms,
                                  "largest fit residual, in sigma_z of the depth noise "
                                  "(PerceptionOptions::max_fit_rms_sigmas; 0 = off, tuning)")
                       ->check(CLI::Range(0.0, 100.0));
                   sub.add_option("--max-penetration", opt->max_penetration,
                                  "deepest a detection may sink below the bin floor, metres "
                                  "(PerceptionOptions::max_support_penetration; tuning)")
                       ->check(CLI::Range(0.0, 0.05))
                       ->capture_default_str();
                   sub.add_option("--ambiguity-gain", opt->ambiguity_net_gain,
                                  "an alternative pose explaining this fraction more of the view replaces the "
                                  "detection's (PerceptionOptions::ambiguity_net_gain; 0 = off, tuning)")
                       ->check(CLI::Range(0.0, 10.0))
                       ->capture_default_str();
                   sub.add_option("--own-turn-gain", opt->own_turn_gain,
                                  "a turn explaining this fraction more of a part's own points (its neighbours' "
                                  "left out) replaces its pose (PerceptionOptions::own_turn_gain; < 0 = off, tuning)")
                       ->check(CLI::Range(-1.0, 10.0))
                       ->capture_default_str();
                   sub.add_option("--own-turn-min-foreign", opt->own_turn_min_foreign,
                                  "own_turns judges again only parts whose neighbours hold at least this fraction of "
                                  "the points within their reach, or ambiguous ones "
                                  "(PerceptionOptions::own_turn_min_foreign; tuning)")
                       ->check(CLI::Range(0.0, 1.0))
                       ->capture_default_str();
                   sub.add_option("--max-free-space", opt->max_free_space,
                                  "largest fraction of a detection's seen surface in free space "
                                  "(PerceptionOptions::max_free_space_fraction; 1 = off, tuning)")
                       ->check(CLI::Range(0.0, 1.0));
                   sub.add_option("--smooth", opt->smooth,
                                  "smooth frames noisier than this at their median depth, metres "
                                  "(PerceptionOptions::smoothing_target_sigma; 0 = never, tuning)")
                       ->check(CLI::Range(0.0, 0.01));
                   sub.add_option("--second-look-skip", opt->second_look_skip_tried,
                                  "1: the second look does not refine again the coarse poses the waves refined "
                                  "(PerceptionOptions::second_look_skip_tried; tuning)")
                       ->capture_default_str();
                   sub.add_option("--residual-regions", opt->residual_regions,
                                  "1: match the samples no detection explains, grouped by grid connectivity, "
                                  "after the residual pass (PerceptionOptions::residual_regions; tuning)")
                       ->capture_default_str();
                   sub.add_option("--residual-across-jumps", opt->residual_across_jumps,
                                  "1: also match the residual regions' groups whose grid cells touch across a "
                                  "depth jump, joined (PerceptionOptions::residual_across_jumps; tuning)")
                       ->capture_default_str();
                   sub.add_option("--residual-own-normals", opt->residual_own_normals,
                                  "1: match the residual regions' views nothing was found in once more with the "
                                  "estimator's own normals (PerceptionOptions::residual_own_normals; tuning)")
                       ->capture_default_str();
                   sub.add_flag("--causes", opt->causes,
                                "also count the misses and false positives by cause (segmentation cut, the true "
                                "pose's score on the part's own points, what a wrong detection sits on; "
                                "organized synthetic frames)");
                   sub.add_option("--unmeasured-no-evidence", opt->unmeasured_no_evidence,
                                  "1: a grazing face over pixels without depth is no evidence against a pose in "
                                  "the normal and second-look searches; 0: it counts against (before issue 37's "
                                  "eighth session; PerceptionOptions::unmeasured_is_no_evidence; tuning)")
                       ->capture_default_str();
                   sub.add_option("--ambiguous-min-visible", opt->ambiguous_min_visible,
                                  "withhold a detection whose pose is ambiguous when less than this fraction of its "
                                  "camera-facing surface is seen (PerceptionOptions::ambiguous_min_visible; 0 = "
                                  "off, tuning)")
                       ->check(CLI::Range(0.0, 1.0))
                       ->capture_default_str();
                   sub.add_option("--one-plane-min-visible", opt->one_plane_min_visible,
                                  "withhold a detection whose support lies on one plane when less than this "
                                  "fraction of its camera-facing surface is seen "
                                  "(PerceptionOptions::one_plane_min_visible; 0 = off, tuning)")
                       ->check(CLI::Range(0.0, 1.0))
                       ->capture_default_str();
                   sub.add_option("--planar-view-min-share", opt->planar_view_min_share,
                                  "a view this share of whose points lies within 1.5 mm of one plane gets face "
                                  "seeds (PerceptionOptions::planar_view_min_share; 0 = the 1 mm RMS test alone, "
                                  "tuning)")
                       ->check(CLI::Range(0.0, 1.0))
                       ->capture_default_str();
                   sub.add_option("--near-centre-min-shared", opt->near_centre_min_shared,
                                  "acceptance: a candidate whose surface centre is near an accepted detection's "
                                  "conflicts with it only when this fraction of its support lies on that "
                                  "detection's surface "
                                  "(PerceptionOptions::near_centre_min_shared; 0 = centre closeness alone, tuning)")
                       ->check(CLI::Range(0.0, 1.0))
                       ->capture_default_str();
                   sub.add_option("--enclosing", opt->enclosing_parts,
                                  "1: a larger class fitted over a detection it may enclose replaces it when it "
                                  "explains its points and more (PerceptionOptions::enclosing_parts; tuning)")
                       ->capture_default_str();
                   sub.add_flag("--bin-only", opt->bin_only,
                                "run the bin detection stage alone on each frame and score it against the "
                                "truth's bin (fast on large piles; no parts are detected)");
                   sub.add_flag("--thorough", opt->thorough,
                                "run the thorough search (the planner's retry) on every frame (tuning)");
                   return [opt] { return Run(*opt); };
                 }};
}

}  // namespace bp::cli
