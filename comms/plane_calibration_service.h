// The 2D auto calibration behind RC 11 / 12 (CalibrationKind::kAuto2D; issue
// 9, docs/protocols.md "2D tasks"). Other kinds answer Unavailable: the 3D
// hand-eye service forwards kAuto2D calls here.
//
// The robot carries a marker at its tool centre point through a grid of
// points of its plane. Start records the robot's centre pose; every
// Accumulate captures the marker at the pose the robot sent (X_PT, tool in
// the plane) and proposes the next grid point (same orientation and z). A
// view without the marker is an error at the start pose (the robot is asked
// again there) and skipped at a grid point (step.good false, the next point
// proposed). After the last point it fits the image -> plane calibration
// (twod/plane_calibration.h) with the points it has and reports done; Finish
// publishes it to the store and writes it atomically (keeping a .bak), or
// returns why there is none (the fit failed, or the calibration ended early).
//
// Thread-safety: the request handler serializes the calls.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "comms/calibration_service.h"
#include "twod/plane_calibration.h"
#include "twod/plane_camera.h"

namespace bp {

struct PlaneCalibrationOptions {
  int grid_x = 5, grid_y = 4;          // points in the plane (row-major from -x, -y)
  double span_x = 0.36, span_y = 0.24;  // m, grid extent centred on the start pose
  std::string file;                     // where to persist; empty = memory only
};

class PlaneCalibrationService final : public CalibrationService {
 public:
  PlaneCalibrationService(std::shared_ptr<PlaneCamera> camera, std::shared_ptr<PlaneCalibrationStore> store,
                          PlaneCalibrationOptions options);
  Status Start(CalibrationKind kind, const Pose& X_PT) override;
  Result<CalibrationStep> Accumulate(CalibrationKind kind, const Pose& X_PT) override;
  Status Finish(CalibrationKind kind) override;

  // The last successful fit of this calibration run, for reports and tests.
  const std::optional<PlaneCalibration>& last() const { return last_; }

 private:
  Pose GridPose(size_t i) const;
  std::shared_ptr<PlaneCamera> camera_;
  std::shared_ptr<PlaneCalibrationStore> store_;
  PlaneCalibrationOptions options_;
  bool running_ = false;
  bool centre_seen_ = false;  // the start pose's view has the marker
  size_t visited_ = 0;        // grid points visited (seen or skipped)
  Status fit_error_;          // the last fit's failure, reported by Finish
  Pose X_PT_centre_ = Pose::Identity();
  std::vector<Eigen::Vector2d> pixels_, plane_xy_;
  std::optional<PlaneCalibration> last_;
};

}  // namespace bp
