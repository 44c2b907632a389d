// Frame file IO at the default cell's resolutions: the file source's cost per
// capture (load) and binpick render's cost per frame (write).
#include <cmath>
#include <filesystem>
#include <random>

#include <benchmark/benchmark.h>

#include "pipeline/frame_io.h"

namespace bp {
namespace {

Frame MakeFrame(int width, int height) {
  Frame f;
  f.intrinsics.width = width;
  f.intrinsics.height = height;
  f.intrinsics.fx = f.intrinsics.fy = 1.25 * width;
  f.intrinsics.cx = (width - 1) / 2.0;
  f.intrinsics.cy = (height - 1) / 2.0;
  f.depth = DepthImage(width, height);
  std::mt19937 rng{7};
  std::uniform_real_distribution<float> z(0.8f, 1.05f);
  for (float& d : f.depth.data) d = z(rng);
  return f;
}

std::string Dir() {
  const auto dir = std::filesystem::temp_directory_path() / "binpick_bench";
  std::filesystem::create_directories(dir);
  return dir.string();
}

void BM_WriteDepthPng(benchmark::State& state) {
  const Frame f = MakeFrame(static_cast<int>(state.range(0)), static_cast<int>(state.range(1)));
  const std::string path = Dir() + "/bench_depth.png";
  for (auto _ : state) benchmark::DoNotOptimize(WriteDepthPng(f, path).ok());
}
void BM_LoadDepthPng(benchmark::State& state) {
  const Frame f = MakeFrame(static_cast<int>(state.range(0)), static_cast<int>(state.range(1)));
  const std::string path = Dir() + "/bench_depth.png";
  if (!WriteDepthPng(f, path).ok()) state.SkipWithError("write failed");
  for (auto _ : state) benchmark::DoNotOptimize(LoadFrameFile(path).ok());
}
void BM_WriteCloudPcd(benchmark::State& state) {
  const Frame f = MakeFrame(static_cast<int>(state.range(0)), static_cast<int>(state.range(1)));
  const std::string path = Dir() + "/bench_cloud.pcd";
  for (auto _ : state) benchmark::DoNotOptimize(WriteCloudPcd(f, path).ok());
}
void BM_LoadCloudPcd(benchmark::State& state) {
  const Frame f = MakeFrame(static_cast<int>(state.range(0)), static_cast<int>(state.range(1)));
  const std::string path = Dir() + "/bench_cloud.pcd";
  if (!WriteCloudPcd(f, path).ok()) state.SkipWithError("write failed");
  for (auto _ : state) benchmark::DoNotOptimize(LoadFrameFile(path).ok());
}

BENCHMARK(BM_WriteDepthPng)->Args({640, 480})->Args({1920, 1200})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LoadDepthPng)->Args({640, 480})->Args({1920, 1200})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_WriteCloudPcd)->Args({640, 480})->Args({1920, 1200})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LoadCloudPcd)->Args({640, 480})->Args({1920, 1200})->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace bp
