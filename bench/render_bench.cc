// Synthetic capture costs on the default cell (20 parts):
//   ./build/bin/bp_bench --benchmark_filter='Pile|Capture|RenderOnly'
#include <benchmark/benchmark.h>

#include <cstdio>
#include <cstdlib>

#include "core/mesh_gen.h"
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

// Full capture: render + projector render + noise + ground truth (solo renders).
void BM_Capture(benchmark::State& state) {
  const Cell cell = BenchCell();
  auto source = MakeSyntheticSource(cell);
  if (!source.ok()) {
    state.SkipWithError(source.status().ToString().c_str());
    return;
  }
  CaptureRequest r;
  r.config_id = static_cast<int>(state.range(0));
  for (auto _ : state) {
    auto f = (*source)->Capture(r);
    benchmark::DoNotOptimize(f.ok());
  }
  state.SetLabel(r.config_id == 1 ? "640x480" : "1920x1200");
}
BENCHMARK(BM_Capture)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);

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
BENCHMARK(BM_RenderOnly)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace bp
