// The planner of pick_2d tasks (issue 9): capture the top-view image, detect
// the flat parts (twod/detector_2d.h), pose each part's 2D grasps (cell
// parts[].flat_2d.grasps) in the plane and drop those whose gripper footprint
// (grippers[].footprint) overlaps a neighbouring blob.
//
// Grasps are plane poses: Grasp::X_BT is X_PT, the tool in the robot-defined
// plane P with z = the part's thickness (the robot overwrites z) and the tool
// turned by the grasp angle about the plane normal, approaching along -z_P
// (R = Rz(theta) * Rx(pi)). X_BT_pre equals X_BT; X_BO is the part in P.
//
// TaskKindPlanner routes pick_2d requests to a Plane2DPlanner and everything
// else to the 3D planner, so the server's request path is unchanged.
//
// Thread-safety: as GraspPlanner (grasp/planner.h); per-task state is locked.
#pragma once

#include <map>
#include <memory>
#include <mutex>
#include <vector>

#include "core/cell.h"
#include "grasp/planner.h"
#include "twod/detector_2d.h"
#include "twod/plane_calibration.h"
#include "twod/plane_camera.h"

namespace bp {

// A plane pose as the 6D tool pose sent to the robot.
Pose PlanePose(const Pose2D& X_PT, double z);
// A part lying in the plane as a 3D pose (z = 0, turned about z_P).
Pose PartPose(const Pose2D& X_PO);
// The plane pose back from a tool pose (x, y and the rotation about z_P of a
// tool pointing down).
Pose2D ToPose2D(const Pose& X_PT);

class Plane2DPlanner final : public GraspPlanner {
 public:
  Plane2DPlanner(const Cell& cell, std::shared_ptr<PlaneCamera> camera,
                 std::shared_ptr<PlaneCalibrationStore> calibration, Detector2DOptions options = {});

  Result<CaptureHandle> Capture(const PlanRequest& request) override;
  // @returns Unavailable when there is no 2D calibration yet (the server then
  // answers no objects).
  Result<PlanResult> Plan(const PlanRequest& request, const CapturedScene& scene) override;
  void NotifyHandedOut(const TaskSpec& task, const Grasp& grasp) override;

 private:
  Cell cell_;
  std::shared_ptr<PlaneCamera> camera_;
  std::shared_ptr<PlaneCalibrationStore> calibration_;
  Detector2D detector_;
  std::mutex mutex_;
  // Per task: the truth instance behind each grasp's instance_id of the
  // last plan (synthetic scenes), for simulated picks. GUARDED_BY(mutex_)
  std::map<int, std::map<int, int>> truth_of_instance_;
};

class TaskKindPlanner final : public GraspPlanner {
 public:
  // `planner_3d` may be null (then non-2D tasks answer Unavailable).
  TaskKindPlanner(std::unique_ptr<GraspPlanner> planner_3d, std::unique_ptr<GraspPlanner> planner_2d)
      : planner_3d_(std::move(planner_3d)), planner_2d_(std::move(planner_2d)) {}
  Result<CaptureHandle> Capture(const PlanRequest& request) override;
  Result<PlanResult> Plan(const PlanRequest& request, const CapturedScene& scene) override;
  Result<PlanResult> PlanWithHead(const PlanRequest& request, const CapturedScene& scene,
                                  const HeadReady& on_head) override;
  void NotifyHandedOut(const TaskSpec& task, const Grasp& grasp) override;
  Status Teach(const TeachRequest& request) override;
  Result<double> CheckPrecision(const PlanRequest& request) override;

 private:
  GraspPlanner* For(const TaskSpec& task) const;
  std::unique_ptr<GraspPlanner> planner_3d_;
  std::unique_ptr<GraspPlanner> planner_2d_;
};

// binpickd's wiring of 2D tasks.
bool HasPick2DTask(const Cell& cell);
bool OnlyPick2DTasks(const Cell& cell);
struct Plane2DSetup {
  std::shared_ptr<PlaneCamera> camera;            // shared by the planner and the calibration
  std::shared_ptr<PlaneCalibrationStore> store;   // the calibration both use
};
// A synthetic top-view camera scattered with source.num_parts parts
// (source.seed), and the calibration from camera.plane_calibration_file when
// that file exists. @returns its error when the file exists but is invalid.
Result<Plane2DSetup> MakePlane2DSetup(const Cell& cell);
// A TaskKindPlanner: pick_2d tasks to a Plane2DPlanner on `setup`, the rest
// to `planner_3d` (may be null when every task is pick_2d).
std::unique_ptr<GraspPlanner> WithPlane2DPlanner(const Cell& cell, std::unique_ptr<GraspPlanner> planner_3d,
                                                 const Plane2DSetup& setup);

}  // namespace bp
