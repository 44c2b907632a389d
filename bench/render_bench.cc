// Synthetic capture costs on the default cell (20 parts):
//   ./build/bin/bp_bench --benchmark_filter='Pile|Capture|RenderOnly'
// Part meshes are in-memory stand-ins of the default parts' sizes until the
// shipped meshes load through LoadMesh.
#include <benchmark/benchmark.h>


#include "pipeline/renderer.h"
#include "pipeline/synthetic_source.h"
#include "tests/test_meshes.h"

namespace bp {
namespace {

std::vector<PileClass> StandInClasses() {
  std::vector<PileClass> c(3);
  TriangleMesh bushing = testing::CylinderMesh(0.03f, 0.008f, 64);
  {
    TriangleMesh hub = testing::CylinderMesh(0.018f, 0.04f, 64);
    const int base = static_cast<int>(bushing.vertices.size());
    for (auto v : hub.vertices) bushing.vertices.push_back(v + Eigen::Vector3f(0, 0, 0.02f));
    for (auto t : hub.triangles) bushing.triangles.push_back(t + Eigen::Vector3i::Constant(base));
  }
  TriangleMesh bracket = testing::BoxMesh({0.09f, 0.04f, 0.005f}, {0.045f, 0, 0.0025f});
  testing::AppendBox(bracket, {0.005f, 0.04f, 0.07f}, {0.0025f, 0, 0.035f});
  TriangleMesh tee = testing::CylinderMesh(0.02f, 0.07f, 48);
  c[0] = {0, "flanged_bushing", std::make_shared<TriangleMesh>(bushing)};
  c[1] = {1, "l_bracket", std::make_shared<TriangleMesh>(bracket)};
  c[2] = {2, "pipe_tee", std::make_shared<TriangleMesh>(tee)};
  return c;
}

// The default cell; while its mesh assets are not in the tree (LoadDefaultCell
// checks them), a copy of its camera and bin.
Cell BenchCell() {
  auto loaded = LoadDefaultCell();
  Cell cell;
  if (loaded.ok()) {
    cell = *loaded;
  } else {
    cell.camera.X_BC = MakePose(Eigen::AngleAxisd(M_PI, Vec3::UnitX()).toRotationMatrix(), Vec3(0.7, 0, 1.05));
    for (int id : {1, 2}) {
      CameraConfig c;
      c.id = id;
      c.intrinsics.width = id == 1 ? 640 : 1920;
      c.intrinsics.height = id == 1 ? 480 : 1200;
      c.intrinsics.fx = c.intrinsics.fy = id == 1 ? 800 : 2400;
      c.intrinsics.cx = (c.intrinsics.width - 1) / 2.0;
      c.intrinsics.cy = (c.intrinsics.height - 1) / 2.0;
      c.min_depth = 0.3;
      c.max_depth = 2.0;
      cell.camera.configs.push_back(c);
    }
    cell.bin.inner_size = Vec3(0.5, 0.36, 0.2);
    cell.bin.wall_thickness = 0.012;
    cell.bin.X_BW = MakePose(Mat3::Identity(), Vec3(0.7, 0, 0));
  }
  cell.source.num_parts = 20;
  cell.source.seed = 1;
  return cell;
}

TriangleMesh Bin(const Cell& cell) {
  return testing::OpenBinMesh(cell.bin.inner_size.cast<float>(), static_cast<float>(cell.bin.wall_thickness));
}

void BM_PileGeneration20(benchmark::State& state) {
  const Cell cell = BenchCell();
  const TriangleMesh bin = Bin(cell);
  PileOptions o;
  o.num_parts = 20;
  uint64_t seed = 1;
  for (auto _ : state) {
    o.seed = seed++;
    auto pile = SyntheticPile::Generate(cell.bin, bin, StandInClasses(), o);
    benchmark::DoNotOptimize(pile.ok());
  }
}
BENCHMARK(BM_PileGeneration20)->Unit(benchmark::kMillisecond);

// Full capture: render + projector render + noise + ground truth (solo renders).
void BM_Capture(benchmark::State& state) {
  const Cell cell = BenchCell();
  auto source = SyntheticSource::Create(cell, StandInClasses(), Bin(cell));
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
  auto source = SyntheticSource::Create(cell, StandInClasses(), Bin(cell));
  auto renderer = MakeOsMesaRenderer();
  if (!source.ok() || !renderer.ok()) {
    state.SkipWithError("setup failed");
    return;
  }
  const SyntheticPile& pile = (*source)->pile();
  RenderScene scene;
  scene.meshes.push_back(std::make_shared<TriangleMesh>(Bin(cell)));
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
