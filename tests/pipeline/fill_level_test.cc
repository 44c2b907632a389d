// The fill level of a bin from its ROI points (issue 41 item 2).
#include "pipeline/fill_level.h"

#include <gtest/gtest.h>

#include <limits>
#include <vector>

namespace bp {
namespace {

// Points on a grid every `step` over the rectangle |x| <= hx, |y| <= hy of
// the bin frame at height z, in B through X_BW.
std::vector<Eigen::Vector3f> Slab(const Pose& X_BW, double hx, double hy, double z, double step = 0.002) {
  std::vector<Eigen::Vector3f> out;
  for (double x = -hx; x <= hx; x += step) {
    for (double y = -hy; y <= hy; y += step) out.push_back((X_BW * Vec3(x, y, z)).cast<float>());
  }
  return out;
}

TEST(FillLevel, AnEmptyFloorIsEmptyAndALayerCoveringHalfOfItIsHalfFull) {
  const Pose X_BW = MakePose(Mat3(Eigen::AngleAxisd(0.3, Vec3::UnitZ())), Vec3(0.7, -0.1, 0.05));
  const Eigen::Vector2d half(0.2, 0.1);
  const FillLevel empty = MeasureFillLevel({}, X_BW, half);
  EXPECT_EQ(empty.cells, 40 * 20);
  EXPECT_EQ(empty.mean_height, 0.0);
  EXPECT_EQ(empty.max_height, 0.0);
  EXPECT_EQ(empty.occupied_fraction, 0.0);
  // Floor noise below the occupied height does not count as parts.
  const FillLevel floor = MeasureFillLevel(Slab(X_BW, 0.2, 0.1, 0.003), X_BW, half);
  EXPECT_EQ(floor.occupied_fraction, 0.0);
  // A 50 mm layer over the half x < 0: half the floor at 50 mm.
  std::vector<Eigen::Vector3f> layer;
  for (const Eigen::Vector3f& p : Slab(X_BW, 0.2, 0.1, 0.05)) {
    if ((X_BW.inverse() * p.cast<double>()).x() < -0.0005) layer.push_back(p);
  }
  const FillLevel half_full = MeasureFillLevel(layer, X_BW, half);
  EXPECT_NEAR(half_full.occupied_fraction, 0.5, 0.03);
  EXPECT_NEAR(half_full.mean_height, 0.025, 0.002);
  EXPECT_NEAR(half_full.max_height, 0.05, 1e-6);
}

TEST(FillLevel, PointsOutsideTheFloorAndNaNsAreIgnored) {
  const Pose X_BW = Pose::Identity();
  std::vector<Eigen::Vector3f> points = {Eigen::Vector3f(0.5f, 0.0f, 0.2f),  // beyond the wall
                                         Eigen::Vector3f(std::numeric_limits<float>::quiet_NaN(), 0.0f, 0.2f)};
  const FillLevel fill = MeasureFillLevel(points, X_BW, Eigen::Vector2d(0.2, 0.1));
  EXPECT_EQ(fill.max_height, 0.0);
  EXPECT_EQ(fill.occupied_fraction, 0.0);
  // A bin pose moved by 0.3 m in x puts the same point over its floor.
  const Pose moved = MakePose(Mat3::Identity(), Vec3(0.35, 0.0, 0.0));
  EXPECT_NEAR(MeasureFillLevel(points, moved, Eigen::Vector2d(0.2, 0.1)).max_height, 0.2, 1e-6);
}

}  // namespace
}  // namespace bp
