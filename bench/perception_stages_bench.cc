// Perception's stages one at a time on the default cell's 20-part pile at
// 640x480 (config 1, seed 1), on a 2-thread oneTBB arena: the depth
// smoothing (radius 1 and 2; this frame is not noisy enough to be smoothed
// by the pipeline), the crop, the grid labels, the segments, the pose stage
// (every view in waves, with acceptance) and the second look. Each stage's input is built once, outside
// the timed loop.
//
//   build/bin/bp_bench --benchmark_filter=Stage --benchmark_repetitions=5
//       --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>

#include <memory>
#include <vector>

#include <tbb/task_arena.h>

#include "core/cell.h"
#include "pipeline/capture_source.h"
#include "pipeline/internal/acceptance.h"
#include "pipeline/internal/class_model.h"
#include "pipeline/internal/depth_smoothing.h"
#include "pipeline/internal/fit_limit.h"
#include "pipeline/internal/part_settings.h"
#include "pipeline/internal/roi_cloud.h"
#include "pipeline/internal/segmentation.h"
#include "pipeline/internal/view_matching.h"
#include "pipeline/internal/view_passes.h"

namespace bp::internal {
namespace {

struct StageData {
  Cell cell;
  PerceptionOptions options;
  Frame frame;
  RoiBox box;
  RoiCloud roi;
  GridLabels labels;
  Segments segments;
  std::vector<std::unique_ptr<ClassModel>> owned;
  std::vector<const ClassModel*> models;
  std::unique_ptr<FitRmsLimit> fit_limit;
  bool ok = false;

  SegmentationOptions segmentation() const {
    SegmentationOptions s;
    s.grid_spacing = options.grid_spacing;
    s.max_jump = options.segment_max_jump;
    s.normal_angle_deg = options.segment_normal_angle_deg;
    s.min_segment_points = options.min_segment_points;
    return s;
  }
  ViewSet Views() const {
    ViewSet views;
    views.views = SegmentViews(segments, 0.f);
    views.first_region = views.views.size();
    for (const ViewIndices& v : segments.region_views) views.views.push_back(v);
    return views;
  }
  Eigen::Vector4d Floor() const {
    const Eigen::Vector3d z = cell.bin.X_BW.linear().col(2);
    return Eigen::Vector4d(z.x(), z.y(), z.z(), -cell.bin.X_BW.translation().dot(z));
  }
};

tbb::task_arena& Arena() {
  static tbb::task_arena arena(2);
  return arena;
}

StageData& Data() {
  static StageData* d = [] {
    auto* data = new StageData;
    auto cell = LoadDefaultCell();
    if (!cell.ok()) return data;
    data->cell = *cell;
    data->cell.source.seed = 1;
    data->cell.source.num_parts = 20;
    auto source = MakeCaptureSource(data->cell);
    if (!source.ok()) return data;
    CaptureRequest request;
    request.config_id = 1;
    auto frame = (*source)->Capture(request);
    if (!frame.ok()) return data;
    data->frame = std::move(*frame);
    for (const PartSpec& part : data->cell.parts) {
      auto model = BuildClassModel(part, CameraFiguresOf(data->cell, data->options));
      if (!model.ok()) return data;
      data->models.push_back(model->get());
      data->owned.push_back(std::move(*model));
    }
    data->box = MakeRoiBox(data->cell);
    Arena().execute([&] {
      CropToRoi(data->frame, data->cell.bin.X_BW, data->box, &data->roi);
      data->labels = LabelGrid(data->roi, data->frame, data->cell.bin.X_BW, data->segmentation());
      data->segments = GroupGridSegments(data->roi, data->labels, data->segmentation());
    });
    data->fit_limit = std::make_unique<FitRmsLimit>(data->options.max_fit_rms_sigmas, data->options.min_fit_rms_limit,
                                                    DepthNoise(data->cell.camera, data->frame), data->frame);
    data->ok = true;
    return data;
  }();
  return *d;
}

#define STAGE_DATA_OR_SKIP(d)                                            \
  StageData& d = Data();                                                 \
  if (!d.ok) {                                                           \
    state.SkipWithError("no synthetic frame or class models (OSMesa)"); \
    return;                                                              \
  }

// SmoothDepth over the whole frame, window half width state.range(0).
void BM_StageSmooth(benchmark::State& state) {
  STAGE_DATA_OR_SKIP(d);
  const DepthNoise noise(d.cell.camera, d.frame);
  const int radius = static_cast<int>(state.range(0));
  for (auto _ : state) {
    Arena().execute([&] { benchmark::DoNotOptimize(SmoothDepth(d.frame.depth, radius, noise, 2.0)); });
  }
}
BENCHMARK(BM_StageSmooth)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_StageCrop(benchmark::State& state) {
  STAGE_DATA_OR_SKIP(d);
  RoiCloud roi;
  for (auto _ : state) Arena().execute([&] { CropToRoi(d.frame, d.cell.bin.X_BW, d.box, &roi); });
  state.counters["roi_points"] = static_cast<double>(roi.points_B.size());
}
BENCHMARK(BM_StageCrop)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_StageLabelGrid(benchmark::State& state) {
  STAGE_DATA_OR_SKIP(d);
  for (auto _ : state) {
    Arena().execute([&] { benchmark::DoNotOptimize(LabelGrid(d.roi, d.frame, d.cell.bin.X_BW, d.segmentation())); });
  }
}
BENCHMARK(BM_StageLabelGrid)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_StageGroupSegments(benchmark::State& state) {
  STAGE_DATA_OR_SKIP(d);
  size_t segments = 0;
  for (auto _ : state) {
    Arena().execute([&] { segments = GroupGridSegments(d.roi, d.labels, d.segmentation()).range.size(); });
  }
  state.counters["segments"] = static_cast<double>(segments);
}
BENCHMARK(BM_StageGroupSegments)->Unit(benchmark::kMillisecond)->UseRealTime();

// The pose stage: every view in waves, each wave's candidates accepted.
void BM_StagePoseWaves(benchmark::State& state) {
  STAGE_DATA_OR_SKIP(d);
  size_t detections = 0;
  int estimator_calls = 0;
  for (auto _ : state) {
    Arena().execute([&] {
      ViewMatcher matcher(d.options, d.models, false, d.frame, d.Floor(), d.segments, *d.fit_limit);
      Acceptance acceptance(d.roi.points_B.size(), d.models);
      WaveResult waves = MatchInWaves(d.Views(), d.options, false, d.segments, matcher, acceptance);
      detections = acceptance.TakeDetections().size();
      estimator_calls = matcher.counts().estimator_calls;
    });
  }
  state.counters["detections"] = static_cast<double>(detections);
  state.counters["estimator_calls"] = estimator_calls;
}
BENCHMARK(BM_StagePoseWaves)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);

// The second look alone: its input (the waves' weak views and acceptance)
// is rebuilt outside the timing for each iteration.
void BM_StageSecondLook(benchmark::State& state) {
  STAGE_DATA_OR_SKIP(d);
  int looks = 0;
  for (auto _ : state) {
    state.PauseTiming();
    auto matcher = std::make_unique<ViewMatcher>(d.options, d.models, false, d.frame, d.Floor(), d.segments,
                                                 *d.fit_limit);
    auto acceptance = std::make_unique<Acceptance>(d.roi.points_B.size(), d.models);
    WaveResult waves;
    Arena().execute([&] { waves = MatchInWaves(d.Views(), d.options, false, d.segments, *matcher, *acceptance); });
    state.ResumeTiming();
    Arena().execute([&] { looks = SecondLook(std::move(waves.weak), d.options, d.segments, *matcher, *acceptance); });
  }
  state.counters["views_looked_at"] = looks;
}
BENCHMARK(BM_StageSecondLook)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace bp::internal
