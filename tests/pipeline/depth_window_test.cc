// The depth-image window test of verification against brute force: it may
// answer "maybe" too often, never "no" when a point of the image lies within
// the radius (the verification's support counts rely on it), and the pixel
// rounding matches std::lround.
#include "pipeline/internal/depth_window.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

namespace bp::internal {
namespace {

TEST(DepthWindow, RoundToIntMatchesLround) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> x(-3000.0, 3000.0);
  std::vector<double> values = {0.0, 0.5, -0.5, 1.5, -1.5, 2.4999999999, 639.5, -0.49999999, 1e9, -1e9};
  for (int i = 0; i < 20000; ++i) values.push_back(i % 4 == 0 ? std::round(x(rng)) + 0.5 : x(rng));
  for (double v : values) {
    int r = 0;
    ASSERT_TRUE(RoundToInt(v, &r)) << v;
    EXPECT_EQ(r, std::lround(v)) << v;
  }
  int r = 0;
  EXPECT_FALSE(RoundToInt(std::numeric_limits<double>::quiet_NaN(), &r));
  EXPECT_FALSE(RoundToInt(3e9, &r));
  EXPECT_FALSE(RoundToInt(-std::numeric_limits<double>::infinity(), &r));
}

TEST(DepthWindow, NeverRulesOutAPointOfTheImageWithinTheRadius) {
  // A 1 m deep scene of steps and slopes with holes, deprojected as the ROI
  // crop does (float), then queries near its points and in free space.
  Intrinsics K;
  K.width = 80, K.height = 60, K.fx = 570.0, K.fy = 571.0, K.cx = 39.5, K.cy = 29.5;
  DepthImage depth;
  depth.width = K.width, depth.height = K.height;
  depth.data.assign(static_cast<size_t>(K.width) * K.height, 0.f);
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> noise(-0.0005f, 0.0005f);
  for (int v = 0; v < K.height; ++v) {
    for (int u = 0; u < K.width; ++u) {
      float z = 1.0f + (u > 40 ? 0.02f : 0.f) + 0.0004f * static_cast<float>(v) + noise(rng);
      if ((u * 7 + v * 3) % 23 == 0) z = std::numeric_limits<float>::quiet_NaN();
      depth.at(u, v) = z;
    }
  }
  std::vector<Eigen::Vector3f> points;  // in C, each on its pixel
  for (int v = 0; v < K.height; ++v) {
    for (int u = 0; u < K.width; ++u) {
      const float z = depth.at(u, v);
      if (!std::isfinite(z)) continue;
      points.emplace_back(static_cast<float>((u - K.cx) / K.fx) * z, static_cast<float>((v - K.cy) / K.fy) * z, z);
      ASSERT_TRUE(OnItsPixel(K, depth, points.back(), OnPixelTolerance{})) << u << ", " << v;
    }
  }
  // Off its pixel's centre, off its depth, or on no measurement: not on its pixel.
  const Eigen::Vector3f& first = points.front();
  EXPECT_FALSE(OnItsPixel(K, depth, first + Eigen::Vector3f(0.1f * first.z() / 570.f, 0.f, 0.f), OnPixelTolerance{}));
  EXPECT_FALSE(OnItsPixel(K, depth, first * 1.001f, OnPixelTolerance{}));
  EXPECT_FALSE(OnItsPixel(K, depth, Eigen::Vector3f(0.f, 0.f, -1.f), OnPixelTolerance{}));
  constexpr float kRadius = 0.0015f;
  const OnPixelTolerance tol;
  std::uniform_int_distribution<size_t> pick(0, points.size() - 1);
  std::uniform_real_distribution<float> offset(-0.003f, 0.003f);
  int checked = 0, near = 0, ruled_out = 0, wide = 0;
  for (int q = 0; q < 20000; ++q) {
    const Eigen::Vector3f p = points[pick(rng)] + Eigen::Vector3f(offset(rng), offset(rng), 4.f * offset(rng));
    int u = 0, v = 0;
    if (!PixelOf(K, depth, p, &u, &v)) continue;
    ++checked;
    bool any = false;
    for (const Eigen::Vector3f& s : points) any |= (s - p).squaredNorm() <= kRadius * kRadius;
    const bool maybe = DepthWindowMayHoldPointNear(depth, K, p, u, v, kRadius, tol, 3);
    if (any) {
      ++near;
      ASSERT_TRUE(maybe) << "query " << q << " at (" << u << ", " << v << ") depth " << p.z();
    } else if (!maybe) {
      ++ruled_out;
    }
    wide += DepthWindowMayHoldPointNear(depth, K, p, u, v, kRadius, tol, 0) ? 1 : 0;
  }
  // Both answers occur: the test is not vacuous, and the window saves work.
  EXPECT_GT(near, 1000);
  EXPECT_GT(ruled_out, 1000);
  // A window allowed no width at all cannot decide: always "maybe".
  EXPECT_EQ(wide, checked);
}

}  // namespace
}  // namespace bp::internal
