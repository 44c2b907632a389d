// The hand-eye transform binpick uses (X_BC eye-to-hand, X_FC eye-in-hand)
// and what the status page says about it.
//
// Ownership: binpickd creates one HandEyeState per cell with a calibration
// section and shares it. Writer: HandEyeCalibrationService (a solved
// calibration, guidance verdicts), on the calibration sequence. Readers: the
// capture source (each frame's X_BC, through a HandEyeProvider), the
// precision check, the auto-calibration planner and the status page probe,
// on detection workers, transport threads and the HTTP thread.
//
// Thread-safety: every member may be called concurrently; a reader sees a
// result's pose and its figures together (one mutex).
#pragma once

#include <chrono>
#include <mutex>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/pose.h"

namespace bp {

// A solved calibration, as the status page shows it.
struct HandEyeResultInfo {
  std::chrono::system_clock::time_point time{};
  std::string kind;    // "manual", "auto", "guidance", "gri"
  std::string method;  // solver ("park+refine")
  int poses = 0;
  double residual_rms_mm = 0, residual_max_mm = 0;
  double residual_rms_deg = 0, residual_max_deg = 0;
  double reprojection_rms_px = 0;
};

// A guidance pose answered 13 (bad), and why.
struct GuidanceVerdict {
  std::chrono::system_clock::time_point time{};
  std::string reason;
};

struct HandEyeSnapshot {
  Pose X = Pose::Identity();
  std::string origin;  // where X came from: "camera.pose", the hand-eye file, "calibration"
  std::optional<HandEyeResultInfo> last_result;       // since this process started
  std::optional<GuidanceVerdict> last_bad_guidance;   // idem
  std::string mode = "none";  // calibration under way: "manual", "auto", "guidance"; "none" after a solve
  int poses = 0;              // views it holds
};

class HandEyeState {
 public:
  explicit HandEyeState(const Pose& X, std::string origin = "camera.pose") {
    snapshot_.X = X;
    snapshot_.origin = std::move(origin);
  }
  Pose Get() const {
    std::lock_guard lock(mutex_);
    return snapshot_.X;
  }
  HandEyeSnapshot Snapshot() const {
    std::lock_guard lock(mutex_);
    return snapshot_;
  }
  // A pose without a result (tests, tools).
  void Set(const Pose& X) {
    std::lock_guard lock(mutex_);
    snapshot_.X = X;
  }
  // A solved calibration: the pose in use from now on and its figures.
  void SetResult(const Pose& X, HandEyeResultInfo info) {
    std::lock_guard lock(mutex_);
    snapshot_.X = X;
    snapshot_.origin = "calibration";
    snapshot_.last_result = std::move(info);
    snapshot_.mode = "none";
  }
  // The calibration under way and the views it holds.
  void SetSession(std::string mode, int poses) {
    std::lock_guard lock(mutex_);
    snapshot_.mode = std::move(mode);
    snapshot_.poses = poses;
  }
  void SetBadGuidance(std::string reason) {
    std::lock_guard lock(mutex_);
    snapshot_.last_bad_guidance = GuidanceVerdict{std::chrono::system_clock::now(), std::move(reason)};
  }

 private:
  mutable std::mutex mutex_;
  HandEyeSnapshot snapshot_;  // GUARDED_BY(mutex_)
};

// The status page's "Calibration" rows (StatusState::SetCalibrationProbe):
// the transform in use (xyz mm, rpy deg) and where it came from, the last
// result's time, residuals and poses, the last bad guidance pose's reason.
std::vector<std::pair<std::string, std::string>> HandEyeStatusRows(const HandEyeSnapshot& snapshot,
                                                                   bool eye_in_hand);

}  // namespace bp
