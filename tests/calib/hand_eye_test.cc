#include "calib/hand_eye.h"

#include <gtest/gtest.h>

#include <opencv2/calib3d.hpp>

#include "calib/board.h"
#include "calib/calibration_camera.h"
#include "calib/hand_eye_service.h"
#include "tests/calib/calib_test_util.h"

namespace bp {
namespace {

// Views of the board from the auto plan around the start pose, as the
// service would take them.
std::vector<HandEyeSample> PlannedViews(const Cell& cell, int count) {
  SimulatedCalibrationCamera camera(cell.camera, *cell.calibration);
  const Pose start = BoardFacingStartPose(cell);
  const Pose X_nominal = cell.camera.eye_in_hand ? cell.camera.X_FC : cell.camera.X_BC;
  const Pose X_BC = cell.camera.eye_in_hand ? Pose(start * X_nominal) : X_nominal;
  const Pose X_CT = camera.TrueX_CT(start);
  const Vec3 p_B = X_BC * (X_CT * BoardCentre(*cell.calibration));
  std::vector<Pose> poses = {start};
  for (const Pose& p : HandEyeCalibrationService::PlanAround(start, p_B, X_BC.translation(), count - 1)) {
    poses.push_back(p);
  }
  std::vector<HandEyeSample> samples;
  for (const Pose& X_BF : poses) {
    Result<IntensityImage> image = camera.CaptureBoard(X_BF);
    EXPECT_TRUE(image.ok());
    Result<BoardDetection> d = DetectBoard(*image, *cell.calibration, camera.intrinsics());
    EXPECT_TRUE(d.ok()) << d.status().ToString();
    if (!d.ok()) continue;
    samples.push_back({X_BF, d->X_CT, d->corners});
  }
  return samples;
}

TEST(Board, DetectionRecoversTheRenderedPose) {
  const Cell cell = testing::CalibCell(false);
  SimulatedCalibrationCamera camera(cell.camera, *cell.calibration);
  const Pose start = BoardFacingStartPose(cell);
  const Pose truth = camera.TrueX_CT(start);
  ASSERT_TRUE(BoardVisibility(*cell.calibration, camera.intrinsics(), truth).ok());
  Result<IntensityImage> image = camera.CaptureBoard(start);
  ASSERT_TRUE(image.ok());
  Result<BoardDetection> d = DetectBoard(*image, *cell.calibration, camera.intrinsics());
  ASSERT_TRUE(d.ok()) << d.status().ToString();
  EXPECT_LT(d->rms_px, 0.2);
  const Vec3 c = BoardCentre(*cell.calibration);
  EXPECT_LT(((d->X_CT * c) - (truth * c)).norm(), 0.001);
  EXPECT_LT(RotationErrorDeg(d->X_CT, truth), 0.3);
}

TEST(Board, UpsideDownBoardIsReadTheRightWayRound) {
  const Cell cell = testing::CalibCell(false);
  SimulatedCalibrationCamera camera(cell.camera, *cell.calibration);
  const Pose start = BoardFacingStartPose(cell);
  // Turn the board 180 degrees about the view: OpenCV's corner order flips.
  const Pose truth = camera.TrueX_CT(start);
  const Vec3 c = BoardCentre(*cell.calibration);
  const Pose turn = MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitZ())), c - Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitZ())) * c);
  const Pose X_CT = truth * turn;
  Result<IntensityImage> image = RenderBoard(*cell.calibration, camera.intrinsics(), X_CT, 7);
  ASSERT_TRUE(image.ok());
  Result<BoardDetection> d = DetectBoard(*image, *cell.calibration, camera.intrinsics());
  ASSERT_TRUE(d.ok());
  EXPECT_LT(RotationErrorDeg(d->X_CT, X_CT), 0.3);
}

TEST(Board, BoardOutOfViewIsNotFound) {
  const Cell cell = testing::CalibCell(false);
  SimulatedCalibrationCamera camera(cell.camera, *cell.calibration);
  Pose away = BoardFacingStartPose(cell);
  away.translation() += Vec3(0.5, 0, 0);  // half a metre aside: outside the image
  EXPECT_FALSE(BoardVisibility(*cell.calibration, camera.intrinsics(), camera.TrueX_CT(away)).ok());
  Result<IntensityImage> image = camera.CaptureBoard(away);
  ASSERT_TRUE(image.ok());
  Result<BoardDetection> d = DetectBoard(*image, *cell.calibration, camera.intrinsics());
  EXPECT_EQ(d.status().code(), Status::Code::kNotFound);
}

class SolverAccuracy : public ::testing::TestWithParam<bool> {};

TEST_P(SolverAccuracy, TwelvePlannedPosesRecoverTheTrueTransform) {
  const Cell cell = testing::CalibCell(GetParam());
  const std::vector<HandEyeSample> samples = PlannedViews(cell, 12);
  ASSERT_EQ(samples.size(), 12u);
  HandEyeOptions o;
  o.eye_in_hand = GetParam();
  Result<HandEyeSolution> sol = SolveHandEye(samples, *cell.calibration, cell.camera.configs[0].intrinsics, o);
  ASSERT_TRUE(sol.ok()) << sol.status().ToString();
  const Pose& truth = cell.calibration->true_pose;
  EXPECT_LT(TranslationErrorMm(sol->X, truth), 0.5);
  EXPECT_LT(RotationErrorDeg(sol->X, truth), 0.05);
  EXPECT_LT(sol->reprojection_rms_px, 0.3);
  EXPECT_EQ(sol->method, "park+refine");
  // The closed form alone agrees with OpenCV's PARK on the same data.
  o.refine = false;
  Result<HandEyeSolution> park = SolveHandEye(samples, *cell.calibration, cell.camera.configs[0].intrinsics, o);
  ASSERT_TRUE(park.ok());
  std::vector<cv::Mat> Rg, tg, Rt, tt;
  for (const HandEyeSample& s : samples) {
    const Pose G = GetParam() ? s.X_BF : Pose(s.X_BF.inverse());
    cv::Mat R(3, 3, CV_64F), t(3, 1, CV_64F), R2(3, 3, CV_64F), t2(3, 1, CV_64F);
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        R.at<double>(r, c) = G.linear()(r, c);
        R2.at<double>(r, c) = s.X_CT.linear()(r, c);
      }
      t.at<double>(r) = G.translation()(r);
      t2.at<double>(r) = s.X_CT.translation()(r);
    }
    Rg.push_back(R); tg.push_back(t); Rt.push_back(R2); tt.push_back(t2);
  }
  cv::Mat Rx, tx;
  cv::calibrateHandEye(Rg, tg, Rt, tt, Rx, tx, cv::CALIB_HAND_EYE_PARK);
  Pose cvX = Pose::Identity();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) cvX.linear()(r, c) = Rx.at<double>(r, c);
    cvX.translation()(r) = tx.at<double>(r);
  }
  EXPECT_LT(TranslationErrorMm(park->X, cvX), 1.0);
  EXPECT_LT(RotationErrorDeg(park->X, cvX), 0.05);
}

INSTANTIATE_TEST_SUITE_P(Mounts, SolverAccuracy, ::testing::Values(false, true),
                         [](const auto& info) { return info.param ? "EyeInHand" : "EyeToHand"; });

TEST(Solver, RotationsAboutOneAxisOnlyAreRejected) {
  const Cell cell = testing::CalibCell(false);
  SimulatedCalibrationCamera camera(cell.camera, *cell.calibration);
  const Pose start = BoardFacingStartPose(cell);
  std::vector<HandEyeSample> samples;
  for (int i = 0; i < 6; ++i) {
    const Pose X_BF = start * MakePose(Mat3(Eigen::AngleAxisd(0.15 * i, Vec3::UnitZ())), Vec3::Zero());
    Result<BoardDetection> d = DetectBoard(*camera.CaptureBoard(X_BF), *cell.calibration, camera.intrinsics());
    ASSERT_TRUE(d.ok());
    samples.push_back({X_BF, d->X_CT, d->corners});
  }
  Result<HandEyeSolution> sol = SolveHandEye(samples, *cell.calibration, camera.intrinsics(), {});
  EXPECT_EQ(sol.status().code(), Status::Code::kInvalidArgument);
}

TEST(Solver, FewerThanThreePosesAreRejected) {
  const Cell cell = testing::CalibCell(false);
  const std::vector<HandEyeSample> samples = PlannedViews(cell, 2);
  Result<HandEyeSolution> sol = SolveHandEye(samples, *cell.calibration, cell.camera.configs[0].intrinsics, {});
  EXPECT_EQ(sol.status().code(), Status::Code::kInvalidArgument);
}

}  // namespace
}  // namespace bp
