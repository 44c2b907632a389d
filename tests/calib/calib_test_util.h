// Cells for the calibration tests: the embedded default (eye-to-hand) and an
// eye-in-hand variant of it.
#pragma once

#include <string>

#include "core/cell.h"

namespace bp::testing {

inline Cell CalibCell(bool eye_in_hand) {
  Result<Cell> cell = LoadDefaultCell();
  if (!cell.ok()) std::abort();
  Cell c = *cell;
  if (eye_in_hand) {
    c.camera.eye_in_hand = true;
    // Camera 10 cm ahead of the flange along its z, looking along it.
    c.camera.X_FC = MakePose(Mat3::Identity(), Vec3(0.0, 0.05, 0.1));
    CalibrationSpec& s = *c.calibration;
    s.true_pose = MakePose(Mat3(Eigen::AngleAxisd(0.01, Vec3(1, 2, 3).normalized())), Vec3(0.0012, 0.0483, 0.1021));
    // Board fixed on the table, facing up (its z down, into the table).
    s.target_pose = MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), Vec3(0.5, 0.2, 0.05));
    s.precision_target = MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), Vec3(0.5, 0.2, 0.05));
    // Robot poses on the DaoAI wire are floor(10000 * value): 0.1 mm and
    // 1e-4 rad steps, which an eye-in-hand solve feels directly; 15 poses.
    s.auto_poses = 15;
  }
  return c;
}

}  // namespace bp::testing
