// PointHash::Build on what the pose estimator hashes per estimate: a
// segment's points (a curved patch sampled every 1.3 mm, like the 640x480
// grid on the bin floor) with the support hash's 3 mm cells and the PPF
// voxels' 5 mm cells, and a sparse set with a cell per point.
#include <benchmark/benchmark.h>

#include <cmath>
#include <vector>

#include <Eigen/Core>

#include "pipeline/internal/point_hash.h"

namespace bp {
namespace {

std::vector<Eigen::Vector3f> Patch(int n_side, float pitch) {
  std::vector<Eigen::Vector3f> p;
  for (int y = 0; y < n_side; ++y) {
    for (int x = 0; x < n_side; ++x) {
      const float u = pitch * static_cast<float>(x), v = pitch * static_cast<float>(y);
      p.emplace_back(u, v, 0.01f * std::sin(20.f * u) * std::cos(15.f * v));
    }
  }
  return p;
}

// Args: points per side (n^2 points), cell in micrometres.
void BM_PointHashBuild(benchmark::State& state) {
  const int side = static_cast<int>(state.range(0));
  const float cell = static_cast<float>(state.range(1)) * 1e-6f;
  const std::vector<Eigen::Vector3f> pts = Patch(side, 0.0013f);
  internal::PointHash hash;
  for (auto _ : state) {
    hash.Build(pts, cell);
    benchmark::DoNotOptimize(hash.size());
  }
  state.counters["points"] = static_cast<double>(pts.size());
}
BENCHMARK(BM_PointHashBuild)
    ->ArgsProduct({{40, 70}, {3000, 5000}})
    ->Args({70, 1000})  // every point in a cell of its own
    ->Unit(benchmark::kMicrosecond);

}  // namespace
}  // namespace bp
