// The detected parts' surface depth along chosen pixels' rays
// (grasp/internal/surface_depth.h), against the exact ray / triangle z-buffer
// of the pose tests (tests/pipeline/pose_test_util.h) on the cell's own part
// shapes, overlapping in view.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <utility>
#include <vector>

#include "core/mesh_gen.h"
#include "grasp/internal/surface_depth.h"
#include "tests/pipeline/pose_test_util.h"

namespace bp {
namespace {

using testing::DefaultCamera;
using testing::MakeTestBlock;
using testing::Render;
using testing::RenderedScene;
using testing::TestCamera;

TEST(SurfaceDepth, IsTheNearestSurfaceAlongEachWantedPixelsRayAndNothingElsewhere) {
  const TestCamera cam = DefaultCamera();
  const TriangleMesh bushing = MakeFlangedBushing(), bracket = MakeLBracket(), tee = MakePipeTee();
  // Three parts 0.9-0.95 m from the camera, turned, the tee over the bracket's end.
  const std::vector<std::pair<const TriangleMesh*, Pose>> objects = {
      {&bushing, MakePose(Mat3(Eigen::AngleAxisd(0.4, Vec3(1, 1, 0).normalized())), Vec3(-0.05, 0.02, 0.06))},
      {&bracket, MakePose(Mat3(Eigen::AngleAxisd(1.1, Vec3(0.2, 1, 0.3).normalized())), Vec3(0.03, -0.01, 0.05))},
      {&tee, MakePose(Mat3(Eigen::AngleAxisd(2.0, Vec3(0, 0.3, 1).normalized())), Vec3(0.07, 0.0, 0.09))},
  };
  const RenderedScene truth = Render(objects, cam, 0.0, 1);
  std::vector<internal::PlacedMesh> placed;
  for (const auto& [mesh, X_BO] : objects) placed.push_back({mesh, X_BO});
  // A window off the image's corner, every third pixel wanted.
  const int u0 = 200, v0 = 150, width = 260, height = 190;
  std::vector<uint8_t> wanted(static_cast<size_t>(width) * height, 0);
  for (size_t i = 0; i < wanted.size(); i += 3) wanted[i] = 1;
  const std::vector<float> depth =
      internal::NearestSurfaceDepth(cam.K, cam.X_BC, placed, internal::PixelWindow{u0, v0, width, height, wanted});
  ASSERT_EQ(depth.size(), wanted.size());
  int on_parts = 0, edge_disagreements = 0;
  for (int v = 0; v < height; ++v) {
    for (int u = 0; u < width; ++u) {
      const size_t i = static_cast<size_t>(v) * width + u;
      const float expected = truth.depth.at(u0 + u, v0 + v);
      if (!wanted[i]) {
        EXPECT_EQ(depth[i], std::numeric_limits<float>::infinity());
        continue;
      }
      if (std::isfinite(expected) && std::isfinite(depth[i])) {
        ++on_parts;
        EXPECT_NEAR(depth[i], expected, 1e-5) << "pixel " << u0 + u << ", " << v0 + v;
      } else if (std::isfinite(expected) != std::isfinite(depth[i])) {
        ++edge_disagreements;  // a ray through a silhouette's edge, decided differently in rounding
      }
    }
  }
  EXPECT_GT(on_parts, 2000);
  EXPECT_LE(edge_disagreements, on_parts / 500);
}

TEST(SurfaceDepth, BehindTheCameraOrOutsideTheWindowCountsNothing) {
  const TestCamera cam = DefaultCamera();
  const TriangleMesh block = MakeTestBlock();
  // Above the camera (1 m above B, looking down): behind it.
  const internal::PlacedMesh behind{&block, MakePose(Mat3::Identity(), Vec3(0, 0, 1.2))};
  std::vector<uint8_t> wanted(100 * 100, 1);
  const internal::PixelWindow window{270, 190, 100, 100, wanted};
  for (float z : internal::NearestSurfaceDepth(cam.K, cam.X_BC, std::span(&behind, 1), window)) {
    EXPECT_EQ(z, std::numeric_limits<float>::infinity());
  }
  // In front, 0.98 m - 10 mm: its top face at z_C = 0.97 m, but only in view
  // of the window's pixels that it covers.
  const internal::PlacedMesh below{&block, MakePose(Mat3::Identity(), Vec3(0, 0, 0.02))};
  const std::vector<float> depth = internal::NearestSurfaceDepth(cam.K, cam.X_BC, std::span(&below, 1), window);
  int hits = 0;
  for (int v = 0; v < 100; ++v) {
    for (int u = 0; u < 100; ++u) {
      const float z = depth[static_cast<size_t>(v) * 100 + u];
      // 60 x 40 mm at 0.97 m, fx 800: |u - 319.5| <= 24.74, |v - 239.5| <= 16.49
      // (pixel centres are half-integers off the principal point).
      const double du = std::abs(270 + u - 319.5), dv = std::abs(190 + v - 239.5);
      const bool inside = du <= 24.6 && dv <= 16.4;
      const bool outside = du > 24.9 || dv > 16.6;
      if (inside) {
        EXPECT_NEAR(z, 0.97f, 1e-6);
        ++hits;
      } else if (outside) {
        EXPECT_EQ(z, std::numeric_limits<float>::infinity());
      }
    }
  }
  EXPECT_EQ(hits, 50 * 32);
}

}  // namespace
}  // namespace bp
