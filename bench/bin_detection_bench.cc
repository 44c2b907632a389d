// The bin detection stage (issue 41, pipeline/bin_detection.h) alone, on the
// default cell's 20-part pile (seed 1) with the bin off nominal as seed 1
// draws it within +-50 mm / +-10 deg / 2 deg tilt (source.bin_offset; 6.9 mm
// for seed 1, counter offset_mm), per camera config:
// 1 = 640x480, 2 = 1920x1200. The frame is rendered once, outside the loop.
//
//   build/bin/bp_bench --benchmark_filter=BinDetection --benchmark_repetitions=5
//       --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>

#include <map>
#include <memory>

#include "core/cell.h"
#include "pipeline/bin_detection.h"
#include "pipeline/capture_source.h"

namespace bp {
namespace {

struct BinFrame {
  Cell cell;
  Frame frame;
  bool ok = false;
};

const BinFrame& FrameFor(int config_id) {
  static std::map<int, BinFrame> frames;
  auto [it, inserted] = frames.try_emplace(config_id);
  BinFrame& d = it->second;
  if (!inserted) return d;
  auto cell = LoadDefaultCell();
  if (!cell.ok()) return d;
  d.cell = *cell;
  d.cell.source.seed = 1;
  d.cell.source.num_parts = 20;
  d.cell.source.bin_offset_translation = 0.05;
  d.cell.source.bin_offset_yaw_deg = 10.0;
  d.cell.source.bin_offset_tilt_deg = 2.0;
  auto source = MakeCaptureSource(d.cell);
  if (!source.ok()) return d;
  CaptureRequest request;
  request.config_id = config_id;
  auto frame = (*source)->Capture(request);
  if (!frame.ok()) return d;
  d.frame = std::move(*frame);
  d.ok = true;
  return d;
}

void BM_StageBinDetection(benchmark::State& state) {
  const BinFrame& d = FrameFor(static_cast<int>(state.range(0)));
  if (!d.ok) {
    state.SkipWithError("no synthetic frame (OSMesa)");
    return;
  }
  BinDetection bin;
  for (auto _ : state) {
    bin = DetectBin(d.frame, d.cell.bin);
    benchmark::DoNotOptimize(bin);
  }
  state.counters["found"] = bin.found ? 1 : 0;
  state.counters["rim_points"] = bin.rim_points;
  state.counters["offset_mm"] = 1e3 * bin.offset;
}
BENCHMARK(BM_StageBinDetection)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

// The same frames with a free-standing bin's window (bin.detect_search
// rotation_deg: any, search_yaw_deg 180): the rim's yaw searched over its
// whole period.
void BM_StageBinDetectionAnyYaw(benchmark::State& state) {
  const BinFrame& d = FrameFor(static_cast<int>(state.range(0)));
  if (!d.ok) {
    state.SkipWithError("no synthetic frame (OSMesa)");
    return;
  }
  BinSpec bin_spec = d.cell.bin;
  bin_spec.detect.search_yaw_deg = 180.0;
  BinDetection bin;
  for (auto _ : state) {
    bin = DetectBin(d.frame, bin_spec);
    benchmark::DoNotOptimize(bin);
  }
  state.counters["found"] = bin.found ? 1 : 0;
  state.counters["rim_points"] = bin.rim_points;
  state.counters["offset_mm"] = 1e3 * bin.offset;
}
BENCHMARK(BM_StageBinDetectionAnyYaw)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace bp
