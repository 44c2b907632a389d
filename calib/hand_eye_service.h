// The hand-eye calibration the DaoAI commands (1/2/4/6/7/10) and the GRI
// (HEC_*) drive: each step captures the board, detects it (sub-pixel corners,
// solvePnP) and stores it with the robot pose; Finish solves (calib/hand_eye.h),
// writes the result file atomically and makes the new camera pose current.
//
// Thread-safety: as CalibrationService (the request handler serializes the
// calls, on its calibration sequence's job thread); HandEyeState is shared
// with readers on other threads, and last_solution() and poses() may be read
// from any thread while steps run (tests, the CLI).
#pragma once

#include <atomic>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "calib/calibration_camera.h"
#include "calib/hand_eye.h"
#include "calib/hand_eye_state.h"
#include "comms/calibration_service.h"
#include "core/atomic_file.h"
#include "core/cell.h"

namespace bp {

struct HandEyeServiceOptions {
  // Where Finish writes the result (the cell's camera.hand_eye_file); empty:
  // the result is used but not persisted.
  std::string result_file;
  // keep_backup is always set; before_rename is for crash tests.
  AtomicWriteOptions write;
};

class HandEyeCalibrationService final : public CalibrationService {
 public:
  // `cell` must have a calibration section. `auto2d`, when given, serves
  // CalibrationKind::kAuto2D (else such calls answer Unavailable).
  HandEyeCalibrationService(const Cell& cell, std::shared_ptr<CalibrationCamera> camera,
                            std::shared_ptr<HandEyeState> state, std::unique_ptr<CalibrationService> auto2d = nullptr,
                            HandEyeServiceOptions options = {});

  Status Start(CalibrationKind kind, const Pose& X_BF) override;
  // NotFound (manual) when the board is not seen; auto answers good = false
  // and the next planned pose; guidance answers good = false with the reason.
  Result<CalibrationStep> Accumulate(CalibrationKind kind, const Pose& X_BF) override;
  // Solves, persists and makes the result current. InvalidArgument with
  // too few (or too similar) poses: the previous calibration stays in use
  // and on disk.
  Status Finish(CalibrationKind kind) override;
  // GRI HEC_SET_POSE: the view at X_BF replaces the one in `slot`.
  Result<CalibrationStep> AccumulateInSlot(CalibrationKind kind, int slot, const Pose& X_BF) override;

  // The last solve's result (a copy) and the poses the session keeps, for
  // tests and the CLI. Any thread, also while a step runs on the handler's
  // job thread: a test polls them while a robot process drives the
  // calibration, an order only the socket between them makes, which TSan
  // does not see.
  std::optional<HandEyeSolution> last_solution() const {
    std::lock_guard lock(last_mutex_);
    return last_;
  }
  size_t poses() const { return pose_count_.load(std::memory_order_acquire); }
  // The poses an auto calibration plans around X_BF, given the board centre
  // p_B (base frame) and the camera position c_B: rotations of the robot
  // about p_B, about axes across and along the view.
  static std::vector<Pose> PlanAround(const Pose& X_BF, const Vec3& p_B, const Vec3& c_B, int count);

 private:
  // Captures and detects at X_BF; NotFound / OutOfRange when the board is not seen.
  Result<HandEyeSample> Observe(const Pose& X_BF);
  Status Persist(const HandEyeSolution& solution) const;
  // After samples_ changed: poses() and the status page's session count.
  void PublishSession(CalibrationKind kind);

  const Cell cell_;
  const CalibrationSpec spec_;
  std::shared_ptr<CalibrationCamera> camera_;
  std::shared_ptr<HandEyeState> state_;
  std::unique_ptr<CalibrationService> auto2d_;
  HandEyeServiceOptions options_;

  std::map<int, HandEyeSample> samples_;  // by slot; accumulated poses get slots from 1000
  int next_slot_ = 1000;
  std::vector<Pose> plan_;  // auto: poses still to visit, next first
  size_t plan_next_ = 0;
  bool planned_ = false;
  std::atomic<size_t> pose_count_{0};  // samples_.size(), published after each change
  mutable std::mutex last_mutex_;
  std::optional<HandEyeSolution> last_;  // GUARDED_BY(last_mutex_)
};

}  // namespace bp
