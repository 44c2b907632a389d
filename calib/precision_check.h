// RC_PRECISION_CHECK (50): a GraspPlanner decorator answering CheckPrecision
// from the precision target (calibration.precision_target, a board fixed in
// the base). The first check of a task defines it: the target's position in
// the base, measured through the hand-eye transform in use, is recorded as
// the reference and the error is 0. Each later check re-detects the target
// and returns the distance (mm) of its centre from the reference: a camera
// that moved since shows up as that error. A new hand-eye calibration
// redefines the references. Everything else goes to the wrapped planner.
//
// The references survive a restart: each one defined is written atomically
// to options.reference_file (default next to the hand-eye file,
// PrecisionReferenceFile) and LoadReferences reads them back at start-up, so
// the first check after a restart measures against the reference defined
// before it. File format: docs/file_formats.md "Precision-check references".
//
// Thread-safety: as GraspPlanner (the handler calls CheckPrecision under its
// capture lock); the references are guarded by a mutex.
#pragma once

#include <map>
#include <memory>
#include <mutex>
#include <string>

#include "calib/calibration_camera.h"
#include "calib/hand_eye_service.h"
#include "grasp/planner.h"

namespace bp {

struct PrecisionCheckOptions {
  // Where the references are kept; empty: in memory only.
  std::string reference_file;
  AtomicWriteOptions write;
};

// The reference file next to the cell's hand-eye file ("x.yaml" ->
// "x.precision.yaml"); empty when the cell has no hand-eye file.
std::string PrecisionReferenceFile(const Cell& cell);

class PrecisionCheckPlanner final : public GraspPlanner {
 public:
  PrecisionCheckPlanner(std::shared_ptr<GraspPlanner> inner, const Cell& cell,
                        std::shared_ptr<CalibrationCamera> camera, std::shared_ptr<HandEyeState> state,
                        PrecisionCheckOptions options = {});

  // Reads options.reference_file if it exists (a missing file: no
  // references yet). Corruption naming the file and the reason otherwise.
  Status LoadReferences();

  Result<CaptureHandle> Capture(const PlanRequest& request) override { return inner_->Capture(request); }
  Result<PlanResult> Plan(const PlanRequest& request, const CapturedScene& scene) override {
    return inner_->Plan(request, scene);
  }
  Result<PlanResult> PlanWithHead(const PlanRequest& request, const CapturedScene& scene,
                                  const HeadReady& on_head) override {
    return inner_->PlanWithHead(request, scene, on_head);
  }
  void NotifyHandedOut(const TaskSpec& task, const Grasp& grasp) override { inner_->NotifyHandedOut(task, grasp); }
  Status Teach(const TeachRequest& request) override { return inner_->Teach(request); }
  // NotFound when the target is not detected (answered 52).
  Result<double> CheckPrecision(const PlanRequest& request) override;

 private:
  struct Reference {
    Vec3 p_B;         // target centre in the base when the check was defined
    Pose hand_eye;    // the hand-eye transform it was measured with
  };
  std::shared_ptr<GraspPlanner> inner_;
  const bool eye_in_hand_;
  const CalibrationSpec spec_;
  std::shared_ptr<CalibrationCamera> camera_;
  std::shared_ptr<HandEyeState> state_;
  const PrecisionCheckOptions options_;
  // REQUIRES: mutex_ held. Writes references_ to options_.reference_file.
  Status SaveReferences() const;
  std::mutex mutex_;
  std::map<int, Reference> references_;  // GUARDED_BY(mutex_); by task id
};

}  // namespace bp
