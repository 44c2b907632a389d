#include "twod/planner_2d.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>

namespace bp {
namespace {

class PlaneScene final : public CapturedScene {
 public:
  explicit PlaneScene(PlaneImage image) : image(std::move(image)) {}
  std::string Describe() const override {
    return "2D image " + std::to_string(image.image.width) + "x" + std::to_string(image.image.height);
  }
  PlaneImage image;
};

double Ms(std::chrono::steady_clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace

Pose PlanePose(const Pose2D& X_PT, double z) {
  const Mat3 R = Eigen::AngleAxisd(X_PT.theta, Vec3::UnitZ()).toRotationMatrix() *
                 Eigen::AngleAxisd(M_PI, Vec3::UnitX()).toRotationMatrix();
  return MakePose(R, Vec3(X_PT.x, X_PT.y, z));
}

Pose PartPose(const Pose2D& X_PO) {
  return MakePose(Mat3(Eigen::AngleAxisd(X_PO.theta, Vec3::UnitZ())), Vec3(X_PO.x, X_PO.y, 0.0));
}

Pose2D ToPose2D(const Pose& X_PT) {
  // x axis of the tool projected on the plane: Rz(theta) Rx(pi) keeps x = Rz(theta) e_x.
  const Vec3 x = X_PT.linear().col(0);
  return {X_PT.translation().x(), X_PT.translation().y(), std::atan2(x.y(), x.x())};
}

Plane2DPlanner::Plane2DPlanner(const Cell& cell, std::shared_ptr<PlaneCamera> camera,
                               std::shared_ptr<PlaneCalibrationStore> calibration, Detector2DOptions options)
    : cell_(cell), camera_(std::move(camera)), calibration_(std::move(calibration)), detector_(cell, options) {}

Result<CaptureHandle> Plane2DPlanner::Capture(const PlanRequest& /*request*/) {
  Result<PlaneImage> image = camera_->Capture(PlaneCaptureRequest{});
  if (!image.ok()) return image.status();
  return CaptureHandle(std::make_shared<const PlaneScene>(std::move(*image)));
}

Result<PlanResult> Plane2DPlanner::Plan(const PlanRequest& request, const CapturedScene& scene) {
  const auto* plane = dynamic_cast<const PlaneScene*>(&scene);
  if (!plane) return Status::InvalidArgument("2D planner: the scene is not a 2D capture");
  const std::shared_ptr<const PlaneCalibration> calibration = calibration_->Get();
  if (!calibration) return Status::Unavailable("2D planner: no 2D calibration (run RC 11/12 first)");
  const TaskSpec& task = request.task;
  const GripperSpec* gripper = cell_.FindGripper(task.gripper);
  if (!gripper) return Status::InvalidArgument("2D planner: unknown gripper '" + task.gripper + "'");

  PlanResult result;
  auto t0 = std::chrono::steady_clock::now();
  Result<Detect2DResult> detected = detector_.Detect(plane->image.image, *calibration, task.part_classes);
  if (!detected.ok()) return detected.status();
  result.stages.push_back({"detect_2d", Ms(t0)});
  t0 = std::chrono::steady_clock::now();
  result.roi_points = detected->foreground_pixels;
  result.image_pixels = static_cast<int64_t>(plane->image.image.width) * plane->image.image.height;
  result.largest_region_points = detected->largest_blob_pixels;
  result.detections = static_cast<int>(detected->parts.size());

  // Best-matching detections first.
  std::vector<size_t> order(detected->parts.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
    return detected->parts[a].score > detected->parts[b].score;
  });

  std::map<int, int> truth_of;
  for (size_t k : order) {
    const Detection2D& d = detected->parts[k];
    const PartSpec* part = cell_.FindPart(d.class_id);
    result.parts.push_back({d.class_id, PartPose(d.X_PO), d.score});
    // Ground truth (synthetic scenes): the nearest part of the class.
    int truth = -1;
    double nearest = 0.01;
    for (const FlatPartTruth& t : plane->image.truth) {
      const double dist = (t.X_PO.xy() - d.X_PO.xy()).norm();
      if (t.class_id == d.class_id && dist < nearest) {
        nearest = dist;
        truth = t.instance_id;
      }
    }
    for (const Grasp2DSpec& g : part->flat_2d->grasps) {
      if (g.gripper != task.gripper) continue;
      const Pose2D X_PT = d.X_PO.Compose({g.xy.x(), g.xy.y(), g.angle});
      // Footprint (top view in T) into the plane: T is Rz(theta) Rx(pi), so
      // (x, y) in T lands at Rz(theta) (x, -y).
      std::vector<Eigen::Vector2d> footprint_P;
      for (const Eigen::Vector2d& f : gripper->footprint) footprint_P.push_back(X_PT.Apply({f.x(), -f.y()}));
      bool collides = false;
      for (size_t b = 0; b < detected->blobs_P.size() && !collides; ++b) {
        if (static_cast<int>(b) == detected->part_blob[k]) continue;
        collides = PolygonsOverlap(footprint_P, detected->blobs_P[b]);
      }
      if (collides) continue;
      Grasp grasp;
      grasp.X_BT = PlanePose(X_PT, part->flat_2d->thickness);
      grasp.X_BT_pre = grasp.X_BT;
      grasp.X_BO = PartPose(d.X_PO);
      grasp.instance_id = static_cast<int>(k);
      grasp.class_id = d.class_id;
      grasp.score = d.score;
      grasp.name = g.name;
      result.grasps.push_back(std::move(grasp));
      if (truth >= 0) truth_of[static_cast<int>(k)] = truth;
      break;  // one grasp per part
    }
  }
  result.stages.push_back({"grasps_2d", Ms(t0)});
  result.outcome = result.detections == 0    ? PlanResult::Outcome::kNoObjects
                   : result.grasps.empty()   ? PlanResult::Outcome::kNoCollisionFree
                                             : PlanResult::Outcome::kGrasps;
  result.message = std::to_string(result.detections) + " parts in 2D, " + std::to_string(result.grasps.size()) +
                   " collision-free";
  {
    std::lock_guard<std::mutex> lock(mutex_);
    truth_of_instance_[task.id] = std::move(truth_of);
  }
  return result;
}

void Plane2DPlanner::NotifyHandedOut(const TaskSpec& task, const Grasp& grasp) {
  int truth = -1;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto& m = truth_of_instance_[task.id];
    if (auto it = m.find(grasp.instance_id); it != m.end()) truth = it->second;
  }
  if (truth >= 0 && cell_.source.simulate_picks) camera_->RemovePart(truth);
}

GraspPlanner* TaskKindPlanner::For(const TaskSpec& task) const {
  return task.kind == TaskSpec::Kind::kPick2D ? planner_2d_.get() : planner_3d_.get();
}

Result<CaptureHandle> TaskKindPlanner::Capture(const PlanRequest& request) {
  GraspPlanner* p = For(request.task);
  if (!p) return Status::Unavailable("no planner for this task kind");
  return p->Capture(request);
}

Result<PlanResult> TaskKindPlanner::Plan(const PlanRequest& request, const CapturedScene& scene) {
  GraspPlanner* p = For(request.task);
  if (!p) return Status::Unavailable("no planner for this task kind");
  return p->Plan(request, scene);
}

Result<PlanResult> TaskKindPlanner::PlanWithHead(const PlanRequest& request, const CapturedScene& scene,
                                                 const HeadReady& on_head) {
  GraspPlanner* p = For(request.task);
  if (!p) return Status::Unavailable("no planner for this task kind");
  return p->PlanWithHead(request, scene, on_head);
}

void TaskKindPlanner::NotifyHandedOut(const TaskSpec& task, const Grasp& grasp) {
  if (GraspPlanner* p = For(task)) p->NotifyHandedOut(task, grasp);
}

Status TaskKindPlanner::Teach(const TeachRequest& request) {
  GraspPlanner* p = For(request.task);
  return p ? p->Teach(request) : Status::Unavailable("no planner for this task kind");
}

Result<double> TaskKindPlanner::CheckPrecision(const PlanRequest& request) {
  GraspPlanner* p = For(request.task);
  if (!p) return Status::Unavailable("no planner for this task kind");
  return p->CheckPrecision(request);
}

bool HasPick2DTask(const Cell& cell) {
  return std::any_of(cell.tasks.begin(), cell.tasks.end(),
                     [](const TaskSpec& t) { return t.kind == TaskSpec::Kind::kPick2D; });
}

bool OnlyPick2DTasks(const Cell& cell) {
  return std::all_of(cell.tasks.begin(), cell.tasks.end(),
                     [](const TaskSpec& t) { return t.kind == TaskSpec::Kind::kPick2D; });
}

Result<Plane2DSetup> MakePlane2DSetup(const Cell& cell) {
  Result<std::unique_ptr<SyntheticPlaneCamera>> camera = SyntheticPlaneCamera::Create(cell);
  if (!camera.ok()) return camera.status();
  if (Status s = (*camera)->Scatter(cell.source.num_parts, cell.source.seed, cell.source.part_classes); !s.ok()) {
    return s;
  }
  Plane2DSetup setup;
  setup.camera = std::shared_ptr<PlaneCamera>(std::move(*camera));
  setup.store = std::make_shared<PlaneCalibrationStore>();
  if (!cell.camera.plane_calibration_file.empty()) {
    Result<PlaneCalibration> loaded = LoadPlaneCalibration(cell.camera.plane_calibration_file);
    if (loaded.ok()) {
      spdlog::info("2D calibration {}: {} points, residual {:.3f} mm rms", cell.camera.plane_calibration_file,
                   loaded->points, loaded->residual_rms_mm);
      setup.store->Set(std::move(*loaded));
    } else if (loaded.status().code() == Status::Code::kNotFound) {
      spdlog::warn("2D calibration {} does not exist yet: pick_2d picks are answered -1 until RC 11/12 ran",
                   cell.camera.plane_calibration_file);
    } else {
      return loaded.status();
    }
  }
  return setup;
}

std::unique_ptr<GraspPlanner> WithPlane2DPlanner(const Cell& cell, std::unique_ptr<GraspPlanner> planner_3d,
                                                 const Plane2DSetup& setup) {
  return std::make_unique<TaskKindPlanner>(std::move(planner_3d),
                                           std::make_unique<Plane2DPlanner>(cell, setup.camera, setup.store));
}

}  // namespace bp
