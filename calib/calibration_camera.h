// Where calibration images come from: the camera seeing the calibration
// board (or the precision-check target) with the robot at X_BF. The
// simulated one renders the boards with the cell's TRUE hand-eye transform
// (calibration.true_pose), which only it reads.
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>

#include "core/cell.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/status.h"

namespace bp {

class CalibrationCamera {
 public:
  virtual ~CalibrationCamera() = default;
  virtual const Intrinsics& intrinsics() const = 0;
  // The calibration board with the robot at X_BF (eye-to-hand: on the flange).
  virtual Result<IntensityImage> CaptureBoard(const Pose& X_BF) = 0;
  // The precision target (fixed in the base) with the robot at X_BF.
  virtual Result<IntensityImage> CapturePrecisionTarget(const Pose& X_BF) = 0;
};

// Thread-safe. Each capture draws new image noise (seed, seed + 1, ...).
class SimulatedCalibrationCamera final : public CalibrationCamera {
 public:
  // Uses the camera's default config; `spec` is the cell's calibration section.
  SimulatedCalibrationCamera(const CameraSpec& camera, const CalibrationSpec& spec);
  const Intrinsics& intrinsics() const override { return intrinsics_; }
  Result<IntensityImage> CaptureBoard(const Pose& X_BF) override;
  Result<IntensityImage> CapturePrecisionTarget(const Pose& X_BF) override;

  // The true board / target pose in the camera at X_BF (for tests and the planner's checks).
  Pose TrueX_CT(const Pose& X_BF) const;
  Pose TrueX_CP(const Pose& X_BF) const;
  // Moves the true camera (a bumped camera: tests of the precision check).
  void set_true_pose(const Pose& X);
  Pose true_pose() const;

 private:
  Pose TrueX_BC(const Pose& X_BF) const;  // REQUIRES: mutex_ held

  const bool eye_in_hand_;
  const CalibrationSpec spec_;
  Intrinsics intrinsics_;
  mutable std::mutex mutex_;
  Pose true_pose_;     // GUARDED_BY(mutex_)
  uint64_t next_seed_;  // GUARDED_BY(mutex_)
};

}  // namespace bp

namespace bp {
// Simulator only (reads the true transform): a robot pose from which the
// board faces the camera square-on, its centre `distance` metres along the
// optical axis. Calibration flows start here.
Pose BoardFacingStartPose(const Cell& cell, double distance = 0.5);
}  // namespace bp
