// Perception latency, frame in memory -> detections, on a 2-thread oneTBB
// arena: the default cell's 20-part pile at 640x480 (config 1) and 1920x1200
// (config 2). Counters give the mean per-stage time (ms) over the iterations.
//
//   build/bin/bp_bench --benchmark_filter=Perception
//       --benchmark_repetitions=5 --benchmark_report_aggregates_only=true
#include <benchmark/benchmark.h>

#include <cstdio>
#include <ctime>
#include <map>
#include <memory>

#include <tbb/task_arena.h>

#include "core/cell.h"
#include "pipeline/capture_source.h"
#include "pipeline/perception.h"

namespace bp {
namespace {

struct PerceptionBenchData {
  Cell cell;
  std::unique_ptr<Perception> perception;
  std::map<int, Frame> frames;  // by camera config id
  bool ok = false;
};

PerceptionBenchData& Data() {
  static PerceptionBenchData* d = [] {
    auto* data = new PerceptionBenchData;
    auto cell = LoadDefaultCell();
    if (!cell.ok()) return data;
    data->cell = *cell;
    data->cell.source.seed = 1;
    data->cell.source.num_parts = 20;
    auto perception = Perception::Build(data->cell);
    if (!perception.ok()) return data;
    data->perception = std::move(*perception);
    auto source = MakeCaptureSource(data->cell);
    if (!source.ok()) return data;
    for (int config : {1, 2}) {
      CaptureRequest request;
      request.config_id = config;
      auto frame = (*source)->Capture(request);
      if (!frame.ok()) return data;
      data->frames[config] = std::move(*frame);
    }
    data->ok = true;
    return data;
  }();
  return *d;
}

void BM_PerceptionRun(benchmark::State& state) {
  PerceptionBenchData& data = Data();
  if (!data.ok) {
    state.SkipWithError("no synthetic frame or perception (OSMesa / models)");
    return;
  }
  const Frame& frame = data.frames.at(static_cast<int>(state.range(0)));
  tbb::task_arena arena(2);
  std::map<std::string, double> stage_ms;
  size_t detections = 0;
  int coarse_refined = 0;  // first-pass ICPs per run: the estimator's work, machine-independent
  // Process CPU time (all threads) per run: with 2 threads, cpu_ms / wall
  // time tells how well the arena is used.
  const auto process_cpu_ms = [] {
    timespec ts{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts);
    return 1e3 * static_cast<double>(ts.tv_sec) + 1e-6 * static_cast<double>(ts.tv_nsec);
  };
  double cpu_ms = 0.0;
  for (auto _ : state) {
    const double cpu0 = process_cpu_ms();
    Result<PerceptionResult> r = Status::Internal("not run");
    arena.execute([&] { r = data.perception->Run(frame); });
    if (!r.ok()) {
      state.SkipWithError(r.status().ToString().c_str());
      return;
    }
    cpu_ms += process_cpu_ms() - cpu0;
    for (const StageTiming& t : r->timings) stage_ms[t.stage] += t.ms;
    detections = r->detections.size();
    coarse_refined = r->coarse_refined;
    benchmark::DoNotOptimize(r);
  }
  for (const auto& [stage, ms] : stage_ms) {
    state.counters[stage + "_ms"] = ms / static_cast<double>(state.iterations());
  }
  state.counters["detections"] = static_cast<double>(detections);
  state.counters["coarse_refined"] = coarse_refined;
  state.counters["cpu_ms"] = cpu_ms / static_cast<double>(state.iterations());
  state.SetLabel(std::to_string(frame.depth.width) + "x" + std::to_string(frame.depth.height));
}
BENCHMARK(BM_PerceptionRun)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime()->MinTime(2.0);

}  // namespace
}  // namespace bp
