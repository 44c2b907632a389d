#include "calib/hand_eye_state.h"

#include <algorithm>
#include <cmath>
#include <ctime>
#include <iomanip>
#include <sstream>

namespace bp {
namespace {

std::string Utc(std::chrono::system_clock::time_point t) {
  const std::time_t s = std::chrono::system_clock::to_time_t(t);
  std::tm tm{};
  gmtime_r(&s, &tm);
  std::ostringstream os;
  os << std::put_time(&tm, "%Y-%m-%dT%H:%M:%SZ");
  return os.str();
}

// xyz in mm and fixed-axis roll, pitch, yaw in degrees (R = Rz * Ry * Rx, as
// the cell's rpy_deg).
std::string PoseText(const Pose& X) {
  const Mat3 R = X.linear();
  const double roll = std::atan2(R(2, 1), R(2, 2));
  const double pitch = std::asin(std::clamp(-R(2, 0), -1.0, 1.0));
  const double yaw = std::atan2(R(1, 0), R(0, 0));
  constexpr double kDeg = 180.0 / M_PI;
  // No "-0.000" for a component that prints as zero.
  auto shown = [](double v, double unit) { return std::abs(v) < 5e-4 / unit ? 0.0 : v * unit; };
  std::ostringstream os;
  os << std::fixed << std::setprecision(2) << "xyz [" << shown(X.translation().x(), 1000) << ", "
     << shown(X.translation().y(), 1000) << ", " << shown(X.translation().z(), 1000) << "] mm, rpy ["
     << std::setprecision(3) << shown(roll, kDeg) << ", " << shown(pitch, kDeg) << ", " << shown(yaw, kDeg)
     << "] deg";
  return os.str();
}

std::string Fixed(double v, int digits) {
  std::ostringstream os;
  os << std::fixed << std::setprecision(digits) << v;
  return os.str();
}

}  // namespace

std::vector<std::pair<std::string, std::string>> HandEyeStatusRows(const HandEyeSnapshot& s, bool eye_in_hand) {
  std::vector<std::pair<std::string, std::string>> rows;
  rows.emplace_back(eye_in_hand ? "hand-eye X_FC in use" : "hand-eye X_BC in use", PoseText(s.X));
  rows.emplace_back("hand-eye from", s.origin);
  rows.emplace_back("mode", s.mode);
  rows.emplace_back("poses accumulated", std::to_string(s.poses));
  if (s.last_result) {
    const HandEyeResultInfo& r = *s.last_result;
    rows.emplace_back("last calibration", Utc(r.time) + " (" + r.kind + ", " + std::to_string(r.poses) +
                                              " poses, " + r.method + ")");
    rows.emplace_back("residuals rms / max", Fixed(r.residual_rms_mm, 3) + " / " + Fixed(r.residual_max_mm, 3) +
                                                 " mm, " + Fixed(r.residual_rms_deg, 4) + " / " +
                                                 Fixed(r.residual_max_deg, 4) + " deg");
    rows.emplace_back("reprojection rms", Fixed(r.reprojection_rms_px, 3) + " px");
  } else {
    rows.emplace_back("last calibration", "none since start");
  }
  if (s.last_bad_guidance) {
    rows.emplace_back("last bad guidance pose (13)",
                      Utc(s.last_bad_guidance->time) + ": " + s.last_bad_guidance->reason);
  }
  return rows;
}

}  // namespace bp
