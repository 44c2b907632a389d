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
  fit_error_ = Status::Ok();
  X_PT_centre_ = X_PT;
  centre_seen_ = false;
  visited_ = 0;
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
  Result<Eigen::Vector2d> marker = image.ok() ? FindMarker(image->image) : Result<Eigen::Vector2d>(image.status());
  CalibrationStep step;
  if (!marker.ok()) {
    // At the start pose: asked again there. At a grid point: skipped.
    if (!centre_seen_) return marker.status();
    spdlog::warn("2D calibration: grid point {} skipped: {}", visited_, marker.status().message());
    step.good = false;
  } else {
    pixels_.push_back(*marker);
    plane_xy_.push_back(X_PT.translation().head<2>());
  }
  // The start pose, then every grid point.
  if (!centre_seen_) {
    centre_seen_ = true;
  } else {
    ++visited_;
  }
  const size_t grid = static_cast<size_t>(options_.grid_x * options_.grid_y);
  if (visited_ < grid) {
    step.next_X_BF = GridPose(visited_);
    return step;
  }
  // The grid is done: fit now, so that Finish publishes or reports why not.
  running_ = false;
  Result<PlaneCalibration> fit = FitPlaneCalibration(camera_->intrinsics(), pixels_, plane_xy_);
  if (fit.ok()) {
    spdlog::info("2D calibration: {} points, residual {:.3f} mm rms, {:.3f} mm max", fit->points,
                 fit->residual_rms_mm, fit->residual_max_mm);
    last_ = *fit;
  } else {
    fit_error_ = fit.status();
  }
  step.done = true;
  return step;
}

Status PlaneCalibrationService::Finish(CalibrationKind kind) {
  if (kind != CalibrationKind::kAuto2D) return Status::Unavailable("the 2D calibration service handles RC 11/12 only");
  running_ = false;
  if (!fit_error_.ok()) return fit_error_;
  if (!last_) return Status::InvalidArgument("2D calibration: ended before the grid was complete; the previous calibration stays in use");
  store_->Set(*last_);
  if (!options_.file.empty()) return SavePlaneCalibration(*last_, options_.file);
  return Status::Ok();
}

}  // namespace bp
