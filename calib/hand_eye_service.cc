#include "calib/hand_eye_service.h"

#include <spdlog/spdlog.h>

#include <chrono>
#include <cmath>
#include <ctime>
#include <iomanip>
#include <sstream>

#include "calib/board.h"

namespace bp {
namespace {

const char* KindName(CalibrationKind kind) {
  switch (kind) {
    case CalibrationKind::kManual: return "manual";
    case CalibrationKind::kAuto: return "auto";
    case CalibrationKind::kGuidance: return "guidance";
    case CalibrationKind::kAuto2D: return "auto-2d";
  }
  return "?";
}

std::string PoseYaml(const Pose& X) {
  const Quat q(X.linear());
  std::ostringstream os;
  os << std::setprecision(17) << "{xyz: [" << X.translation().x() << ", " << X.translation().y() << ", "
     << X.translation().z() << "], quat_wxyz: [" << q.w() << ", " << q.x() << ", " << q.y() << ", " << q.z() << "]}";
  return os.str();
}

std::string UtcNow() {
  const std::time_t now = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm tm{};
  gmtime_r(&now, &tm);
  std::ostringstream os;
  os << std::put_time(&tm, "%Y-%m-%dT%H:%M:%SZ");
  return os.str();
}

// A guidance pose adds nothing when it is this close to one already kept.
constexpr double kSameRotationDeg = 3.0;
constexpr double kSamePositionM = 0.01;

}  // namespace

HandEyeCalibrationService::HandEyeCalibrationService(const Cell& cell, std::shared_ptr<CalibrationCamera> camera,
                                                     std::shared_ptr<HandEyeState> state,
                                                     std::unique_ptr<CalibrationService> auto2d,
                                                     HandEyeServiceOptions options)
    : cell_(cell),
      spec_(cell.calibration.value_or(CalibrationSpec{})),
      camera_(std::move(camera)),
      state_(std::move(state)),
      auto2d_(std::move(auto2d)),
      options_(std::move(options)) {
  options_.write.keep_backup = true;
}

Status HandEyeCalibrationService::Start(CalibrationKind kind, const Pose& X_BF) {
  if (kind == CalibrationKind::kAuto2D) {
    if (!auto2d_) return Status::Unavailable("no 2D auto calibration service is configured");
    return auto2d_->Start(kind, X_BF);
  }
  samples_.clear();
  next_slot_ = 1000;
  plan_.clear();
  plan_next_ = 0;
  planned_ = false;
  PublishSession(kind);
  spdlog::info("calib: {} hand-eye calibration started", KindName(kind));
  return Status::Ok();
}

void HandEyeCalibrationService::PublishSession(CalibrationKind kind) {
  pose_count_.store(samples_.size(), std::memory_order_release);
  state_->SetSession(KindName(kind), static_cast<int>(samples_.size()));
}

Result<HandEyeSample> HandEyeCalibrationService::Observe(const Pose& X_BF) {
  Result<IntensityImage> image = camera_->CaptureBoard(X_BF);
  if (!image.ok()) return image.status();
  Result<BoardDetection> d = DetectBoard(*image, spec_, camera_->intrinsics());
  if (!d.ok()) return d.status();
  HandEyeSample s;
  s.X_BF = X_BF;
  s.X_CT = d->X_CT;
  s.corners = std::move(d->corners);
  return s;
}

std::vector<Pose> HandEyeCalibrationService::PlanAround(const Pose& X_BF, const Vec3& p_B, const Vec3& c_B,
                                                        int count) {
  const Vec3 view = (p_B - c_B).normalized();
  Vec3 a1 = view.cross(Vec3::UnitZ());
  if (a1.norm() < 0.1) a1 = view.cross(Vec3::UnitX());
  a1.normalize();
  const Vec3 a2 = view.cross(a1).normalized();
  // (axis, degrees) pairs: tilts across the view in four directions, turns
  // about the view, then mixtures, so every pair of poses differs by a
  // well-conditioned rotation.
  struct Turn {
    Vec3 axis;
    double deg;
  };
  const std::vector<Turn> turns = {
      {a1, 20},           {a2, 20},         {view, 30},       {a1, -20},         {a2, -20},
      {view, -30},        {a1 + a2, 18},    {a1 - a2, -18},   {a1 + view, 22},   {a2 - view, 22},
      {a1 - a2 + view, 16}, {a1 + a2 - view, -16}, {a2 + view, -22}, {a1 - view, -22}};
  std::vector<Pose> plan;
  for (int i = 0; i < count && i < static_cast<int>(turns.size()); ++i) {
    const Mat3 R = Eigen::AngleAxisd(turns[i].deg * M_PI / 180.0, turns[i].axis.normalized()).toRotationMatrix();
    // Rotate the robot about p_B: the board (or the camera's view of it) turns in place.
    Pose about = Pose::Identity();
    about.linear() = R;
    about.translation() = p_B - R * p_B;
    plan.push_back(about * X_BF);
  }
  return plan;
}

Result<CalibrationStep> HandEyeCalibrationService::Accumulate(CalibrationKind kind, const Pose& X_BF) {
  if (kind == CalibrationKind::kAuto2D) {
    if (!auto2d_) return Status::Unavailable("no 2D auto calibration service is configured");
    return auto2d_->Accumulate(kind, X_BF);
  }
  const int wanted = spec_.auto_poses;
  if (samples_.size() >= kMaxCalibrationPoses) {
    spdlog::warn("calib: {} pose not used: {} poses kept already (the cap)", KindName(kind),
                 kMaxCalibrationPoses);
    return Status::OutOfRange("calibration: " + std::to_string(kMaxCalibrationPoses) +
                              " poses already (the cap); finish or restart the calibration");
  }
  Result<HandEyeSample> sample = Observe(X_BF);
  CalibrationStep step;
  switch (kind) {
    case CalibrationKind::kManual:
      if (!sample.ok()) {
        spdlog::warn("calib: manual pose {} not used: {}", samples_.size() + 1, sample.status().message());
        return Status::NotFound("board not visible: " + sample.status().message());
      }
      samples_[next_slot_++] = std::move(*sample);
      PublishSession(kind);
      spdlog::info("calib: manual pose {} stored", samples_.size());
      return step;

    case CalibrationKind::kAuto: {
      if (sample.ok()) {
        if (!planned_) {
          // Plan around the first view: the board centre in the base, from
          // the detection and the hand-eye transform currently in use.
          const Pose X_hand_eye = state_->Get();
          const Pose X_BC = cell_.camera.eye_in_hand ? Pose(X_BF * X_hand_eye) : X_hand_eye;
          const Vec3 p_B = X_BC * (sample->X_CT * BoardCentre(spec_));
          plan_ = PlanAround(X_BF, p_B, X_BC.translation(), wanted - 1);
          planned_ = true;
        }
        samples_[next_slot_++] = std::move(*sample);
        PublishSession(kind);
        spdlog::info("calib: auto pose {} of {} stored", samples_.size(), wanted);
      } else {
        step.good = false;
        spdlog::warn("calib: auto pose not used (board not visible: {})", sample.status().message());
        if (!planned_) return Status::NotFound("board not visible from the start pose: " + sample.status().message());
      }
      if (static_cast<int>(samples_.size()) >= wanted || plan_next_ >= plan_.size()) {
        step.done = true;
      } else {
        step.next_X_BF = plan_[plan_next_++];
      }
      return step;
    }

    case CalibrationKind::kGuidance: {
      if (!sample.ok()) {
        step.good = false;
        const std::string reason = "board not visible (" + sample.status().message() + ")";
        spdlog::warn("calib: guidance pose BAD: {}", reason);
        state_->SetBadGuidance(reason);
        return step;
      }
      for (const auto& [slot, kept] : samples_) {
        if (RotationErrorDeg(kept.X_BF, X_BF) < kSameRotationDeg &&
            (kept.X_BF.translation() - X_BF.translation()).norm() < kSamePositionM) {
          step.good = false;
          std::ostringstream reason;
          reason << "within " << kSameRotationDeg << " deg and " << kSamePositionM * 1000
                 << " mm of a pose already kept; rotate the robot about another axis";
          spdlog::warn("calib: guidance pose BAD: {}", reason.str());
          state_->SetBadGuidance(reason.str());
          return step;
        }
      }
      samples_[next_slot_++] = std::move(*sample);
      PublishSession(kind);
      spdlog::info("calib: guidance pose GOOD ({} of {})", samples_.size(), wanted);
      step.done = static_cast<int>(samples_.size()) >= wanted;
      return step;
    }
    case CalibrationKind::kAuto2D:
      break;
  }
  return Status::InvalidArgument("unknown calibration kind");
}

Result<CalibrationStep> HandEyeCalibrationService::AccumulateInSlot(CalibrationKind kind, int slot, const Pose& X_BF) {
  if (kind == CalibrationKind::kAuto2D) return Accumulate(kind, X_BF);
  Result<HandEyeSample> sample = Observe(X_BF);
  if (!sample.ok()) {
    spdlog::warn("calib: pose for slot {} not used: {}", slot, sample.status().message());
    return Status::NotFound("board not visible: " + sample.status().message());
  }
  samples_[slot] = std::move(*sample);
  PublishSession(kind);
  spdlog::info("calib: pose stored in slot {} ({} poses)", slot, samples_.size());
  return CalibrationStep{};
}

Status HandEyeCalibrationService::Finish(CalibrationKind kind) {
  if (kind == CalibrationKind::kAuto2D) {
    if (!auto2d_) return Status::Unavailable("no 2D auto calibration service is configured");
    return auto2d_->Finish(kind);
  }
  if (static_cast<int>(samples_.size()) < spec_.min_poses) {
    return Status::InvalidArgument("hand-eye calibration needs " + std::to_string(spec_.min_poses) +
                                      " poses with the board in view, got " + std::to_string(samples_.size()) +
                                      "; the previous calibration stays in use");
  }
  std::vector<HandEyeSample> samples;
  for (const auto& [slot, s] : samples_) samples.push_back(s);
  HandEyeOptions o;
  o.eye_in_hand = cell_.camera.eye_in_hand;
  Result<HandEyeSolution> sol = SolveHandEye(samples, spec_, camera_->intrinsics(), o);
  if (!sol.ok()) return sol.status();
  if (Status s = Persist(*sol); !s.ok()) return s;
  HandEyeResultInfo info;
  info.time = std::chrono::system_clock::now();
  info.kind = KindName(kind);
  info.method = sol->method;
  info.poses = sol->poses;
  info.residual_rms_mm = sol->residual_rms_mm;
  info.residual_max_mm = sol->residual_max_mm;
  info.residual_rms_deg = sol->residual_rms_deg;
  info.residual_max_deg = sol->residual_max_deg;
  info.reprojection_rms_px = sol->reprojection_rms_px;
  state_->SetResult(sol->X, std::move(info));
  {
    std::lock_guard lock(last_mutex_);
    last_ = *sol;
  }
  spdlog::info("calib: {} calibration solved from {} poses ({} pairs, {}): residuals {:.3f} mm / {:.4f} deg RMS, "
               "{:.3f} mm / {:.4f} deg max, reprojection {:.3f} px",
               KindName(kind), sol->poses, sol->pairs, sol->method, sol->residual_rms_mm, sol->residual_rms_deg,
               sol->residual_max_mm, sol->residual_max_deg, sol->reprojection_rms_px);
  return Status::Ok();
}

Status HandEyeCalibrationService::Persist(const HandEyeSolution& sol) const {
  if (options_.result_file.empty()) {
    spdlog::warn("calib: no result file (camera.hand_eye_file): the calibration is used but not saved");
    return Status::Ok();
  }
  const bool eih = cell_.camera.eye_in_hand;
  std::ostringstream y;
  y << std::setprecision(10);
  y << "# binpick hand-eye calibration (loaded as camera.hand_eye_file; only `pose` is read)\n";
  y << "pose: " << PoseYaml(sol.X) << "   # " << (eih ? "X_FC" : "X_BC") << "\n";
  y << "mount: " << (eih ? "eye_in_hand" : "eye_to_hand") << "\n";
  y << "timestamp: " << UtcNow() << "\n";
  y << "method: " << sol.method << "\n";
  y << "residuals: {rms_mm: " << sol.residual_rms_mm << ", max_mm: " << sol.residual_max_mm
    << ", rms_deg: " << sol.residual_rms_deg << ", max_deg: " << sol.residual_max_deg
    << ", reprojection_rms_px: " << sol.reprojection_rms_px << "}\n";
  y << "target: {squares: [" << spec_.cols << ", " << spec_.rows << "], square_size: " << spec_.square_size << "}\n";
  y << "target_pose: " << PoseYaml(sol.Y) << "   # " << (eih ? "X_BT" : "X_FT") << "\n";
  y << "poses_used:   # X_BF of each view\n";
  for (const auto& [slot, s] : samples_) y << "  - " << PoseYaml(s.X_BF) << "\n";
  return WriteFileAtomic(options_.result_file, y.str(), options_.write);
}

}  // namespace bp
