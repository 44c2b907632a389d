#include "calib/precision_check.h"

#include <spdlog/spdlog.h>
#include <yaml-cpp/yaml.h>

#include <filesystem>
#include <iomanip>
#include <sstream>

#include "calib/board.h"

namespace bp {

std::string PrecisionReferenceFile(const Cell& cell) {
  if (cell.camera.hand_eye_file.empty()) return {};
  std::filesystem::path p(cell.camera.hand_eye_file);
  p.replace_extension(".precision.yaml");
  return p.string();
}

PrecisionCheckPlanner::PrecisionCheckPlanner(std::shared_ptr<GraspPlanner> inner, const Cell& cell,
                                             std::shared_ptr<CalibrationCamera> camera,
                                             std::shared_ptr<HandEyeState> state,
                                             PrecisionCheckOptions options)
    : inner_(std::move(inner)),
      eye_in_hand_(cell.camera.eye_in_hand),
      spec_(cell.calibration.value_or(CalibrationSpec{})),
      camera_(std::move(camera)),
      state_(std::move(state)),
      options_(std::move(options)) {}

Status PrecisionCheckPlanner::LoadReferences() {
  const std::string& file = options_.reference_file;
  std::error_code ec;
  if (file.empty() || !std::filesystem::exists(file, ec)) return Status::Ok();
  auto bad = [&file](const std::string& why) {
    return Status::Corruption(file + ": " + why + " (precision-check references)");
  };
  std::map<int, Reference> loaded;
  try {
    const YAML::Node root = YAML::LoadFile(file);
    const YAML::Node list = root["references"];
    if (!list || !list.IsSequence()) return bad("no 'references' list");
    for (const YAML::Node& r : list) {
      if (!r.IsMap() || !r["task"] || !r["target_B"] || !r["hand_eye"]) {
        return bad("a reference needs task, target_B and hand_eye");
      }
      const int task = r["task"].as<int>();
      const auto p = r["target_B"].as<std::vector<double>>();
      const auto m = r["hand_eye"].as<std::vector<double>>();
      if (p.size() != 3) return bad("task " + std::to_string(task) + ": target_B needs 3 numbers");
      if (m.size() != 16) return bad("task " + std::to_string(task) + ": hand_eye needs 16 numbers (4x4, row-major)");
      Reference ref;
      ref.p_B = Vec3(p[0], p[1], p[2]);
      Eigen::Matrix4d M;
      for (int i = 0; i < 16; ++i) M(i / 4, i % 4) = m[i];
      ref.hand_eye.matrix() = M;
      const Mat3 R = ref.hand_eye.linear();
      if (!(R * R.transpose()).isApprox(Mat3::Identity(), 1e-6) || R.determinant() < 0) {
        return bad("task " + std::to_string(task) + ": hand_eye is not a rigid transform");
      }
      if (loaded.count(task)) return bad("task " + std::to_string(task) + " appears twice");
      loaded[task] = ref;
    }
  } catch (const YAML::Exception& e) {
    return bad(e.what());
  }
  std::lock_guard lock(mutex_);
  references_ = std::move(loaded);
  spdlog::info("calib: {} precision-check reference(s) loaded from {}", references_.size(), file);
  return Status::Ok();
}

Status PrecisionCheckPlanner::SaveReferences() const {
  if (options_.reference_file.empty()) return Status::Ok();
  std::ostringstream y;
  y << std::setprecision(17);
  y << "# binpick precision-check references (RC 50): the target centre in the base (m) when each\n"
       "# task's check was defined, and the hand-eye transform (4x4 row-major) it was measured with.\n";
  y << "references:\n";
  for (const auto& [task, ref] : references_) {
    y << "  - task: " << task << "\n";
    y << "    target_B: [" << ref.p_B.x() << ", " << ref.p_B.y() << ", " << ref.p_B.z() << "]\n";
    y << "    hand_eye: [";
    for (int i = 0; i < 16; ++i) y << (i ? ", " : "") << ref.hand_eye.matrix()(i / 4, i % 4);
    y << "]\n";
  }
  return WriteFileAtomic(options_.reference_file, y.str(), options_.write);
}

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
    // A reference that cannot be saved still serves this run.
    if (Status s = SaveReferences(); !s.ok()) {
      spdlog::error("calib: precision-check reference not saved: {}", s.ToString());
    }
    return 0.0;
  }
  const double error_mm = (p_B - it->second.p_B).norm() * 1000.0;
  spdlog::info("calib: precision check of task {}: {:.3f} mm", request.task.id, error_mm);
  return error_mm;
}

}  // namespace bp
