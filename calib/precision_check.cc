#include "calib/precision_check.h"

#include <spdlog/spdlog.h>

#include "calib/board.h"

namespace bp {

PrecisionCheckPlanner::PrecisionCheckPlanner(std::shared_ptr<GraspPlanner> inner, const Cell& cell,
                                             std::shared_ptr<CalibrationCamera> camera,
                                             std::shared_ptr<HandEyeState> state)
    : inner_(std::move(inner)),
      eye_in_hand_(cell.camera.eye_in_hand),
      spec_(cell.calibration.value_or(CalibrationSpec{})),
      camera_(std::move(camera)),
      state_(std::move(state)) {}

Result<double> PrecisionCheckPlanner::CheckPrecision(const PlanRequest& request) {
  if (eye_in_hand_ && !request.X_BF) {
    return Status::InvalidArgument("an eye-in-hand precision check needs the robot pose");
  }
  const Pose X_BF = request.X_BF.value_or(Pose::Identity());
  Result<IntensityImage> image = camera_->CapturePrecisionTarget(X_BF);
  if (!image.ok()) return image.status();
  Result<BoardDetection> d = DetectBoard(*image, spec_, camera_->intrinsics());
  if (!d.ok()) return Status::NotFound("precision target not found: " + d.status().message());
  const Pose hand_eye = state_->Get();
  const Pose X_BC = eye_in_hand_ ? Pose(X_BF * hand_eye) : hand_eye;
  const Vec3 p_B = X_BC * (d->X_CT * BoardCentre(spec_));
  std::lock_guard lock(mutex_);
  auto it = references_.find(request.task.id);
  if (it == references_.end() || !it->second.hand_eye.isApprox(hand_eye, 1e-12)) {
    references_[request.task.id] = {p_B, hand_eye};
    spdlog::info("calib: precision check of task {} defined: target at [{:.4f}, {:.4f}, {:.4f}] m", request.task.id,
                 p_B.x(), p_B.y(), p_B.z());
    return 0.0;
  }
  const double error_mm = (p_B - it->second.p_B).norm() * 1000.0;
  spdlog::info("calib: precision check of task {}: {:.3f} mm", request.task.id, error_mm);
  return error_mm;
}

}  // namespace bp
