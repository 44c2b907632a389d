// Synthetic capture costs on the default cell (20 parts):
//   ./build/bin/bp_bench --benchmark_filter='Pile|Capture|RenderOnly|DepthNoise'
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <optional>
#include <string>

#include "core/mesh_gen.h"
#include "pipeline/internal/depth_noise.h"
#include "pipeline/renderer.h"
#include "pipeline/synthetic_source.h"

namespace bp {
namespace {

Cell BenchCell() {
  auto cell = LoadDefaultCell();
  if (!cell.ok()) {
    std::fprintf(stderr, "%s\n", cell.status().ToString().c_str());
    std::abort();
  }
  cell->source.num_parts = 20;
  cell->source.seed = 1;
  return *cell;
}

std::vector<PileClass> Classes(const Cell& cell) {
  std::vector<PileClass> classes;
  for (const auto& part : cell.parts) {
    auto mesh = LoadMesh(part.mesh);
    if (!mesh.ok()) std::abort();
    classes.push_back({part.class_id, part.name, std::make_shared<TriangleMesh>(std::move(*mesh))});
  }
  return classes;
}

SyntheticSource* AsSynthetic(const std::unique_ptr<CaptureSource>& s) {
  return dynamic_cast<SyntheticSource*>(s.get());
}

void BM_PileGeneration20(benchmark::State& state) {
  const Cell cell = BenchCell();
  const TriangleMesh bin = MakeBinMesh(cell.bin);
  const auto classes = Classes(cell);
  PileOptions o;
  o.num_parts = 20;
  uint64_t seed = 1;
  for (auto _ : state) {
    o.seed = seed++;
    auto pile = SyntheticPile::Generate(cell.bin, bin, classes, o);
    benchmark::DoNotOptimize(pile.ok());
  }
}
BENCHMARK(BM_PileGeneration20)->Unit(benchmark::kMillisecond);

// Full capture: render + projector render + noise + ground truth (solo
// renders). Arg 2: 1 = every capture renders everything (ForgetRenders: a
// pile where everything moved), 0 = the same untouched pile again (the
// renders kept between captures: noise and truth only).
void BM_Capture(benchmark::State& state) {
  const Cell cell = BenchCell();
  auto source = MakeSyntheticSource(cell);
  if (!source.ok()) {
    state.SkipWithError(source.status().ToString().c_str());
    return;
  }
  CaptureRequest r;
  r.config_id = static_cast<int>(state.range(0));
  const bool fresh = state.range(1) != 0;
  if (!(*source)->Capture(r).ok()) {  // the first capture renders in either mode
    state.SkipWithError("capture failed");
    return;
  }
  for (auto _ : state) {
    if (fresh) AsSynthetic(*source)->ForgetRenders();
    auto f = (*source)->Capture(r);
    benchmark::DoNotOptimize(f.ok());
  }
  state.SetLabel(std::string(r.config_id == 1 ? "640x480" : "1920x1200") + (fresh ? " fresh" : " unchanged pile"));
}
BENCHMARK(BM_Capture)
    ->Args({1, 1})
    ->Args({2, 1})
    ->Args({1, 0})
    ->Args({2, 0})
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();

// The capture after a pick, as a robot's cycle makes it (binpick bench-cell,
// binpick clear): the top part (the most visible) is taken out, the pile
// resettles, then the capture. A pile left with 5 parts is dropped anew
// (untimed, with its first capture).
void BM_CaptureAfterPick(benchmark::State& state) {
  Cell cell = BenchCell();
  cell.source.simulate_picks = true;
  CaptureRequest r;
  r.config_id = static_cast<int>(state.range(0));
  std::unique_ptr<CaptureSource> source;
  std::optional<Frame> last;
  const auto refill = [&]() -> bool {
    auto s = MakeSyntheticSource(cell);
    if (!s.ok()) return false;
    source = std::move(*s);
    auto f = source->Capture(r);
    if (!f.ok()) return false;
    last = std::move(*f);
    return true;
  };
  if (!refill()) {
    state.SkipWithError("setup failed");
    return;
  }
  for (auto _ : state) {
    if (last->truth->parts.size() <= 5) {
      state.PauseTiming();
      const bool ok = refill();
      state.ResumeTiming();
      if (!ok) {
        state.SkipWithError("refill failed");
        return;
      }
    }
    const auto& parts = last->truth->parts;
    const auto top = std::max_element(parts.begin(), parts.end(), [](const PartTruth& a, const PartTruth& b) {
      return a.visible_pixels < b.visible_pixels;
    });
    source->NotifyPicked(top->instance_id);
    auto f = source->Capture(r);
    if (!f.ok()) {
      state.SkipWithError("capture failed");
      return;
    }
    last = std::move(*f);
  }
  state.SetLabel(r.config_id == 1 ? "640x480" : "1920x1200");
}
BENCHMARK(BM_CaptureAfterPick)
    ->Arg(1)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->MeasureProcessCPUTime()
    ->UseRealTime();

// One scene render (depth + labels + intensity), no noise, no ground truth.
void BM_RenderOnly(benchmark::State& state) {
  const Cell cell = BenchCell();
  auto source = MakeSyntheticSource(cell);
  auto renderer = MakeOsMesaRenderer();
  if (!source.ok() || !renderer.ok()) {
    state.SkipWithError("setup failed");
    return;
  }
  const SyntheticPile& pile = AsSynthetic(*source)->pile();
  RenderScene scene;
  scene.meshes.push_back(std::make_shared<TriangleMesh>(MakeBinMesh(cell.bin)));
  for (const auto& c : pile.classes()) scene.meshes.push_back(c.mesh);
  scene.instances.push_back({0, Pose::Identity(), GroundTruth::kBinLabel});
  for (const auto& p : pile.parts()) {
    scene.instances.push_back({1 + p.class_index, p.X_WO, static_cast<uint16_t>(p.instance_id)});
  }
  const CameraConfig* config = nullptr;
  for (const auto& c : cell.camera.configs) {
    if (c.id == state.range(0)) config = &c;
  }
  const Pose X_WC = cell.bin.X_BW.inverse() * cell.camera.X_BC;
  RenderOutput out;
  for (auto _ : state) {
    benchmark::DoNotOptimize((*renderer)->RenderInto(scene, config->intrinsics, X_WC, out).ok());
  }
  state.SetLabel(state.range(0) == 1 ? "640x480" : "1920x1200");
}
BENCHMARK(BM_RenderOnly)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime();

// The structured-light noise of one capture (grazing dropout, projector
// shadow, axial noise, range) on the scene of BM_RenderOnly: the clean and
// projector renders are made once, outside the loop.
void BM_DepthNoise(benchmark::State& state) {
  const Cell cell = BenchCell();
  auto source = MakeSyntheticSource(cell);
  auto renderer = MakeOsMesaRenderer();
  if (!source.ok() || !renderer.ok()) {
    state.SkipWithError("setup failed");
    return;
  }
  const SyntheticPile& pile = AsSynthetic(*source)->pile();
  RenderScene scene;
  scene.meshes.push_back(std::make_shared<TriangleMesh>(MakeBinMesh(cell.bin)));
  for (const auto& c : pile.classes()) scene.meshes.push_back(c.mesh);
  scene.instances.push_back({0, Pose::Identity(), GroundTruth::kBinLabel});
  for (const auto& p : pile.parts()) {
    scene.instances.push_back({1 + p.class_index, p.X_WO, static_cast<uint16_t>(p.instance_id)});
  }
  const CameraConfig* config = nullptr;
  for (const auto& c : cell.camera.configs) {
    if (c.id == state.range(0)) config = &c;
  }
  const Pose X_WC = cell.bin.X_BW.inverse() * cell.camera.X_BC;
  const Intrinsics& K = config->intrinsics;
  const NoiseModel& noise = config->noise;
  const Intrinsics K_P = internal::ProjectorIntrinsics(K, noise.projector_offset, config->min_depth);
  Pose X_CP = Pose::Identity();
  X_CP.translation() = noise.projector_offset;
  RenderOutput clean, projector;
  if (!(*renderer)->RenderInto(scene, K, X_WC, clean).ok() ||
      !(*renderer)->RenderInto(scene, K_P, X_WC * X_CP, projector).ok()) {
    state.SkipWithError("render failed");
    return;
  }
  internal::NoiseInputs in;
  in.K = &K;
  in.min_depth = config->min_depth;
  in.max_depth = config->max_depth;
  in.projector_depth = &projector.depth;
  in.K_projector = &K_P;
  in.projector_offset = noise.projector_offset;
  DepthImage noisy;
  uint64_t seed = 1;
  for (auto _ : state) {
    internal::ApplyDepthNoise(noise, in, seed++, clean.depth, noisy);
    benchmark::DoNotOptimize(noisy.data.data());
  }
  state.SetLabel(state.range(0) == 1 ? "640x480" : "1920x1200");
}
BENCHMARK(BM_DepthNoise)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime();

}  // namespace
}  // namespace bp
