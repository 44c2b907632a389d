#include "calib/calibration_camera.h"

#include "calib/board.h"

namespace bp {

SimulatedCalibrationCamera::SimulatedCalibrationCamera(const CameraSpec& camera, const CalibrationSpec& spec)
    : eye_in_hand_(camera.eye_in_hand), spec_(spec), true_pose_(spec.true_pose), next_seed_(spec.seed) {
  const CameraConfig* config = camera.FindConfig(camera.default_config);
  if (config != nullptr) intrinsics_ = config->intrinsics;
}

Pose SimulatedCalibrationCamera::TrueX_BC(const Pose& X_BF) const {
  return eye_in_hand_ ? Pose(X_BF * true_pose_) : true_pose_;
}

Pose SimulatedCalibrationCamera::TrueX_CT(const Pose& X_BF) const {
  std::lock_guard lock(mutex_);
  const Pose X_BT = eye_in_hand_ ? spec_.target_pose : Pose(X_BF * spec_.target_pose);
  return TrueX_BC(X_BF).inverse() * X_BT;
}

Pose SimulatedCalibrationCamera::TrueX_CP(const Pose& X_BF) const {
  std::lock_guard lock(mutex_);
  return TrueX_BC(X_BF).inverse() * spec_.precision_target;
}

Result<IntensityImage> SimulatedCalibrationCamera::CaptureBoard(const Pose& X_BF) {
  const Pose X_CT = TrueX_CT(X_BF);
  uint64_t seed;
  {
    std::lock_guard lock(mutex_);
    seed = next_seed_++;
  }
  return RenderBoard(spec_, intrinsics_, X_CT, seed);
}

Result<IntensityImage> SimulatedCalibrationCamera::CapturePrecisionTarget(const Pose& X_BF) {
  const Pose X_CP = TrueX_CP(X_BF);
  uint64_t seed;
  {
    std::lock_guard lock(mutex_);
    seed = next_seed_++;
  }
  return RenderBoard(spec_, intrinsics_, X_CP, seed);
}

void SimulatedCalibrationCamera::set_true_pose(const Pose& X) {
  std::lock_guard lock(mutex_);
  true_pose_ = X;
}

Pose SimulatedCalibrationCamera::true_pose() const {
  std::lock_guard lock(mutex_);
  return true_pose_;
}

}  // namespace bp

namespace bp {
Pose BoardFacingStartPose(const Cell& cell, double distance) {
  const CalibrationSpec spec = cell.calibration.value_or(CalibrationSpec{});
  const Pose ahead = MakePose(Mat3::Identity(), Vec3(0, 0, distance));
  const Pose to_centre = MakePose(Mat3::Identity(), -BoardCentre(spec));
  if (cell.camera.eye_in_hand) {
    // Camera (X_BC) such that the board centre is `distance` ahead, axes aligned with the board.
    const Pose X_BC = spec.target_pose * to_centre.inverse() * ahead.inverse();
    return X_BC * spec.true_pose.inverse();
  }
  const Pose X_BT = spec.true_pose * ahead * to_centre;
  return X_BT * spec.target_pose.inverse();
}
}  // namespace bp
