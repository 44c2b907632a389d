// Recorder costs. BM_RecordVgaCapture: the writer thread's time per 640 x 480
// capture (PCD + depth PNG + intensity PNG, fsync, checksums, manifest,
// rename), measured as OnDetection + Flush. BM_OnDetectionEnqueue: what the
// detection worker pays (queue push; the frame is shared, not copied), with
// a queue that is always full, so every call is a drop.
#include <benchmark/benchmark.h>

#include <filesystem>
#include <random>

#include "grasp/bin_picking_planner.h"
#include "record/recorder.h"

namespace bp {
namespace {

DetectionEvent VgaEvent() {
  std::mt19937 rng{42};
  std::uniform_real_distribution<float> z(0.9f, 1.1f);
  Frame f;
  f.intrinsics.width = 640;
  f.intrinsics.height = 480;
  f.intrinsics.fx = f.intrinsics.fy = 800.0;
  f.intrinsics.cx = 319.5;
  f.intrinsics.cy = 239.5;
  f.depth = DepthImage(640, 480);
  f.intensity = IntensityImage(640, 480);
  for (size_t i = 0; i < f.depth.data.size(); ++i) {
    f.depth.data[i] = z(rng);
    f.intensity.data[i] = static_cast<uint8_t>(rng() & 0xFF);
  }
  DetectionEvent e;
  e.scene = std::make_shared<CapturedFrame>(std::move(f));
  e.plan = PlanResult{};
  return e;
}

std::shared_ptr<Recorder> StartRecorder(const std::string& name, RecorderOptions o) {
  const std::string dir = (std::filesystem::temp_directory_path() / name).string();
  std::filesystem::remove_all(dir);
  o.directory = dir;
  o.max_disk_bytes = int64_t{200} << 20;
  auto cell = LoadDefaultCell();
  return *Recorder::Start(*cell, o);
}

void BM_RecordVgaCapture(benchmark::State& state) {
  auto recorder = StartRecorder("binpick_record_bench", {});
  const DetectionEvent e = VgaEvent();
  for (auto _ : state) {
    recorder->OnDetection(e);
    recorder->Flush();
  }
  recorder->Stop();
  state.counters["recorded"] = static_cast<double>(recorder->stats().captures_recorded);
}
BENCHMARK(BM_RecordVgaCapture)->Unit(benchmark::kMillisecond)->Iterations(20);

void BM_OnDetectionEnqueue(benchmark::State& state) {
  RecorderOptions o;
  o.queue_captures = 1;
  std::mutex m;
  m.lock();  // the writer blocks on its first capture: the queue stays full
  o.before_write = [&m] {
    m.lock();
    m.unlock();
  };
  auto recorder = StartRecorder("binpick_record_bench_q", o);
  const DetectionEvent e = VgaEvent();
  recorder->OnDetection(e);
  recorder->OnDetection(e);
  for (auto _ : state) recorder->OnDetection(e);
  m.unlock();
  recorder->Stop();
}
BENCHMARK(BM_OnDetectionEnqueue)->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace bp
