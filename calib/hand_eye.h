// The hand-eye solver. Unknowns: the hand-eye transform X (X_BC for an
// eye-to-hand camera, X_FC for an eye-in-hand one) and the board pose Y (X_FT
// on the flange eye-to-hand, X_BT in the base eye-in-hand). Each sample is a
// robot pose X_BF and the board seen from the camera X_CT:
//   eye-to-hand: X_CT = X_BC^-1 * X_BF * X_FT
//   eye-in-hand: X_CT = X_FC^-1 * X_BF^-1 * X_BT
#pragma once

#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/cell.h"
#include "core/pose.h"
#include "core/status.h"

namespace bp {

struct HandEyeSample {
  Pose X_BF = Pose::Identity();
  Pose X_CT = Pose::Identity();
  std::vector<Eigen::Vector2d> corners;  // detected, in BoardCorners order
};

struct HandEyeOptions {
  bool eye_in_hand = false;
  // Pairs whose relative robot rotation is below this are not used by the
  // closed form (they make AX = XB ill-conditioned).
  double min_pair_rotation_deg = 5.0;
  // Joint reprojection refinement of X and Y after the closed form.
  bool refine = true;
};

struct HandEyeSolution {
  Pose X = Pose::Identity();   // X_BC or X_FC
  Pose Y = Pose::Identity();   // X_FT or X_BT
  int poses = 0;               // samples used
  int pairs = 0;               // pose pairs used by the closed form
  // Consistency of every sample with (X, Y): the board pose predicted from
  // the robot pose against the detected one, RMS and max.
  double residual_rms_mm = 0, residual_max_mm = 0;
  double residual_rms_deg = 0, residual_max_deg = 0;
  double reprojection_rms_px = 0;  // of all corners, with X and Y
  std::string method;              // "park" or "park+refine"
};

// Park & Martin's closed form over the view pairs whose relative robot
// rotation is at least options.min_pair_rotation_deg (the same closed form as
// cv::calibrateHandEye(PARK), which has no such pair filter; OpenCV 4.6's
// TSAI is unstable for small rotations, HORAUD / DANIILIDIS have a
// quaternion-sign bug), then (options.refine) Levenberg-Marquardt on the
// corner reprojection of all views jointly over X and Y.
// @returns InvalidArgument when fewer than 3 samples or fewer than 2
// pairs with enough rotation (rotations about one axis only also fail: the
// problem has no unique answer).
Result<HandEyeSolution> SolveHandEye(const std::vector<HandEyeSample>& samples, const CalibrationSpec& board,
                                     const Intrinsics& intrinsics, const HandEyeOptions& options);

// Translation (mm) and rotation (deg) difference between two poses.
double TranslationErrorMm(const Pose& a, const Pose& b);
double RotationErrorDeg(const Pose& a, const Pose& b);

}  // namespace bp
