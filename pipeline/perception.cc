#include "pipeline/perception.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <map>
#include <utility>

#include <spdlog/spdlog.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include "pipeline/internal/acceptance.h"
#include "pipeline/internal/class_model.h"
#include "pipeline/internal/depth_smoothing.h"
#include "pipeline/internal/enclosing_parts.h"
#include "pipeline/internal/fit_limit.h"
#include "pipeline/internal/model_sampling.h"
#include "pipeline/internal/own_point_turns.h"
#include "pipeline/internal/part_settings.h"
#include "pipeline/internal/roi_cloud.h"
#include "pipeline/internal/segmentation.h"
#include "pipeline/internal/view_matching.h"
#include "pipeline/internal/view_passes.h"

namespace bp {

double PerceptionResult::TotalMs() const {
  double total = 0.0;
  for (const StageTiming& t : timings) total += t.ms;
  return total;
}

double SteadyClockMs() {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now().time_since_epoch()).count();
}

PoseEstimatorOptions ReferenceEstimatorOptions(const PerceptionOptions& options) {
  PoseEstimatorOptions reference;
  reference.max_support_penetration = options.max_support_penetration;
  reference.ambiguity_net_gain = options.ambiguity_net_gain;
  reference.arm_swaps = options.arm_swaps;
  reference.planar_view_min_share = options.planar_view_min_share;
  reference.unmeasured_is_no_evidence = options.unmeasured_is_no_evidence;
  reference.turns_below_bar = options.turns_below_bar;
  return reference;
}

namespace {

using internal::ClassModel;
using Clock = std::chrono::steady_clock;

// Unorganized clouds are grouped by voxel connectivity at this voxel size
// (fine enough that 5000 points scattered through the bin stay isolated).
constexpr float kUnorganizedVoxel = 0.003f;

// Surface samples of region.clear_mesh_R at a third of the margin (random,
// seeded: the same samples every run) in B; drops the ROI points within the
// margin of them (PerceptionRegion::clear_mesh_R).
void ClearKnownGeometry(const PerceptionRegion& region, internal::RoiCloud* roi) {
  constexpr uint64_t kSampleSeed = 0xC1EA5u;
  internal::OrientedPoints samples =
      internal::SampleSurface(*region.clear_mesh_R, region.clear_margin / 3, kSampleSeed);
  const Eigen::Isometry3f X_BR = region.X_BR.cast<float>();
  for (Eigen::Vector3f& p : samples.points) p = X_BR * p;
  const int64_t dropped = internal::DropPointsNear(samples.points, static_cast<float>(region.clear_margin), roi);
  spdlog::debug("perception: {} ROI points within {:.1f} mm of the region's known geometry dropped", dropped,
                1000 * region.clear_margin);
}

// Appends each stage's wall time to PerceptionResult::timings.
class StageClock {
 public:
  explicit StageClock(std::vector<StageTiming>* timings) : timings_(timings), t_(Clock::now()) {}
  // Ends the stage `name` (begun at the previous Lap or at construction).
  void Lap(const char* name) {
    const Clock::time_point t = Clock::now();
    timings_->push_back({name, std::chrono::duration<double, std::milli>(t - t_).count()});
    t_ = t;
  }
  void Restart() { t_ = Clock::now(); }

 private:
  std::vector<StageTiming>* timings_;
  Clock::time_point t_;
};

internal::SegmentationOptions SegmentationOptionsOf(const PerceptionOptions& o) {
  internal::SegmentationOptions s;
  s.grid_spacing = o.grid_spacing;
  s.max_jump = o.segment_max_jump;
  s.normal_angle_deg = o.segment_normal_angle_deg;
  s.convex_tolerance = o.segment_convex_tolerance;
  s.min_segment_points = o.min_segment_points;
  s.match_regions = o.match_regions;
  s.match_fragmented_regions = o.match_fragmented_regions;
  s.floor_band = static_cast<float>(o.floor_band);
  return s;
}

// The frame's depth smoothed (SmoothDepth); the camera pose, intrinsics and
// source kept; no truth, intensity or unorganized points.
Frame SmoothedFrame(const Frame& frame, int radius, const internal::DepthNoise& noise, double gate_sigmas) {
  Frame out;
  out.depth = internal::SmoothDepth(frame.depth, radius, noise, gate_sigmas);
  out.intrinsics = frame.intrinsics;
  out.X_BC = frame.X_BC;
  out.timestamp_ns = frame.timestamp_ns;
  out.source = frame.source;
  return out;
}

// The bin floor in B: (n, d) with n . x + d = 0 on it, n = z of W.
Eigen::Vector4d FloorPlane(const Pose& X_BW) {
  const Eigen::Vector3f z_W_in_B = X_BW.linear().col(2).cast<float>();
  const float floor_d = static_cast<float>(-X_BW.translation().dot(X_BW.linear().col(2)));
  return Eigen::Vector4d(z_W_in_B.x(), z_W_in_B.y(), z_W_in_B.z(), floor_d);
}

// The log line of a bin detection: a warning when found beyond
// bin.detect_warn, debug otherwise.
void NoteBin(const BinDetection& bin) {
  if (!bin.found) {
    spdlog::debug("bin detection: not found ({}), the nominal bin pose is used", bin.reason);
  } else if (bin.warn) {
    spdlog::warn("bin detection: the bin is {:.1f} mm / {:.2f} deg from its nominal pose (bin.detect_warn)",
                 1e3 * bin.offset, bin.offset_deg);
  } else {
    spdlog::debug("bin detection: found {:.1f} mm / {:.2f} deg from nominal, {} rim points, rim rms {:.2f} mm",
                  1e3 * bin.offset, bin.offset_deg, bin.rim_points, 1e3 * bin.rim_rms);
  }
}

// The classes perception has a model of: the cell's parts, then its fixtures
// (as parts without symmetry or grasps).
std::vector<PartSpec> ModelSpecs(const Cell& cell) {
  std::vector<PartSpec> specs = cell.parts;
  for (const FixtureSpec& f : cell.fixtures) {
    PartSpec p;
    p.class_id = f.class_id;
    p.name = f.name;
    p.mesh = f.mesh;
    specs.push_back(std::move(p));
  }
  return specs;
}

class PerceptionImpl final : public Perception {
 public:
  PerceptionImpl(const Cell& cell, const PerceptionOptions& options,
                 std::vector<std::unique_ptr<ClassModel>> models, std::map<int, std::string> failures)
      : cell_(cell), options_(options), models_(std::move(models)), failures_(std::move(failures)),
        box_(internal::MakeRoiBox(cell)) {}

  Result<PerceptionResult> Run(const Frame& frame, const std::vector<int>& classes, PerceptionEffort effort,
                               const std::optional<PerceptionRegion>& region) const override {
    return RunWithin(frame, classes, effort, region, nullptr);
  }
  Result<PerceptionResult> RunThorough(const Frame& frame, const std::vector<int>& classes,
                                       const PerceptionBudget& budget,
                                       const std::optional<PerceptionRegion>& region) const override {
    return RunWithin(frame, classes, PerceptionEffort::kThorough, region, &budget);
  }
  const PerceptionOptions& options() const override { return options_; }

 private:
  // The pipeline; `budget` (optional) bounds the pose stage.
  Result<PerceptionResult> RunWithin(const Frame& frame, const std::vector<int>& classes, PerceptionEffort effort,
                                     const std::optional<PerceptionRegion>& region,
                                     const PerceptionBudget* budget) const;
  // The models of the requested classes (empty = all) and why the others
  // have none; InvalidArgument for a class the cell does not have.
  Status SelectModels(const std::vector<int>& classes, std::vector<const ClassModel*>* models,
                      std::string* problems) const;
  // Stages "regions" and "segment"; X_BW: the frame whose z = 0 is the floor
  // (none without `floor`).
  internal::Segments Segment(const internal::RoiCloud& roi, const Frame& frame, const Pose& X_BW, bool floor,
                             StageClock& clock) const;
  // Stages "pose", "verify", "second_look", "residual",
  // "residual_regions" and "own_turns": the views matched and accepted.
  // Fills the result's detections and counts. point_of_pixel:
  // RoiCloud::point_of_pixel of result.roi_points_B.
  void MatchViews(const internal::Segments& segments, const Frame& frame, std::span<const int32_t> point_of_pixel,
                  std::span<const ClassModel* const> models, bool thorough, const internal::FitRmsLimit& fit_limit,
                  const std::optional<Eigen::Vector4d>& floor_plane_B, const PerceptionBudget* budget,
                  StageClock& clock, PerceptionResult& result) const;

  Cell cell_;
  PerceptionOptions options_;
  std::vector<std::unique_ptr<ClassModel>> models_;
  std::map<int, std::string> failures_;  // class id -> why it has no model
  internal::RoiBox box_;
};

Status PerceptionImpl::SelectModels(const std::vector<int>& classes, std::vector<const ClassModel*>* models,
                                    std::string* problems) const {
  const auto select = [&](int class_id) {
    const auto it =
        std::find_if(models_.begin(), models_.end(), [&](const auto& m) { return m->class_id() == class_id; });
    if (it != models_.end()) {
      models->push_back(it->get());
    } else if (const auto f = failures_.find(class_id); f != failures_.end()) {
      *problems += (problems->empty() ? "" : "; ") + f->second;
    }
  };
  const auto named = [&](int class_id) { return std::find(classes.begin(), classes.end(), class_id) != classes.end(); };
  // Empty: every part; fixtures only when named.
  for (const PartSpec& part : cell_.parts) {
    if (classes.empty() || named(part.class_id)) select(part.class_id);
  }
  for (const FixtureSpec& fixture : cell_.fixtures) {
    if (named(fixture.class_id)) select(fixture.class_id);
  }
  for (int c : classes) {
    if (cell_.FindPart(c) == nullptr && cell_.FindFixture(c) == nullptr) {
      return Status::InvalidArgument("class " + std::to_string(c) + " is neither a part nor a fixture of cell '" +
                                     cell_.name + "'");
    }
  }
  return Status::Ok();
}

internal::Segments PerceptionImpl::Segment(const internal::RoiCloud& roi, const Frame& frame, const Pose& X_BW,
                                           bool floor, StageClock& clock) const {
  internal::SegmentationOptions options = SegmentationOptionsOf(options_);
  if (!floor) options.floor_band = -std::numeric_limits<float>::infinity();
  if (roi.organized()) {
    internal::GridLabels labels = internal::LabelGrid(roi, frame, X_BW, options);
    clock.Lap("regions");
    options.min_segment_points =
        internal::FrameMinSegmentPoints(options.min_segment_points, options_.min_segment_spacing, labels.spacing);
    internal::Segments segments = internal::GroupGridSegments(roi, std::move(labels), options);
    clock.Lap("segment");
    return segments;
  }
  auto [region_of_point, regions] = internal::LabelCloud(roi, kUnorganizedVoxel);
  clock.Lap("regions");
  internal::Segments segments =
      internal::GroupCloudSegments(roi, std::move(region_of_point), regions, options.min_segment_points);
  clock.Lap("segment");
  return segments;
}

void PerceptionImpl::MatchViews(const internal::Segments& segments, const Frame& frame,
                                std::span<const int32_t> point_of_pixel,
                                std::span<const ClassModel* const> models, bool thorough,
                                const internal::FitRmsLimit& fit_limit,
                                const std::optional<Eigen::Vector4d>& floor_plane_B,
                                const PerceptionBudget* budget, StageClock& clock, PerceptionResult& result) const {
  // Each segment view is the segment's samples, then (context_relative_radius
  // > 0) the other segments' samples near its centroid.
  double max_diameter = 0.0;
  for (const ClassModel* m : models) max_diameter = std::max(max_diameter, m->diameter());
  internal::ViewSet views;
  views.views = internal::SegmentViews(segments, static_cast<float>(options_.context_relative_radius * max_diameter));
  views.first_region = views.views.size();
  for (const internal::ViewIndices& view : segments.region_views) views.views.push_back(view);

  internal::ViewMatcher matcher(options_, models, thorough, frame, floor_plane_B, segments, fit_limit, budget);
  internal::Acceptance acceptance(result.roi_points_B.size(), models, options_.near_centre_min_shared,
                                  result.roi_points_B);
  internal::WaveResult waves = internal::MatchInWaves(std::move(views), options_, thorough, segments, matcher,
                                                      acceptance);
  result.timings.push_back({"pose", waves.match_ms});
  result.timings.push_back({"verify", waves.accept_ms});
  clock.Restart();
  result.second_looks = internal::SecondLook(std::move(waves.weak), options_, segments, matcher, acceptance);
  clock.Lap("second_look");
  internal::ViewSet residual;  // segment views only
  residual.views = internal::ResidualViews(segments, acceptance, segments.min_points);
  residual.first_region = residual.views.size();
  if (!residual.views.empty()) acceptance.Accept(matcher.Match(residual, internal::MatchPass::kWave).candidates);
  clock.Lap("residual");
  if (options_.residual_regions) {
    // Region views (skipped when no class fits), with the waves' search (the
    // second look's wider one added more wrong detections than right ones:
    // docs/tuning.md, "residual_regions").
    internal::ViewSet regions;
    regions.views = internal::ResidualRegionViews(segments, acceptance, segments.min_points,
                                                  options_.residual_across_jumps);
    if (!regions.views.empty()) {
      internal::MatchOutcome matched = matcher.Match(regions, internal::MatchPass::kWave);
      acceptance.Accept(std::move(matched.candidates));
      // The views nothing was found in, again with the estimator's own
      // normals (residual_own_normals; docs/tuning.md).
      if (options_.residual_own_normals) {
        const internal::ViewSet again = internal::NothingFound(regions, matched, options_.min_detection_score);
        if (!again.views.empty()) acceptance.Accept(matcher.Match(again, internal::MatchPass::kWave).candidates);
      }
    }
    clock.Lap("residual_regions");
  }
  if (options_.enclosing_parts) {
    const std::vector<internal::EnclosingView> enclosing =
        internal::EnclosingViews(segments, acceptance, models, std::max(1, segments.min_points / 3));
    internal::ReplaceEnclosed(enclosing, segments, models, matcher, acceptance);
    clock.Lap("enclosing");
  }

  const internal::MatchCounts& counts = matcher.counts();
  result.views = counts.views + waves.views_explained;
  result.views_explained = waves.views_explained;
  result.estimator_calls = counts.estimator_calls;
  result.estimates_skipped = counts.estimates_skipped.load();
  result.coarse_refined = counts.coarse_refined.load();
  result.coarse_skipped = counts.coarse_skipped.load();
  result.detections = acceptance.TakeDetections();
  if (options_.own_turn_gain >= 0.0) {
    internal::RedecideTurns(models, frame, result.roi_points_B, point_of_pixel, floor_plane_B, options_.own_turn_gain,
                            options_.own_turn_min_foreign, &result.detections);
    clock.Lap("own_turns");
  }
  result.withheld_ambiguous = internal::WithholdAmbiguous(options_.ambiguous_min_visible, &result.detections);
  result.withheld_one_plane =
      internal::WithholdOnePlane(options_.one_plane_min_visible, result.roi_points_B, &result.detections);
  if (result.detections.empty()) {
    result.reason = "no hypothesis passed verification in " + std::to_string(segments.range.size()) + " segments" +
                    (counts.rejected_low_score > 0
                         ? " (" + std::to_string(counts.rejected_low_score) + " below min_detection_score)"
                         : std::string()) +
                    (counts.rejected_free_space > 0
                         ? " (" + std::to_string(counts.rejected_free_space) + " too much in free space)"
                         : std::string()) +
                    (counts.first_reason.empty() ? "" : " (e.g. " + counts.first_reason + ")") +
                    (result.withheld_ambiguous > 0
                         ? " (" + std::to_string(result.withheld_ambiguous) + " withheld: ambiguous, mostly hidden)"
                         : std::string()) +
                    (result.withheld_one_plane > 0
                         ? " (" + std::to_string(result.withheld_one_plane) + " withheld: one plane seen, mostly hidden)"
                         : std::string()) +
                    (result.budget_exhausted()
                         ? " (budget used: " + std::to_string(result.estimates_skipped) + " estimates not run)"
                         : std::string());
  }
}

// The pipeline, stage by stage (docs/perception_pipeline.md): deproject and
// crop, depth noise, regions and segments, then the views matched in waves,
// a second look and a residual pass, each followed by acceptance.
Result<PerceptionResult> PerceptionImpl::RunWithin(const Frame& frame, const std::vector<int>& classes,
                                                   PerceptionEffort effort,
                                                   const std::optional<PerceptionRegion>& region,
                                                   const PerceptionBudget* budget) const {
  PerceptionResult result;
  std::vector<const ClassModel*> models;
  std::string model_problems;
  if (Status s = SelectModels(classes, &models, &model_problems); !s.ok()) return s;
  if (region && region->box_R.isEmpty()) return Status::InvalidArgument("perception: the region's box is empty");
  if (region && region->clear_mesh_R && !(region->clear_margin > 0)) {
    return Status::InvalidArgument("perception: the region's clear_margin must be > 0");
  }
  StageClock clock(&result.timings);

  // A frame noisier than smoothing_target_sigma is smoothed first and every
  // later stage sees the smoothed depth. The fit limit keeps the frame's
  // noise as measured before smoothing (docs/perception_pipeline.md, "Depth
  // noise and smoothing").
  const internal::DepthNoise noise(cell_.camera, frame);
  result.depth_noise_sigma = noise.measured_sigma();
  result.depth_noise_at = noise.measured_at();
  const int smoothing_radius =
      internal::SmoothingRadius(noise, options_.smoothing_target_sigma, options_.smoothing_max_radius);
  Frame smoothed;
  if (smoothing_radius > 0) {
    smoothed = SmoothedFrame(frame, smoothing_radius, noise, options_.smoothing_gate_sigmas);
    clock.Lap("smooth");
  }
  const Frame& used = smoothing_radius > 0 ? smoothed : frame;

  // Bin detection (pipeline/bin_detection.h) for runs into the bin; a bin
  // not found leaves the nominal pose (the planner refuses the capture
  // first under `required`, measuring on the raw frame, and hands its
  // detection on with the frame: reported here, not measured again).
  if (!region && cell_.bin.detect.mode != BinDetectSpec::Mode::kOff) {
    result.bin = frame.bin ? *frame.bin : DetectBin(used, cell_.bin);
    result.timings.push_back({"bin", result.bin->ms});
    clock.Restart();
    NoteBin(*result.bin);
  }
  // The region's frame stands in for the bin frame W everywhere below: its
  // z = 0 plane is the floor.
  const Pose& X_BW = region ? region->X_BR : BinPoseOf(result, cell_.bin);
  const internal::RoiBox box = region ? internal::RoiBox{region->box_R.min().cast<float>(),
                                                         region->box_R.max().cast<float>()}
                                      : box_;
  internal::RoiCloud roi;
  internal::CropToRoi(used, X_BW, box, &roi);
  if (region && region->clear_mesh_R && !region->clear_mesh_R->empty()) ClearKnownGeometry(*region, &roi);
  clock.Lap("roi");
  if (!region) {
    // The fill level over the ROI's floor (the bin's inner floor less the wall margin).
    const Eigen::Vector2d half = cell_.bin.inner_size.head<2>() / 2 - Eigen::Vector2d::Constant(cell_.roi.wall_margin);
    result.fill = MeasureFillLevel(roi.points_B, X_BW, half);
  }
  result.roi_point_count = static_cast<int64_t>(roi.points_B.size());
  if (roi.valid_points == 0 || roi.points_B.empty()) {
    result.segment_of_point.assign(roi.points_B.size(), -1);
    result.reason = roi.valid_points == 0 ? "frame has no valid points"
                                          : "ROI is empty: none of the frame's " + std::to_string(roi.valid_points) +
                                                " valid points is inside the " + (region ? "task's" : "bin") + " ROI";
    result.roi_points_B = std::move(roi.points_B);
    return result;
  }

  const internal::FitRmsLimit fit_limit(options_.max_fit_rms_sigmas, options_.min_fit_rms_limit, noise, used);
  const bool floor = !region || region->support;
  internal::Segments segments = Segment(roi, used, X_BW, floor, clock);
  result.segment_of_point = std::move(segments.segment_of_point);
  result.largest_region_points = internal::LargestRegionPoints(segments.region_of_point);
  result.roi_points_B = std::move(roi.points_B);
  if (segments.range.empty()) {
    result.reason = "no segment of at least " + std::to_string(segments.min_points) +
                    " points in the ROI (" + std::to_string(result.roi_point_count) + " ROI points, largest region " +
                    std::to_string(result.largest_region_points) + ")";
    return result;
  }
  if (models.empty()) {
    result.reason = model_problems.empty() ? "no part class to look for" : "no pose model: " + model_problems;
    return result;
  }
  MatchViews(segments, used, roi.point_of_pixel, models, effort == PerceptionEffort::kThorough, fit_limit,
             floor ? std::optional<Eigen::Vector4d>(FloorPlane(X_BW)) : std::nullopt, budget, clock, result);
  return result;
}

}  // namespace

Result<std::unique_ptr<Perception>> Perception::Build(const Cell& cell, const PerceptionOptions& options) {
  if (options.threads < 1) return Status::InvalidArgument("perception: threads must be >= 1");
  for (const auto& [name, s] : {std::pair<const char*, const PoseSearch&>{"thorough_search", options.thorough_search},
                                 {"second_look_search", options.second_look_search}}) {
    if (!s.IsValid()) {
      return Status::InvalidArgument(std::string("perception: ") + name +
                                     " counts must be >= 1, peaks_examined >= peaks_per_reference, stop_score in [0, 1]");
    }
  }
  if (!(options.smoothing_target_sigma >= 0.0) || !std::isfinite(options.smoothing_target_sigma) ||
      options.smoothing_max_radius < 0 || !(options.smoothing_gate_sigmas > 0.0)) {
    return Status::InvalidArgument(
        "perception: smoothing_target_sigma must be finite and >= 0, smoothing_max_radius >= 0, "
        "smoothing_gate_sigmas > 0");
  }
  if (!(options.max_free_space_fraction >= 0.0 && options.max_free_space_fraction <= 1.0)) {
    return Status::InvalidArgument("perception: max_free_space_fraction must be in [0, 1]");
  }
  if (!(options.ambiguous_min_visible >= 0.0 && options.ambiguous_min_visible <= 1.0)) {
    return Status::InvalidArgument("perception: ambiguous_min_visible must be in [0, 1]");
  }
  if (!(options.own_turn_min_foreign >= 0.0 && options.own_turn_min_foreign <= 1.0)) {
    return Status::InvalidArgument("perception: own_turn_min_foreign must be in [0, 1]");
  }
  if (!(options.one_plane_min_visible >= 0.0 && options.one_plane_min_visible <= 1.0)) {
    return Status::InvalidArgument("perception: one_plane_min_visible must be in [0, 1]");
  }
  if (!(options.planar_view_min_share >= 0.0 && options.planar_view_min_share <= 1.0)) {
    return Status::InvalidArgument("perception: planar_view_min_share must be in [0, 1]");
  }
  if (!(options.near_centre_min_shared >= 0.0 && options.near_centre_min_shared <= 1.0)) {
    return Status::InvalidArgument("perception: near_centre_min_shared must be in [0, 1]");
  }
  if (!(options.segment_max_jump > 0.0)) return Status::InvalidArgument("perception: segment_max_jump must be > 0");
  if (!(options.max_support_penetration >= 0.0) || !std::isfinite(options.max_support_penetration)) {
    return Status::InvalidArgument("perception: max_support_penetration must be finite and >= 0");
  }
  if (!(options.ambiguity_net_gain >= 0.0) || !std::isfinite(options.ambiguity_net_gain)) {
    return Status::InvalidArgument("perception: ambiguity_net_gain must be finite and >= 0");
  }
  if (!(options.grid_spacing > 0.0)) return Status::InvalidArgument("perception: grid_spacing must be > 0");
  if (!(options.floor_band > 0.0)) return Status::InvalidArgument("perception: floor_band must be > 0");
  if (options.min_segment_points < 1) return Status::InvalidArgument("perception: min_segment_points must be >= 1");
  if (!(options.rank_planar_share_weight >= 0.0) || !std::isfinite(options.rank_planar_share_weight)) {
    return Status::InvalidArgument("perception: rank_planar_share_weight must be finite and >= 0");
  }
  for (size_t i = 0; i < options.view_waves.size(); ++i) {
    if (options.view_waves[i] < 1 || (i > 0 && options.view_waves[i] >= options.view_waves[i - 1])) {
      return Status::InvalidArgument("perception: view_waves must be positive and strictly decreasing");
    }
  }
  const internal::CameraFigures camera = internal::CameraFiguresOf(cell, options);
  const PoseEstimatorOptions reference = ReferenceEstimatorOptions(options);
  const std::vector<PartSpec> specs = ModelSpecs(cell);
  std::vector<Result<std::unique_ptr<ClassModel>>> built;
  built.reserve(specs.size());
  for (size_t i = 0; i < specs.size(); ++i) built.emplace_back(Status::Internal("not built"));
  tbb::task_arena arena(options.threads);
  arena.execute([&] {
    tbb::parallel_for(size_t{0}, specs.size(),
                      [&](size_t i) { built[i] = internal::BuildClassModel(specs[i], camera, reference); });
  });
  std::vector<std::unique_ptr<ClassModel>> models;
  std::map<int, std::string> failures;
  std::string required_failures;
  std::vector<internal::ClassFigures> figures;
  for (size_t i = 0; i < built.size(); ++i) {
    // specs: the cell's parts, then its fixtures (never optional).
    const PartSpec& part = specs[i];
    const bool fixture = i >= cell.parts.size();
    const char* kind = fixture ? "fixture" : "part";
    if (!built[i].ok()) {
      const std::string why = built[i].status().message();
      spdlog::error("perception: no model for {} '{}' (class {}{}): {}", kind, part.name, part.class_id,
                    part.optional ? ", optional: left out" : "", why);
      failures[part.class_id] = why;
      if (!part.optional) required_failures += (required_failures.empty() ? "" : "; ") + why;
      continue;
    }
    const ClassModel& m = **built[i];
    // The pipeline's options scale to the parts in the bin; a fixture is
    // looked for in its own region, so it does not shrink them.
    if (!fixture) {
      figures.push_back({m.diameter(), part.perception.flat_height.value_or(m.lowest_upward_face()),
                         part.perception.min_view_points.value_or(0)});
    }
    const PoseEstimatorOptions& o = m.estimator_options();
    spdlog::info("perception: {} '{}' (class {}), {:.1f} mm across: ppf step {:.2f} mm, icp spacing {:.2f} mm, "
                 "verify spacing {:.2f} mm, support {:.2f} mm, free space {:.2f} mm, inside depth {:.2f} mm, "
                 "lowest upward face {:.2f} mm",
                 kind, part.name, part.class_id, m.diameter() * 1e3, o.ppf_relative_sampling * m.diameter() * 1e3,
                 o.icp_model_spacing * 1e3, o.verify_model_spacing * 1e3, o.support_distance * 1e3,
                 o.free_space_distance * 1e3, m.inside_depth() * 1e3, m.lowest_upward_face() * 1e3);
    models.push_back(std::move(built[i]).value());
  }
  if (!required_failures.empty()) {
    return Status::InvalidArgument("perception: " + required_failures +
                                   " (mark a part `optional: true` in the cell to start without it)");
  }
  PerceptionOptions scaled = options;
  const std::string changed = internal::ScaleToClasses(figures, camera, &scaled);
  if (!changed.empty()) spdlog::info("perception: scaled to the cell's parts and camera: {}", changed);
  return std::unique_ptr<Perception>(std::make_unique<PerceptionImpl>(cell, scaled, std::move(models), std::move(failures)));
}

}  // namespace bp
