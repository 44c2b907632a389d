// Bin detection (issue 41) on the default cell's rendered frames against the
// bin's true pose, and on frames without a bin.
#include "pipeline/bin_detection.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>

#include "pipeline/synthetic_source.h"
#include "tests/testing/no_bin_source.h"

namespace bp {
namespace {

constexpr double kRadToDeg = 180.0 / M_PI;

Cell DefaultCell() {
  Result<Cell> cell = LoadDefaultCell();
  EXPECT_TRUE(cell.ok()) << cell.status().ToString();
  return *cell;
}

// A frame of `cell`'s scene (seeded pile) and where its bin truly stands.
struct Scene {
  Frame frame;
  Pose X_BW_true;
};

Scene Render(const Cell& cell) {
  auto source = MakeSyntheticSource(cell);
  EXPECT_TRUE(source.ok()) << source.status().ToString();
  auto* synthetic = dynamic_cast<SyntheticSource*>(source->get());
  EXPECT_NE(synthetic, nullptr);
  Result<Frame> frame = (*source)->Capture({});
  EXPECT_TRUE(frame.ok()) << frame.status().ToString();
  return {std::move(*frame), synthetic->X_BW()};
}

// Translation (m) and rotation (deg) between two poses.
std::pair<double, double> Error(const Pose& a, const Pose& b) {
  const Pose d = a.inverse() * b;
  return {d.translation().norm(), Eigen::AngleAxisd(d.linear()).angle() * kRadToDeg};
}

// Renders the default cell with its bin moved by `offset` (in the nominal
// bin frame), detects it with the nominal cell and checks the measured pose
// against the truth: within 0.5 mm and 0.1 deg.
BinDetection ExpectFoundAt(const Pose& offset, const BinDetectSpec& detect = {}) {
  Cell truth = DefaultCell();
  truth.bin.X_BW = truth.bin.X_BW * offset;
  const Scene scene = Render(truth);
  BinSpec nominal = DefaultCell().bin;
  nominal.detect = detect;
  const BinDetection bin = DetectBin(scene.frame, nominal);
  EXPECT_TRUE(bin.found) << bin.reason;
  if (!bin.found) return bin;
  const auto [mm, deg] = Error(bin.X_BW, scene.X_BW_true);
  EXPECT_LT(mm, 0.0005) << 1e3 * mm << " mm";
  EXPECT_LT(deg, 0.1) << deg << " deg";
  return bin;
}

TEST(BinDetection, FindsTheBinAtItsNominalPose) {
  Cell cell = DefaultCell();
  cell.source.num_parts = 20;
  const Scene scene = Render(cell);
  const BinDetection bin = DetectBin(scene.frame, cell.bin);
  ASSERT_TRUE(bin.found) << bin.reason;
  const auto [mm, deg] = Error(bin.X_BW, scene.X_BW_true);
  EXPECT_LT(mm, 0.0001) << 1e3 * mm << " mm";
  EXPECT_LT(deg, 0.02) << deg << " deg";
  EXPECT_FALSE(bin.warn);
  EXPECT_GT(bin.rim_seen, 0.8);
}

TEST(BinDetection, FindsABinShiftedAndTurnedWithinTolerance) {
  // Seeded offsets within the window (+-50 mm, +-10 deg, tilt up to 2 deg),
  // and the window's corner: the scene's bin placed there, nominal kept.
  int far = 0;
  for (uint64_t seed : {3, 11}) {
    Cell cell = DefaultCell();
    cell.source.seed = seed;
    cell.source.bin_offset_translation = 0.05;
    cell.source.bin_offset_yaw_deg = 10.0;
    cell.source.bin_offset_tilt_deg = 2.0;
    const Scene scene = Render(cell);
    const auto [off_mm, off_deg] = Error(cell.bin.X_BW, scene.X_BW_true);
    far += off_mm > 0.015 || off_deg > 3.0 ? 1 : 0;
    const BinDetection bin = DetectBin(scene.frame, cell.bin);
    ASSERT_TRUE(bin.found) << "seed " << seed << ": " << bin.reason;
    const auto [mm, deg] = Error(bin.X_BW, scene.X_BW_true);
    EXPECT_LT(mm, 0.0005) << "seed " << seed << ": " << 1e3 * mm << " mm, bin " << 1e3 * off_mm << " mm / "
                          << off_deg << " deg off";
    EXPECT_LT(deg, 0.1) << "seed " << seed << ": " << deg << " deg";
    EXPECT_NEAR(bin.offset, off_mm, 0.002);
  }
  EXPECT_GT(far, 0) << "the seeded offsets should move the bin noticeably";

  const Pose corner = MakePose(Mat3(Eigen::AngleAxisd(1.5 / kRadToDeg, Vec3(0.6, 0.8, 0).normalized()) *
                                    Eigen::AngleAxisd(-9.5 / kRadToDeg, Vec3::UnitZ())),
                               Vec3(0.048, -0.048, 0.0));
  EXPECT_TRUE(ExpectFoundAt(corner).warn);  // 68 mm / 9.6 deg from nominal, beyond bin.detect_warn
}

TEST(BinDetection, FindsTheBinAroundAFullPile) {
  // 100 parts (mean height 79% of the inner height, parts above the rim in
  // front of it): the band about the rim's height holds three times more
  // pile than rim points. Seed 2074 was lost ("a wall's rim is seen along 0%
  // of its length") while the rim plane was fitted to the whole band and the
  // first ICP gated at the window's reach.
  Cell cell = DefaultCell();
  cell.source.seed = 2074;
  cell.source.num_parts = 100;
  cell.source.bin_offset_translation = 0.05;
  cell.source.bin_offset_yaw_deg = 10.0;
  cell.source.bin_offset_tilt_deg = 2.0;
  const Scene scene = Render(cell);
  const BinDetection bin = DetectBin(scene.frame, cell.bin);
  ASSERT_TRUE(bin.found) << bin.reason;
  const auto [mm, deg] = Error(bin.X_BW, scene.X_BW_true);
  EXPECT_LT(mm, 0.0005) << 1e3 * mm << " mm";
  EXPECT_LT(deg, 0.1) << deg << " deg";
  // The same frame with the window of a free-standing bin (any yaw: the
  // consensus start's yaws every 2 deg over the rim's whole period, 90 of
  // them, against 11 for the default window): at every yaw the pile's band
  // points fall into the histograms, and none of those yaws may outvote the
  // walls'. The rim turned by 180 deg is the same bin.
  BinSpec any_yaw = cell.bin;
  any_yaw.detect.search_yaw_deg = 180.0;
  const BinDetection turned = DetectBin(scene.frame, any_yaw);
  ASSERT_TRUE(turned.found) << turned.reason;
  const Pose flipped = scene.X_BW_true * MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitZ())), Vec3::Zero());
  const auto [any_mm, any_deg] = std::min(Error(turned.X_BW, scene.X_BW_true), Error(turned.X_BW, flipped));
  EXPECT_LT(any_mm, 0.0005) << 1e3 * any_mm << " mm";
  EXPECT_LT(any_deg, 0.1) << any_deg << " deg";
}

TEST(BinDetection, FindsNoBinOnAFloorALidOrAnEmptyFrame) {
  const Cell cell = DefaultCell();
  const BinDetection floor = DetectBin(testing::PlaneFrame(cell, 0.0), cell.bin);
  EXPECT_FALSE(floor.found);
  EXPECT_NE(floor.reason.find("no rim"), std::string::npos) << floor.reason;
  // A plate over the bin at the rim's height: a surface, not a rim.
  const BinDetection lid = DetectBin(testing::PlaneFrame(cell, cell.bin.inner_size.z()), cell.bin);
  EXPECT_FALSE(lid.found);
  EXPECT_NE(lid.reason.find("inward"), std::string::npos) << lid.reason;
  Frame empty = testing::PlaneFrame(cell, 0.0);
  for (float& z : empty.depth.data) z = std::numeric_limits<float>::quiet_NaN();
  EXPECT_FALSE(DetectBin(empty, cell.bin).found);
  Frame unorganized;
  unorganized.points_C = {Eigen::Vector3f(0, 0, 1)};
  EXPECT_FALSE(DetectBin(unorganized, cell.bin).found);
  EXPECT_EQ(DetectBin(unorganized, cell.bin).X_BW.matrix(), cell.bin.X_BW.matrix());
}

TEST(BinDetection, ABinTiltedAtTheWindowsEdgeIsFound) {
  // The floor 50 mm off nominal (the window's edge) and the bin tilted 2 deg
  // about its floor's y axis: its rim stands 7 mm further out, at 57 mm,
  // beyond the window's 55 mm, while the bin itself is inside the window.
  ExpectFoundAt(MakePose(Mat3(Eigen::AngleAxisd(2.0 / kRadToDeg, Vec3::UnitY())), Vec3(0.05, 0.0, 0.0)));
}

TEST(BinDetection, AFreeStandingBinIsFoundAtAnyYawModuloItsSymmetry) {
  // bin.detect_search rotation_deg: any. The default bin (500 x 360 mm) is
  // the same rim turned by 180 deg: the bin frame found is the one within
  // 90 deg of nominal. The default camera sees the bin's nominal footprint
  // with 60 mm to spare; turned, it needs the camera 0.4 m higher.
  Cell cell = DefaultCell();
  cell.camera.X_BC.translation().z() += 0.4;
  BinSpec nominal = cell.bin;
  nominal.detect.search_yaw_deg = 180.0;
  for (double yaw_deg : {73.0, -128.0}) {
    const Pose turned = MakePose(Mat3(Eigen::AngleAxisd(yaw_deg / kRadToDeg, Vec3::UnitZ())), Vec3(0.02, -0.03, 0));
    Cell truth = cell;
    truth.bin.X_BW = truth.bin.X_BW * turned;
    const Scene scene = Render(truth);
    const BinDetection bin = DetectBin(scene.frame, nominal);
    ASSERT_TRUE(bin.found) << yaw_deg << " deg: " << bin.reason;
    // The truth turned by 180 deg about its floor's centre is the same bin.
    const Pose flipped = scene.X_BW_true * MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitZ())), Vec3::Zero());
    const Pose& expected = std::abs(yaw_deg) <= 90 ? scene.X_BW_true : flipped;
    const auto [mm, deg] = Error(bin.X_BW, expected);
    EXPECT_LT(mm, 0.0005) << yaw_deg << " deg: " << 1e3 * mm << " mm";
    EXPECT_LT(deg, 0.1) << yaw_deg << " deg: " << deg << " deg";
  }
  // The default window (10 deg) refuses the bin turned 73 deg.
  Cell truth = cell;
  truth.bin.X_BW = truth.bin.X_BW * MakePose(Mat3(Eigen::AngleAxisd(73.0 / kRadToDeg, Vec3::UnitZ())), Vec3::Zero());
  EXPECT_FALSE(DetectBin(Render(truth).frame, cell.bin).found);
}

TEST(BinDetection, ABinBeyondTheSearchWindowIsNotFound) {
  Cell truth = DefaultCell();
  truth.bin.X_BW = truth.bin.X_BW * MakePose(Mat3::Identity(), Vec3(0.12, 0.0, 0.0));
  const Scene scene = Render(truth);
  const Cell nominal = DefaultCell();
  const BinDetection bin = DetectBin(scene.frame, nominal.bin);
  EXPECT_FALSE(bin.found) << 1e3 * Error(bin.X_BW, scene.X_BW_true).first << " mm";
  EXPECT_EQ(bin.X_BW.matrix(), nominal.bin.X_BW.matrix());
}

}  // namespace
}  // namespace bp
