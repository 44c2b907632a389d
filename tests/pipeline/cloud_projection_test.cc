// Unorganized clouds seen through a virtual pinhole (pipeline/cloud_projection.h):
// the grid a cloud deprojected from a pinhole came from is found again,
// exactly; a cloud off any lattice gets square pixels without grid holes; the
// view without X_BC is the one from above the bin.
#include "pipeline/cloud_projection.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include <gmock/gmock.h>
#include <gtest/gtest.h>

namespace bp {
namespace {

using ::testing::HasSubstr;

const Cell& DefaultCell() {
  static const Cell cell = LoadDefaultCell().value();
  return cell;
}

// A camera's frame of the bin floor 1.05 m away with a 10 cm box on it
// (depth in metres, NaN on a few pixels), seeded noise of 0.3 mm.
Frame FloorWithBox(const Intrinsics& K, const Pose& X_BC, uint32_t seed = 3) {
  std::mt19937 rng{seed};
  std::normal_distribution<float> noise(0.f, 0.0003f);
  Frame f;
  f.intrinsics = K;
  f.X_BC = X_BC;
  f.source = "floor_with_box";
  f.depth = DepthImage(K.width, K.height, std::numeric_limits<float>::quiet_NaN());
  for (int v = 0; v < K.height; ++v) {
    for (int u = 0; u < K.width; ++u) {
      if ((u * 7 + v * 13) % 97 == 0) continue;  // dropouts
      const bool box = std::abs(u - K.width / 2) < K.width / 8 && std::abs(v - K.height / 2) < K.height / 8;
      f.depth.at(u, v) = (box ? 0.95f : 1.05f) + noise(rng);
    }
  }
  return f;
}

// The frame's valid points as an unorganized cloud, in a seeded random order.
Frame Unorganized(const Frame& organized, uint32_t seed = 5) {
  Frame cloud;
  cloud.X_BC = organized.X_BC;
  cloud.source = organized.source;
  cloud.points_C = organized.PointsInCamera();
  std::mt19937 rng{seed};
  std::shuffle(cloud.points_C.begin(), cloud.points_C.end(), rng);
  return cloud;
}

// Every source point is within tol of its pixel's point in the projection
// (a cloud on a lattice: one point per pixel).
void ExpectEveryPointOnItsPixel(const Frame& cloud, const CloudProjection& p, float tol) {
  const Frame& f = p.frame;
  const Pose X_VC = f.X_BC.inverse() * cloud.X_BC;
  for (const Eigen::Vector3f& p_C : cloud.points_C) {
    const Eigen::Vector3f p_V = (X_VC * p_C.cast<double>()).cast<float>();
    const long u = std::lround(f.intrinsics.fx * p_V.x() / p_V.z() + f.intrinsics.cx);
    const long v = std::lround(f.intrinsics.fy * p_V.y() / p_V.z() + f.intrinsics.cy);
    ASSERT_TRUE(u >= 0 && v >= 0 && u < f.depth.width && v < f.depth.height);
    const float z = f.depth.at(static_cast<int>(u), static_cast<int>(v));
    const Eigen::Vector3f q = Deproject(f.intrinsics, static_cast<float>(u), static_cast<float>(v), z);
    ASSERT_LE((q - p_V).norm(), tol) << u << "," << v;
  }
}

// Each pixel's depth is the smallest depth (in V) of the points whose rays
// round to it, and empty where none does: the z-buffer, computed here in
// double.
void ExpectNearestPointDepths(const Frame& cloud, const CloudProjection& p) {
  const Frame& f = p.frame;
  const Pose X_VC = f.X_BC.inverse() * cloud.X_BC;
  std::vector<double> nearest(f.depth.data.size(), std::numeric_limits<double>::infinity());
  for (const Eigen::Vector3f& p_C : cloud.points_C) {
    const Vec3 p_V = X_VC * p_C.cast<double>();
    const long u = std::lround(f.intrinsics.fx * p_V.x() / p_V.z() + f.intrinsics.cx);
    const long v = std::lround(f.intrinsics.fy * p_V.y() / p_V.z() + f.intrinsics.cy);
    ASSERT_TRUE(u >= 0 && v >= 0 && u < f.depth.width && v < f.depth.height);
    double& z = nearest[static_cast<size_t>(v * f.depth.width + u)];
    z = std::min(z, p_V.z());
  }
  for (size_t i = 0; i < nearest.size(); ++i) {
    if (std::isinf(nearest[i])) {
      ASSERT_TRUE(std::isnan(f.depth.data[i])) << i;
    } else {
      ASSERT_NEAR(f.depth.data[i], nearest[i], 1e-6) << i;
    }
  }
}

// Holes between two filled pixels of the floor (deeper than 1 m) in a row,
// and the filled pixels counted alike.
std::pair<int, int> FloorHolesAndFilled(const DepthImage& D) {
  int holes = 0, filled = 0;
  for (int v = 0; v < D.height; ++v) {
    for (int u = 1; u + 1 < D.width; ++u) {
      const bool left = std::isfinite(D.at(u - 1, v)) && D.at(u - 1, v) > 1.f;
      const bool right = std::isfinite(D.at(u + 1, v)) && D.at(u + 1, v) > 1.f;
      if (!left || !right) continue;
      ++(std::isfinite(D.at(u, v)) ? filled : holes);
    }
  }
  return {holes, filled};
}

// The points camera Ck (at X_C0Ck from camera C0) sees of a floor 1.05 m
// below C0 with a box top at 0.95 m, in C0, with seeded noise.
std::vector<Eigen::Vector3f> FloorSeenFrom(const Intrinsics& K, const Pose& X_C0Ck, uint32_t seed) {
  std::mt19937 rng{seed};
  std::normal_distribution<double> noise(0.0, 0.0003);
  std::vector<Eigen::Vector3f> points;
  const Vec3 o = X_C0Ck.translation();
  for (int v = 0; v < K.height; ++v) {
    for (int u = 0; u < K.width; ++u) {
      const Vec3 d = X_C0Ck.linear() * Vec3((u - K.cx) / K.fx, (v - K.cy) / K.fy, 1.0);
      Vec3 p = o + d * ((1.05 - o.z()) / d.z());
      if (std::abs(p.x()) < 0.08 && std::abs(p.y()) < 0.06) p = o + d * ((0.95 - o.z()) / d.z());
      points.push_back((p + d.normalized() * noise(rng)).cast<float>());
    }
  }
  return points;
}

TEST(ProjectCloud, ACloudFromACellCameraGetsThatCamerasGridAndItsDepthsBitForBit) {
  const Cell& cell = DefaultCell();
  const CameraConfig& vga = *cell.camera.FindConfig(1);
  const Frame organized = FloorWithBox(vga.intrinsics, cell.camera.X_BC);
  Result<CloudProjection> p = ProjectCloud(Unorganized(organized), cell, /*X_BC_known=*/true);
  ASSERT_TRUE(p.ok()) << p.status().ToString();
  EXPECT_EQ(p->grid, CloudGrid::kCameraConfig);
  EXPECT_EQ(p->config_id, 1);
  EXPECT_EQ(p->view, CloudViewSource::kCamera);
  EXPECT_THAT(p->Describe(), HasSubstr("camera config 1"));
  const Intrinsics& K = p->frame.intrinsics;
  EXPECT_EQ(K.width, 640);
  EXPECT_EQ(K.fx, vga.intrinsics.fx);
  EXPECT_EQ(K.cx, vga.intrinsics.cx);
  EXPECT_TRUE(p->frame.X_BC.matrix() == organized.X_BC.matrix());
  ASSERT_EQ(p->frame.depth.data.size(), organized.depth.data.size());
  for (size_t i = 0; i < organized.depth.data.size(); ++i) {
    const float a = organized.depth.data[i], b = p->frame.depth.data[i];
    ASSERT_TRUE(a == b || (std::isnan(a) && std::isnan(b))) << i;
  }
  EXPECT_EQ(p->points, p->pixels);
}

TEST(ProjectCloud, RecoversThePinholeLatticeOfACameraTheCellDoesNotKnow) {
  Intrinsics K;
  K.width = 300;
  K.height = 220;
  K.fx = 612.37;
  K.fy = 611.9;
  K.cx = 151.25;
  K.cy = 103.7;
  const Frame organized = FloorWithBox(K, DefaultCell().camera.X_BC);
  // A region of it only, as a viewer exports a region of interest.
  Frame cloud = Unorganized(organized);
  cloud.points_C.erase(std::remove_if(cloud.points_C.begin(), cloud.points_C.end(),
                                      [](const Eigen::Vector3f& p) { return p.x() / p.z() < -0.1; }),
                       cloud.points_C.end());
  Result<CloudProjection> p = ProjectCloud(cloud, DefaultCell(), true);
  ASSERT_TRUE(p.ok()) << p.status().ToString();
  EXPECT_EQ(p->grid, CloudGrid::kRecovered);
  EXPECT_NEAR(p->frame.intrinsics.fx, K.fx, 1e-6 * K.fx);
  EXPECT_NEAR(p->frame.intrinsics.fy, K.fy, 1e-6 * K.fy);
  EXPECT_LT(p->max_shift_px, 0.001);
  EXPECT_EQ(p->points, p->pixels);
  ExpectEveryPointOnItsPixel(cloud, *p, 2e-6f);
}

// Property: the grid does not depend on the order or the subset of the points.
TEST(ProjectCloud, TheRecoveredGridIsTheSameForAnyOrderAndHalfOfThePoints) {
  Intrinsics K;
  K.width = 160;
  K.height = 120;
  K.fx = K.fy = 203.1;
  K.cx = 80.4;
  K.cy = 59.9;
  const Frame organized = FloorWithBox(K, DefaultCell().camera.X_BC);
  std::mt19937 rng{7};
  for (uint32_t trial = 0; trial < 10; ++trial) {
    Frame cloud = Unorganized(organized, trial);
    cloud.points_C.resize(cloud.points_C.size() / 2 + trial * 100);
    Result<CloudProjection> p = ProjectCloud(cloud, DefaultCell(), true);
    ASSERT_TRUE(p.ok()) << p.status().ToString();
    ASSERT_EQ(p->grid, CloudGrid::kRecovered) << trial;
    // The same pixel pitch and the same pixel centres (cx modulo whole pixels).
    EXPECT_NEAR(p->frame.intrinsics.fx, K.fx, 1e-6 * K.fx) << trial;
    const double offset = p->frame.intrinsics.cx - K.cx;
    EXPECT_NEAR(offset, std::round(offset), 1e-4) << trial;
    ExpectEveryPointOnItsPixel(cloud, *p, 2e-6f);
  }
}

// A camera's cloud written in a frame F turned 5 degrees from it: no pixel
// lattice through F. The pixel is a little wider than the points' spacing,
// so the floor has no holes beyond the camera's own dropouts.
TEST(ProjectCloud, ACloudOffAnyLatticeGetsSquarePixelsAndKeepsItsSurfacesWhole) {
  const Cell& cell = DefaultCell();
  const Intrinsics& K = cell.camera.FindConfig(1)->intrinsics;
  const Frame organized = FloorWithBox(K, cell.camera.X_BC);
  const Pose X_CF = MakePose(Quat(Eigen::AngleAxisd(5 * M_PI / 180, Vec3(1, 1, 0).normalized())), Vec3(0.01, -0.02, 0));
  Frame cloud = Unorganized(organized);
  for (Eigen::Vector3f& p : cloud.points_C) p = (X_CF.inverse() * p.cast<double>()).cast<float>();
  cloud.X_BC = cloud.X_BC * X_CF;
  Result<CloudProjection> p = ProjectCloud(cloud, cell, true);
  ASSERT_TRUE(p.ok()) << p.status().ToString();
  EXPECT_EQ(p->grid, CloudGrid::kFromSpacing);
  EXPECT_EQ(p->view, CloudViewSource::kCamera);
  const Intrinsics& V = p->frame.intrinsics;
  EXPECT_EQ(V.fx, V.fy);
  // The camera's pitch is 1 / 800; the virtual one a little wider.
  EXPECT_GT(1.0 / V.fx, 1.0 / K.fx);
  EXPECT_LT(1.0 / V.fx, 1.25 / K.fx);
  EXPECT_LE(p->max_shift_px, std::sqrt(0.5) + 1e-9);
  EXPECT_GT(p->pixels, p->points * 3 / 4);
  EXPECT_THAT(p->Describe(), HasSubstr("no pixel lattice"));
  // Each point moved sideways to its pixel's ray, its depth kept; the nearest wins.
  ExpectNearestPointDepths(cloud, *p);
  // The floor's interior: few empty pixels between two filled ones in a
  // row, about the camera's own 1-in-97 dropouts.
  const auto [holes, filled] = FloorHolesAndFilled(p->frame.depth);
  EXPECT_LT(holes, filled / 50);
}

// Three cameras' clouds of one scene merged: the points bunch, and their
// 95th percentile spacing is below any one camera's pitch; the finer grid
// keeps the floor mostly whole (perception found as many parts in such
// clouds as in the depth images: docs/tuning.md, "Unorganized clouds").
TEST(ProjectCloud, ThreeOverlappingCamerasCloudsGetAFinerGridThatKeepsTheFloorWhole) {
  const Cell& cell = DefaultCell();
  const Intrinsics& K = cell.camera.FindConfig(1)->intrinsics;
  Frame merged;
  merged.X_BC = cell.camera.X_BC;
  for (int k = 0; k < 3; ++k) {
    const Pose X_C0Ck = MakePose(Quat(Eigen::AngleAxisd(0.02 * k, Vec3(1, 2, 0).normalized())),
                                 Vec3(0.004 * k, -0.003 * k, 0.0));
    for (const Eigen::Vector3f& p : FloorSeenFrom(K, X_C0Ck, 10 + k)) merged.points_C.push_back(p);
  }
  Result<CloudProjection> p = ProjectCloud(merged, cell, true);
  ASSERT_TRUE(p.ok()) << p.status().ToString();
  ASSERT_EQ(p->grid, CloudGrid::kFromSpacing);
  EXPECT_GT(p->frame.intrinsics.fx, K.fx);
  const auto [holes, filled] = FloorHolesAndFilled(p->frame.depth);
  EXPECT_GT(filled, 300000) << p->Describe();
  EXPECT_LT(holes, filled / 10) << p->Describe();
}

// Every point written twice, 1/50 pixel apart (a cloud concatenated with a
// resampled copy of itself): the spacing says a pixel 50 times too fine,
// whose grid would be mostly holes; it is coarsened until the surfaces fill it.
TEST(ProjectCloud, AGridThatWouldBeMostlyHolesIsCoarsened) {
  const Cell& cell = DefaultCell();
  const Intrinsics& K = cell.camera.FindConfig(1)->intrinsics;
  const Pose X_CF = MakePose(Quat(Eigen::AngleAxisd(0.05, Vec3::UnitX())), Vec3::Zero());
  Frame cloud;
  cloud.X_BC = cell.camera.X_BC;
  for (const Eigen::Vector3f& p : FloorSeenFrom(K, X_CF, 4)) {
    cloud.points_C.push_back(p);
    cloud.points_C.push_back(p + Eigen::Vector3f(p.z() / K.fx / 50, 0.f, 0.f));
  }
  Result<CloudProjection> p = ProjectCloud(cloud, cell, true);
  ASSERT_TRUE(p.ok()) << p.status().ToString();
  ASSERT_EQ(p->grid, CloudGrid::kFromSpacing);
  EXPECT_LT(p->frame.intrinsics.fx, 1.3 * K.fx) << p->Describe();
  const auto [holes, filled] = FloorHolesAndFilled(p->frame.depth);
  EXPECT_LT(holes, filled / 20) << p->Describe();
}

TEST(ProjectCloud, WithoutXbcTheCloudIsSeenFromAboveTheBin) {
  const Cell& cell = DefaultCell();
  // A camera tilted 20 degrees: the assumed view is not it.
  const Pose X_BC = cell.camera.X_BC * MakePose(Quat(Eigen::AngleAxisd(0.35, Vec3::UnitX())), Vec3::Zero());
  const Frame organized = FloorWithBox(cell.camera.FindConfig(1)->intrinsics, X_BC);
  const Frame cloud = Unorganized(organized);
  Result<CloudProjection> p = ProjectCloud(cloud, cell, /*X_BC_known=*/false);
  ASSERT_TRUE(p.ok()) << p.status().ToString();
  EXPECT_EQ(p->view, CloudViewSource::kAboveBinNoPose);
  EXPECT_THAT(p->Describe(), HasSubstr("no X_BC: assumed"));
  // Looking down -z of the bin, above the bin's centre.
  const Pose X_WV = cell.bin.X_BW.inverse() * p->frame.X_BC;
  EXPECT_TRUE(X_WV.linear().col(2).isApprox(Vec3(0, 0, -1), 1e-12));
  EXPECT_NEAR(X_WV.translation().x(), 0.0, 1e-12);
  EXPECT_NEAR(X_WV.translation().y(), 0.0, 1e-12);
  EXPECT_GT(X_WV.translation().z(), 0.5);
  // The points stay where the given X_BC put them, on their pixels' rays.
  ExpectNearestPointDepths(cloud, *p);
}

TEST(ProjectCloud, ACameraThatDoesNotLookIntoTheBinIsReplacedByTheViewFromAbove) {
  const Cell& cell = DefaultCell();
  const Frame organized = FloorWithBox(cell.camera.FindConfig(1)->intrinsics, cell.camera.X_BC);
  Frame cloud = Unorganized(organized);
  // The same points written in the base frame with X_BC = identity (a merged
  // cloud's usual form): that "camera" looks up.
  for (Eigen::Vector3f& p : cloud.points_C) p = (cell.camera.X_BC * p.cast<double>()).cast<float>();
  cloud.X_BC = Pose::Identity();
  Result<CloudProjection> p = ProjectCloud(cloud, cell, true);
  ASSERT_TRUE(p.ok()) << p.status().ToString();
  EXPECT_EQ(p->view, CloudViewSource::kAboveBinTilted);
  EXPECT_THAT(p->Describe(), HasSubstr("does not look down into the bin"));
  // The top of the box is what the view sees.
  EXPECT_GT(p->pixels, p->points * 3 / 4);
}

TEST(ProjectCloud, ThePixelKeepsTheNearestPointOnItsRay) {
  Frame cloud;
  cloud.X_BC = DefaultCell().camera.X_BC;
  // A 12 x 12 lattice at 1 m, and a point in front of one of them on its ray.
  for (int j = 0; j < 12; ++j) {
    for (int i = 0; i < 12; ++i) cloud.points_C.emplace_back(0.002f * i, 0.002f * j, 1.f);
  }
  cloud.points_C.push_back(Eigen::Vector3f(0.002f * 5, 0.002f * 6, 1.f) * 0.9f);
  Result<CloudProjection> p = ProjectCloud(cloud, DefaultCell(), true);
  ASSERT_TRUE(p.ok()) << p.status().ToString();
  EXPECT_EQ(p->grid, CloudGrid::kRecovered);
  EXPECT_EQ(p->points, 145);
  EXPECT_EQ(p->pixels, 144);
  ASSERT_EQ(p->frame.intrinsics.width, 12);
  EXPECT_FLOAT_EQ(p->frame.depth.at(5, 6), 0.9f);
  EXPECT_FLOAT_EQ(p->frame.depth.at(6, 6), 1.f);
}

TEST(ProjectCloud, ABigSparseCloudIsCoarsenedToTheLargestImage) {
  Frame cloud;
  cloud.X_BC = DefaultCell().camera.X_BC;
  std::mt19937 rng{9};
  std::uniform_real_distribution<float> xy(-0.4f, 0.4f);
  for (int i = 0; i < 5000; ++i) cloud.points_C.emplace_back(xy(rng), xy(rng), 1.f);
  CloudProjectionOptions options;
  options.max_pixels = 1000;
  Result<CloudProjection> p = ProjectCloud(cloud, DefaultCell(), true, options);
  ASSERT_TRUE(p.ok()) << p.status().ToString();
  EXPECT_LE(static_cast<int64_t>(p->frame.intrinsics.width) * p->frame.intrinsics.height, 1000);
  EXPECT_GT(static_cast<int64_t>(p->frame.intrinsics.width) * p->frame.intrinsics.height, 900);
}

// Found by fuzz/pcd_fuzz: a few points far apart on a line made a grid of
// the largest image, mostly empty, searched again and again for holes (a
// timeout). The grid has at most 16 pixels per point, 64 at the least.
TEST(ProjectCloud, AFewPointsFarApartGetASmallGrid) {
  Frame cloud;
  cloud.X_BC = DefaultCell().camera.X_BC;
  cloud.points_C = {{-0.5f, 0.f, 1.f}, {0.f, 0.f, 1.f}, {0.5f, 0.f, 1.f}};
  Result<CloudProjection> p = ProjectCloud(cloud, DefaultCell(), true);
  ASSERT_TRUE(p.ok()) << p.status().ToString();
  EXPECT_LE(static_cast<int64_t>(p->frame.intrinsics.width) * p->frame.intrinsics.height, 16 * 3 + 64);
  EXPECT_EQ(p->pixels, 3);
}

// Found by fuzz/pcd_fuzz (regress-ubsan-huge-tangent): a point at a tangent
// of 1e33 made pixel coordinates whose rounding put points off the grid
// (an out-of-range index). Points more than 84.3 deg off the view's axis
// are dropped.
TEST(ProjectCloud, PointsFarOffTheViewAxisAreDropped) {
  Frame cloud;
  cloud.X_BC = DefaultCell().camera.X_BC;
  for (int i = 0; i < 10; ++i) {
    for (int j = 0; j < 10; ++j) cloud.points_C.emplace_back(0.01f * static_cast<float>(i), 0.01f * j, 1.f);
  }
  cloud.points_C.emplace_back(1e30f, 0.f, 1e-3f + 1e-6f);
  cloud.points_C.emplace_back(0.f, -12.f, 1.f);
  Result<CloudProjection> p = ProjectCloud(cloud, DefaultCell(), true);
  ASSERT_TRUE(p.ok()) << p.status().ToString();
  EXPECT_EQ(p->points, 100);
  EXPECT_EQ(p->pixels, 100);
  cloud.points_C = {{1e30f, 0.f, 1.f}};
  EXPECT_EQ(ProjectCloud(cloud, DefaultCell(), true).status().code(), Status::Code::kInvalidArgument);
}

// Found by fuzz/pcd_fuzz: 25 points spread over a square put the spacing
// search's cell at 2/5 of the square, so the far edge's pixel coordinate
// (2.5) rounded off a grid sized from the extent (an index of -1). Random
// such squares, off any lattice: every point gets a pixel.
TEST(ProjectCloud, EveryPointOfASquareCloudGetsAPixel) {
  std::mt19937 rng{11};
  std::uniform_real_distribution<float> corner(-0.3f, 0.2f), side(0.01f, 0.1f), inside(0.f, 1.f);
  for (int trial = 0; trial < 300; ++trial) {
    Frame cloud;
    cloud.X_BC = DefaultCell().camera.X_BC;
    const float x0 = corner(rng), s = side(rng);
    for (const float cx : {0.f, 1.f}) {
      for (const float cy : {0.f, 1.f}) cloud.points_C.emplace_back(x0 + cx * s, x0 + cy * s, 1.f);
    }
    while (cloud.points_C.size() < 25) {
      cloud.points_C.emplace_back(x0 + inside(rng) * s, x0 + inside(rng) * s, 1.f);
    }
    Result<CloudProjection> p = ProjectCloud(cloud, DefaultCell(), true);
    ASSERT_TRUE(p.ok()) << "trial " << trial << ": " << p.status().ToString();
    ASSERT_EQ(p->points, 25) << "trial " << trial;
  }
}

TEST(ProjectCloud, AnOrganizedFrameOrNoPointInFrontIsInvalidArgument) {
  const Cell& cell = DefaultCell();
  const Frame organized = FloorWithBox(cell.camera.FindConfig(1)->intrinsics, cell.camera.X_BC);
  EXPECT_EQ(ProjectCloud(organized, cell, true).status().code(), Status::Code::kInvalidArgument);
  Frame behind;
  behind.X_BC = cell.camera.X_BC;
  behind.points_C = {{0.f, 0.f, -1.f}, {std::nanf(""), 0.f, 1.f}};
  EXPECT_EQ(ProjectCloud(behind, cell, true).status().code(), Status::Code::kInvalidArgument);
}

}  // namespace
}  // namespace bp
