#include "comms/plane_calibration_service.h"

#include <spdlog/spdlog.h>

#include "twod/detector_2d.h"

namespace bp {

PlaneCalibrationService::PlaneCalibrationService(std::shared_ptr<PlaneCamera> camera,
                                                 std::shared_ptr<PlaneCalibrationStore> store,
                                                 PlaneCalibrationOptions options)
    : camera_(std::move(camera)), store_(std::move(store)), options_(std::move(options)) {}

Pose PlaneCalibrationService::GridPose(size_t i) const {
  const int nx = options_.grid_x, ny = options_.grid_y;
  const int ix = static_cast<int>(i) % nx, iy = static_cast<int>(i) / nx;
  Pose X = X_PT_centre_;
  X.translation().x() += options_.span_x * (nx > 1 ? static_cast<double>(ix) / (nx - 1) - 0.5 : 0.0);
  X.translation().y() += options_.span_y * (ny > 1 ? static_cast<double>(iy) / (ny - 1) - 0.5 : 0.0);
  return X;
}

Status PlaneCalibrationService::Start(CalibrationKind kind, const Pose& X_PT) {
  if (kind != CalibrationKind::kAuto2D) return Status::Unavailable("the 2D calibration service handles RC 11/12 only");
  running_ = true;
  last_.reset();
  X_PT_centre_ = X_PT;
  pixels_.clear();
  plane_xy_.clear();
  return Status::Ok();
}

Result<CalibrationStep> PlaneCalibrationService::Accumulate(CalibrationKind kind, const Pose& X_PT) {
  if (kind != CalibrationKind::kAuto2D) return Status::Unavailable("the 2D calibration service handles RC 11/12 only");
  if (!running_) return Status::InvalidArgument("2D calibration: accumulate before start");
  PlaneCaptureRequest request;
  request.marker_X_PT = X_PT;
  Result<PlaneImage> image = camera_->Capture(request);
  if (!image.ok()) return image.status();
  Result<Eigen::Vector2d> marker = FindMarker(image->image);
  if (!marker.ok()) return marker.status();  // the pose is not counted: the robot is asked again
  pixels_.push_back(*marker);
  plane_xy_.push_back(X_PT.translation().head<2>());
  // The start pose, then every grid point.
  const size_t total = static_cast<size_t>(options_.grid_x * options_.grid_y) + 1;
  CalibrationStep step;
  if (pixels_.size() < total) {
    step.next_X_BF = GridPose(pixels_.size() - 1);
    return step;
  }
  // Fit now so that a failed fit is answered as a failed step, not as DONE.
  running_ = false;
  Result<PlaneCalibration> fit = FitPlaneCalibration(camera_->intrinsics(), pixels_, plane_xy_);
  if (!fit.ok()) return fit.status();
  spdlog::info("2D calibration: {} points, residual {:.3f} mm rms, {:.3f} mm max", fit->points,
               fit->residual_rms_mm, fit->residual_max_mm);
  last_ = *fit;
  step.done = true;
  return step;
}

Status PlaneCalibrationService::Finish(CalibrationKind kind) {
  if (kind != CalibrationKind::kAuto2D) return Status::Unavailable("the 2D calibration service handles RC 11/12 only");
  running_ = false;
  if (!last_) return Status::InvalidArgument("2D calibration: finished before the grid was complete");
  store_->Set(*last_);
  if (!options_.file.empty()) return SavePlaneCalibration(*last_, options_.file);
  return Status::Ok();
}

}  // namespace bp
