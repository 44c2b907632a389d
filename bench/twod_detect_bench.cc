// 2D detection cost per top-view image (issue 9): the twod cell (1920 x 1200,
// distortion), 8 flat parts, each pose method. Run:
//   BINPICK_ASSETS=assets build/bin/bp_twod_bench
#include <benchmark/benchmark.h>

#include <cstdlib>

#include "twod/detector_2d.h"
#include "twod/plane_camera.h"

namespace bp {
namespace {

struct Fixture {
  Fixture() {
    cell = LoadCell(AssetsDir() + "/cells/twod.yaml").value();
    camera = std::move(SyntheticPlaneCamera::Create(cell).value());
    // The calibration from the camera's true geometry (the marker grid fit is
    // measured by the tests; here only detection cost matters).
    std::vector<Eigen::Vector2d> pixels, plane;
    for (int iy = 0; iy < 4; ++iy) {
      for (int ix = 0; ix < 5; ++ix) {
        PlaneCaptureRequest r;
        const Eigen::Vector2d xy(0.09 * ix - 0.18, 0.08 * iy - 0.12);
        r.marker_X_PT = MakePose(Mat3::Identity(), Vec3(xy.x(), xy.y(), 0));
        pixels.push_back(FindMarker(camera->Capture(r).value().image).value());
        plane.push_back(xy);
      }
    }
    calibration = FitPlaneCalibration(camera->intrinsics(), pixels, plane).value();
    (void)camera->Scatter(8, 1);
    image = camera->Capture({}).value();
  }
  Cell cell;
  std::unique_ptr<SyntheticPlaneCamera> camera;
  PlaneCalibration calibration;
  PlaneImage image;
};

Fixture& Shared() {
  static Fixture f;
  return f;
}

void BM_Detect2D(benchmark::State& state) {
  Fixture& f = Shared();
  Detector2DOptions o;
  o.method = state.range(0) == 0 ? Match2DMethod::kMoments : Match2DMethod::kRotatedTemplate;
  const Detector2D detector(f.cell, o);
  size_t parts = 0;
  for (auto _ : state) {
    Result<Detect2DResult> r = detector.Detect(f.image.image, f.calibration);
    parts = r.ok() ? r->parts.size() : 0;
    benchmark::DoNotOptimize(parts);
  }
  state.counters["parts"] = static_cast<double>(parts);
  state.SetLabel(state.range(0) == 0 ? "contours+moments" : "rotated template");
}
BENCHMARK(BM_Detect2D)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

void BM_RenderTopView(benchmark::State& state) {
  Fixture& f = Shared();
  for (auto _ : state) benchmark::DoNotOptimize(f.camera->Capture({}));
  state.SetLabel("synthetic 1920x1200, 8 parts, 4x supersampling");
}
BENCHMARK(BM_RenderTopView)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace bp

BENCHMARK_MAIN();
