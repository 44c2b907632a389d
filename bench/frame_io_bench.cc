// Frame file IO at the default cell's resolutions: the file source's cost per
// capture (load, and ProjectCloud for a point list) and binpick render's cost
// per frame (write).
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <string>

#include <benchmark/benchmark.h>

#include "pipeline/cloud_projection.h"
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

// The frame's points as a point list (2.3 M at 1920 x 1200), in C.
Frame Unorganized(const Frame& f) {
  Frame cloud;
  cloud.X_BC = f.X_BC;
  cloud.points_C = f.PointsInCamera();
  return cloud;
}

// A binary PCD point list (x y z float32), as WriteCloudPcd writes one.
void BM_LoadUnorganizedPcd(benchmark::State& state) {
  const Frame f = Unorganized(MakeFrame(static_cast<int>(state.range(0)), static_cast<int>(state.range(1))));
  const std::string path = Dir() + "/bench_points.pcd";
  if (!WriteCloudPcd(f, path).ok()) state.SkipWithError("write failed");
  for (auto _ : state) benchmark::DoNotOptimize(LoadFrameFile(path).ok());
}
// A binary little-endian PLY point list with double x y z (Open3D's default).
void BM_LoadUnorganizedPlyDouble(benchmark::State& state) {
  const Frame f = Unorganized(MakeFrame(static_cast<int>(state.range(0)), static_cast<int>(state.range(1))));
  const std::string path = Dir() + "/bench_points.ply";
  {
    std::ofstream out(path, std::ios::binary);
    out << "ply\nformat binary_little_endian 1.0\nelement vertex " << f.points_C.size()
        << "\nproperty double x\nproperty double y\nproperty double z\nend_header\n";
    for (const Eigen::Vector3f& p : f.points_C) {
      const double xyz[3] = {p.x(), p.y(), p.z()};
      out.write(reinterpret_cast<const char*>(xyz), sizeof(xyz));
    }
  }
  for (auto _ : state) benchmark::DoNotOptimize(LoadFrameFile(path).ok());
}
// ProjectCloud of a camera's point list: the camera config's grid found
// (range(2) = 0), or the same points written in a frame turned 5 deg (1):
// pixels from the point spacing.
void BM_ProjectCloud(benchmark::State& state) {
  static const Cell cell = LoadDefaultCell().value();
  const Frame organized = MakeFrame(static_cast<int>(state.range(0)), static_cast<int>(state.range(1)));
  Frame cloud = Unorganized(organized);
  if (state.range(2) == 1) {
    const Pose X_CF = MakePose(Quat(Eigen::AngleAxisd(5 * M_PI / 180, Vec3(1, 1, 0).normalized())), Vec3::Zero());
    for (Eigen::Vector3f& p : cloud.points_C) p = (X_CF.inverse() * p.cast<double>()).cast<float>();
    cloud.X_BC = cloud.X_BC * X_CF;
  }
  cloud.X_BC = cell.camera.X_BC * cloud.X_BC;
  for (auto _ : state) {
    Result<CloudProjection> p = ProjectCloud(cloud, cell, true);
    if (!p.ok()) state.SkipWithError(p.status().ToString().c_str());
    benchmark::DoNotOptimize(p.ok());
  }
}

BENCHMARK(BM_WriteDepthPng)->Args({640, 480})->Args({1920, 1200})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LoadDepthPng)->Args({640, 480})->Args({1920, 1200})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_WriteCloudPcd)->Args({640, 480})->Args({1920, 1200})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LoadCloudPcd)->Args({640, 480})->Args({1920, 1200})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LoadUnorganizedPcd)->Args({640, 480})->Args({1920, 1200})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LoadUnorganizedPlyDouble)->Args({640, 480})->Args({1920, 1200})->Unit(benchmark::kMillisecond);
BENCHMARK(BM_ProjectCloud)
    ->Args({640, 480, 0})
    ->Args({1920, 1200, 0})
    ->Args({640, 480, 1})
    ->Args({1920, 1200, 1})
    ->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace bp
