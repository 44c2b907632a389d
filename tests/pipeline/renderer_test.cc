#include "pipeline/renderer.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <set>

#include "tests/test_meshes.h"

namespace bp {
namespace {

Intrinsics SmallK() {
  Intrinsics K;
  K.width = 320;
  K.height = 240;
  K.fx = 300;
  K.fy = 310;
  K.cx = 150.25;
  K.cy = 110.75;
  return K;
}

std::unique_ptr<DepthRenderer> Renderer() {
  auto r = MakeOsMesaRenderer();
  EXPECT_TRUE(r.ok()) << r.status().ToString();
  return r.ok() ? std::move(*r) : nullptr;
}

Pose At(double x, double y, double z) { return MakePose(Mat3::Identity(), Vec3(x, y, z)); }

// A box whose front face (facing the camera at the origin, looking along +z)
// is the rectangle [x0, x1] x [y0, y1] at depth z0.
TEST(OsMesaRenderer, FrontFaceCoversExactlyThePredictedPixelsAtThePredictedDepth) {
  auto renderer = Renderer();
  ASSERT_TRUE(renderer);
  const Intrinsics K = SmallK();
  const double x0 = -0.083, x1 = 0.121, y0 = -0.0712, y1 = 0.0331, z0 = 0.8;
  RenderScene scene;
  scene.meshes.push_back(
      std::make_shared<TriangleMesh>(testing::BoxMesh({float(x1 - x0), float(y1 - y0), 0.05f})));
  scene.instances.push_back({0, At((x0 + x1) / 2, (y0 + y1) / 2, z0 + 0.025), 7});
  auto out = renderer->Render(scene, K, Pose::Identity());
  ASSERT_TRUE(out.ok()) << out.status().ToString();
  const double u0 = K.fx * x0 / z0 + K.cx, u1 = K.fx * x1 / z0 + K.cx;
  const double v0 = K.fy * y0 / z0 + K.cy, v1 = K.fy * y1 / z0 + K.cy;
  int covered = 0;
  for (int v = 0; v < K.height; ++v) {
    for (int u = 0; u < K.width; ++u) {
      // Keep clear of pixel centres lying on an edge (rasterization tie rules).
      ASSERT_GT(std::min({std::abs(u - u0), std::abs(u - u1), std::abs(v - v0), std::abs(v - v1)}),
                0.01);
      const bool inside = u > u0 && u < u1 && v > v0 && v < v1;
      ASSERT_EQ(out->labels.at(u, v), inside ? 7 : 0) << u << "," << v;
      if (inside) {
        ++covered;
        EXPECT_NEAR(out->depth.at(u, v), z0, 1e-4);
        EXPECT_GT(out->intensity.at(u, v), 200);  // facing the light
      } else {
        EXPECT_TRUE(std::isnan(out->depth.at(u, v)));
      }
    }
  }
  EXPECT_GT(covered, 1000);
}

// Camera looking straight down from above a box: every pixel's ray is
// intersected with the top face analytically.
TEST(OsMesaRenderer, DownLookingCameraSeesTheTopFaceWhereRaysHitIt) {
  auto renderer = Renderer();
  ASSERT_TRUE(renderer);
  const Intrinsics K = SmallK();
  Pose X_WC = MakePose(Eigen::AngleAxisd(M_PI, Vec3::UnitX()).toRotationMatrix(),
                       Vec3(0.013, -0.021, 1.05));
  // Slight tilt so that the test does not rely on axis alignment.
  X_WC.linear() =
      X_WC.linear() * Eigen::AngleAxisd(0.1, Vec3(0.3, 1, 0).normalized()).toRotationMatrix();
  const Vec3 size(0.16, 0.1, 0.05);
  Pose X_WO = At(0.02, 0.01, size.z() / 2);
  X_WO.linear() = Eigen::AngleAxisd(0.4, Vec3::UnitZ()).toRotationMatrix();
  RenderScene scene;
  scene.meshes.push_back(std::make_shared<TriangleMesh>(testing::BoxMesh(size.cast<float>())));
  scene.instances.push_back({0, X_WO, 3});
  auto out = renderer->Render(scene, K, X_WC);
  ASSERT_TRUE(out.ok());
  int checked = 0;
  for (int v = 0; v < K.height; v += 2) {
    for (int u = 0; u < K.width; u += 2) {
      const Vec3 ray_C((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
      const Vec3 o_W = X_WC.translation(), d_W = X_WC.linear() * ray_C;
      const double s = (size.z() - o_W.z()) / d_W.z();  // ray parameter = depth z in C
      const Vec3 p_O = X_WO.inverse() * (o_W + s * d_W);
      // Distance to the top face's boundary in pixels (footprint s / fx).
      const double margin =
          std::min(size.x() / 2 - std::abs(p_O.x()), size.y() / 2 - std::abs(p_O.y()));
      const double margin_px = margin * K.fx / s;
      if (std::abs(margin_px) < 0.5) continue;
      if (margin_px > 0) {
        ASSERT_EQ(out->labels.at(u, v), 3) << u << "," << v;
        EXPECT_NEAR(out->depth.at(u, v), s, 1e-4);
        ++checked;
      }
    }
  }
  EXPECT_GT(checked, 200);
}

TEST(OsMesaRenderer, LabelsAreExactAndTheNearestSurfaceWins) {
  auto renderer = Renderer();
  ASSERT_TRUE(renderer);
  const Intrinsics K = SmallK();
  RenderScene scene;
  scene.meshes.push_back(std::make_shared<TriangleMesh>(testing::BoxMesh({0.04f, 0.04f, 0.04f})));
  const uint16_t labels[] = {1, 254, 255, 256, 0x1234, 0xABCD, 0xFFFE, 0xFFFF};
  for (int i = 0; i < 8; ++i)
    scene.instances.push_back({0, At(-0.28 + 0.08 * i, 0, 1.0), labels[i]});
  // A nearer box in front of the first two.
  scene.instances.push_back({0, At(-0.24, 0.0, 0.7), 99});
  auto out = renderer->Render(scene, K, Pose::Identity());
  ASSERT_TRUE(out.ok());
  for (int i = 2; i < 8; ++i) {
    const int u = static_cast<int>(std::lround(K.fx * (-0.28 + 0.08 * i) / 1.0 + K.cx));
    const int v = static_cast<int>(std::lround(K.cy));
    EXPECT_EQ(out->labels.at(u, v), labels[i]) << i;
  }
  const int u_near = static_cast<int>(std::lround(K.fx * -0.24 / 0.7 + K.cx));
  EXPECT_EQ(out->labels.at(u_near, static_cast<int>(K.cy)), 99);
  EXPECT_NEAR(out->depth.at(u_near, static_cast<int>(K.cy)), 0.68, 1e-4);
  std::set<uint16_t> seen(out->labels.data.begin(), out->labels.data.end());
  for (uint16_t l : seen) {
    EXPECT_TRUE(l == 0 || l == 99 || std::count(std::begin(labels), std::end(labels), l)) << l;
  }
}

TEST(OsMesaRenderer, TiltedSurfacesAreDarkerThanFacingOnes) {
  auto renderer = Renderer();
  ASSERT_TRUE(renderer);
  const Intrinsics K = SmallK();
  RenderScene scene;
  scene.meshes.push_back(std::make_shared<TriangleMesh>(testing::BoxMesh({0.1f, 0.1f, 0.01f})));
  scene.instances.push_back({0, At(-0.1, 0, 1.0), 1});
  Pose tilted = At(0.1, 0, 1.0);
  tilted.linear() = Eigen::AngleAxisd(1.2, Vec3::UnitY()).toRotationMatrix();
  scene.instances.push_back({0, tilted, 2});
  auto out = renderer->Render(scene, K, Pose::Identity());
  ASSERT_TRUE(out.ok());
  const int v = static_cast<int>(K.cy);
  const int ua = static_cast<int>(std::lround(K.fx * -0.1 + K.cx));
  const int ub = static_cast<int>(std::lround(K.fx * 0.1 + K.cx));
  ASSERT_EQ(out->labels.at(ua, v), 1);
  ASSERT_EQ(out->labels.at(ub, v), 2);
  EXPECT_GT(out->intensity.at(ua, v), out->intensity.at(ub, v) + 50);
  EXPECT_GT(out->intensity.at(ub, v), 0);
}

// A region rendered into an image of another scene: inside, the bytes of a
// render of the whole image; outside, the old image untouched. Tilted boxes
// with edges crossing the region's border, labels in depth ties.
TEST(OsMesaRenderer, ARegionGetsTheBytesOfAWholeRenderAndLeavesTheRestAlone) {
  auto renderer = Renderer();
  ASSERT_TRUE(renderer);
  const Intrinsics K = SmallK();
  RenderScene before, after;
  before.meshes.push_back(std::make_shared<TriangleMesh>(testing::BoxMesh({0.06f, 0.05f, 0.04f})));
  after.meshes = before.meshes;
  for (int i = 0; i < 12; ++i) {
    Pose p = At(-0.3 + 0.055 * i, 0.03 * (i % 3) - 0.03, 0.9 + 0.01 * (i % 4));
    p.linear() = Eigen::AngleAxisd(0.3 * i, Vec3(1, 0.5 * i, 0.2).normalized()).toRotationMatrix();
    before.instances.push_back({0, p, static_cast<uint16_t>(i + 1)});
    p.translation().z() += i % 2 ? 0.02 : -0.015;  // every part moved, same labels
    after.instances.push_back({0, p, static_cast<uint16_t>(i + 1)});
  }
  after.instances.push_back({0, At(0.0, 0.0, 0.9), 7});  // a duplicate tie at the same place as part 7's: first drawn wins
  auto whole = renderer->Render(after, K, Pose::Identity());
  auto old = renderer->Render(before, K, Pose::Identity());
  ASSERT_TRUE(whole.ok() && old.ok());
  for (const PixelRect region : {PixelRect{37, 21, 203, 170}, PixelRect{0, 0, K.width - 1, K.height - 1},
                                 PixelRect{-20, 100, 40, 400}, PixelRect{150, 110, 150, 110}}) {
    RenderOutput out = *old;
    ASSERT_TRUE(renderer->RenderRegion(after, K, Pose::Identity(), region, out).ok());
    int inside = 0, differs_from_old = 0;
    for (int v = 0; v < K.height; ++v) {
      for (int u = 0; u < K.width; ++u) {
        const bool in = u >= region.u0 && u <= region.u1 && v >= region.v0 && v <= region.v1;
        const RenderOutput& want = in ? *whole : *old;
        inside += in;
        differs_from_old += in && std::memcmp(&whole->depth.at(u, v), &old->depth.at(u, v), sizeof(float)) != 0;
        ASSERT_EQ(std::memcmp(&out.depth.at(u, v), &want.depth.at(u, v), sizeof(float)), 0) << u << "," << v;
        ASSERT_EQ(out.labels.at(u, v), want.labels.at(u, v)) << u << "," << v;
        ASSERT_EQ(out.intensity.at(u, v), want.intensity.at(u, v)) << u << "," << v;
      }
    }
    EXPECT_GT(inside, 0);
    if (region.area() > 20000) {
      EXPECT_GT(differs_from_old, 1000) << "the scenes hardly differ in the region";
    }
  }
  RenderOutput wrong_size;
  EXPECT_FALSE(renderer->RenderRegion(after, K, Pose::Identity(), PixelRect{0, 0, 10, 10}, wrong_size).ok());
}

TEST(OsMesaRenderer, RejectsBadInput) {
  auto renderer = Renderer();
  ASSERT_TRUE(renderer);
  RenderScene scene;
  EXPECT_FALSE(renderer->Render(scene, Intrinsics{}, Pose::Identity()).ok());
  scene.instances.push_back({3, Pose::Identity(), 1});
  EXPECT_FALSE(renderer->Render(scene, SmallK(), Pose::Identity()).ok());
}

}  // namespace
}  // namespace bp
