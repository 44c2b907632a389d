// Hand-eye calibration as the DaoAI commands drive it. The request handler
// owns the mode state machine (which command is valid when, which status to
// answer); a CalibrationService does the work of each step. The real one is
// calib/hand_eye_service.h; CountingCalibrationService only accumulates.
//
// Thread-safety: the request handler serializes all calls (one calibration at
// a time per server).
#pragma once

#include <memory>
#include <optional>
#include <vector>

#include "core/pose.h"
#include "core/status.h"

namespace bp {

enum class CalibrationKind {
  kManual,     // RC 1 / 6 / 2: the robot decides when to stop
  kAuto,       // RC 4 / 7: the vision side proposes poses and says when done
  kGuidance,   // RC 10: each request is a pose; version 1 answers good/bad/done
  kAuto2D,     // RC 11 / 12: as kAuto, poses in the robot's 2D plane
};

// Views one calibration session keeps at most (issue 39: a robot looping
// MANUAL_ACCUMULATE_POSE must not grow the server without bound). Far above
// what a solve needs (calibration.min_poses, auto_poses: about 10-20).
inline constexpr size_t kMaxCalibrationPoses = 64;

struct CalibrationStep {
  bool done = false;             // enough poses: the robot ends the calibration
  bool good = true;              // guidance: the pose gave a usable image
  std::optional<Pose> next_X_BF; // auto modes: the pose the robot moves to next
};

class CalibrationService {
 public:
  virtual ~CalibrationService() = default;
  // Starts a calibration of `kind` from robot pose X_BF (discarding any other).
  virtual Status Start(CalibrationKind kind, const Pose& X_BF) = 0;
  // Captures the target at robot pose X_BF and accumulates it. OutOfRange
  // once kMaxCalibrationPoses are kept (the view is not stored).
  virtual Result<CalibrationStep> Accumulate(CalibrationKind kind, const Pose& X_BF) = 0;
  // Ends the calibration (solving it when the service can).
  virtual Status Finish(CalibrationKind kind) = 0;
  // GRI HEC_SET_POSE: as Accumulate, the view replacing the one stored in
  // `slot` (default: a plain Accumulate).
  virtual Result<CalibrationStep> AccumulateInSlot(CalibrationKind kind, int /*slot*/, const Pose& X_BF) {
    return Accumulate(kind, X_BF);
  }
};

// Accumulates robot poses without capturing or solving: auto / 2D / guidance
// calibrations report done after `poses_needed` poses, manual never does (the
// robot ends it). The proposed next pose is the robot's current pose, so a
// robot following it does not move.
class CountingCalibrationService final : public CalibrationService {
 public:
  explicit CountingCalibrationService(int poses_needed = 12) : poses_needed_(poses_needed) {}
  Status Start(CalibrationKind kind, const Pose& X_BF) override;
  Result<CalibrationStep> Accumulate(CalibrationKind kind, const Pose& X_BF) override;
  Status Finish(CalibrationKind kind) override;
  const std::vector<Pose>& poses() const { return poses_; }

 private:
  int poses_needed_;
  std::vector<Pose> poses_;
};

}  // namespace bp
