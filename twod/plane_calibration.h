// The image -> plane mapping of 2D tasks (issue 9, docs/protocols.md "2D
// tasks"). The robot defines a plane P (x, y in the plane, z its normal); a
// tool-mounted marker is carried through points of the plane and seen by a
// fixed camera. From those pairs (pixel, plane xy) we fit a homography from
// undistorted normalized image coordinates to the plane, lens distortion taken
// from the camera intrinsics, and decompose it into the plane's pose in the
// camera (X_CP) so that points above the plane (a part's top face) map too.
//
// Thread-safety: PlaneCalibration is an immutable value; PlaneCalibrationStore
// is internally locked.
#pragma once

#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/cell.h"
#include "core/pose.h"
#include "core/status.h"

namespace bp {

struct PlaneCalibration {
  Intrinsics intrinsics;          // camera model at calibration time (distortion included)
  Eigen::Matrix3d H_PN = Eigen::Matrix3d::Identity();  // normalized undistorted (x, y, 1) -> plane (x, y, 1), m
  Pose X_CP = Pose::Identity();   // plane in camera (refined from H_PN)
  double residual_rms_mm = 0.0;   // plane-space error of the fit points
  double residual_max_mm = 0.0;
  int points = 0;

  // Pixel (u, v) -> point of the plane frame at `height` above the plane (m):
  // undistort, then intersect the viewing ray with z = height in P.
  Eigen::Vector2d PixelToPlane(const Eigen::Vector2d& uv, double height = 0.0) const;
  std::vector<Eigen::Vector2d> PixelsToPlane(const std::vector<Eigen::Vector2d>& uv,
                                             double height = 0.0) const;
};

// Fits a calibration from >= 4 pairs (pixel, plane xy in m) in general
// position. @returns InvalidArgument for fewer points, mismatched sizes or a
// degenerate configuration (e.g. all points on a line).
Result<PlaneCalibration> FitPlaneCalibration(const Intrinsics& K,
                                             const std::vector<Eigen::Vector2d>& pixels,
                                             const std::vector<Eigen::Vector2d>& plane_xy);

// YAML text (docs/file_formats.md "2D calibration") and back. Parse errors
// name `path`, the key and the reason (Corruption / InvalidArgument).
std::string SerializePlaneCalibration(const PlaneCalibration& calibration);
Result<PlaneCalibration> ParsePlaneCalibration(const std::string& text, const std::string& path);
// Atomic replace, the previous file kept as <path>.bak (core/atomic_file.h).
Status SavePlaneCalibration(const PlaneCalibration& calibration, const std::string& path);
// @returns NotFound when the file does not exist.
Result<PlaneCalibration> LoadPlaneCalibration(const std::string& path);

// The current calibration shared by the calibration service (writer) and the
// 2D planner (reader).
class PlaneCalibrationStore {
 public:
  std::shared_ptr<const PlaneCalibration> Get() const {
    std::lock_guard<std::mutex> lock(mutex_);
    return current_;
  }
  void Set(PlaneCalibration calibration) {
    auto next = std::make_shared<const PlaneCalibration>(std::move(calibration));
    std::lock_guard<std::mutex> lock(mutex_);
    current_ = std::move(next);
  }

 private:
  mutable std::mutex mutex_;
  std::shared_ptr<const PlaneCalibration> current_;  // GUARDED_BY(mutex_); null: not calibrated
};

}  // namespace bp
