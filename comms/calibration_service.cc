#include "comms/calibration_service.h"

#include <string>

namespace bp {

Status CountingCalibrationService::Start(CalibrationKind /*kind*/, const Pose& /*X_BF*/) {
  poses_.clear();
  return Status::Ok();
}

Result<CalibrationStep> CountingCalibrationService::Accumulate(CalibrationKind kind,
                                                               const Pose& X_BF) {
  if (poses_.size() >= kMaxCalibrationPoses) {
    return Status::OutOfRange("calibration: " + std::to_string(kMaxCalibrationPoses) +
                              " poses already (the cap); finish or restart the calibration");
  }
  poses_.push_back(X_BF);
  CalibrationStep step;
  step.done = kind != CalibrationKind::kManual &&
              static_cast<int>(poses_.size()) >= poses_needed_;
  if (kind == CalibrationKind::kAuto || kind == CalibrationKind::kAuto2D) step.next_X_BF = X_BF;
  return step;
}

Status CountingCalibrationService::Finish(CalibrationKind /*kind*/) { return Status::Ok(); }

}  // namespace bp
