// Point-to-plane ICP (Gauss-Newton on a 6-DoF twist) of scene points in B onto
// the model's dense surface samples in O, with O(1) closest points from a
// precomputed ClosestPointField. Correspondences beyond a distance gate that
// shrinks over the iterations, or on model points facing away from the camera,
// are ignored. Thread-safe (pure function of its inputs).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include <Eigen/Core>

#include "core/pose.h"
#include "pipeline/internal/closest_point_field.h"

namespace bp::internal {

struct EdgePlane {
  Eigen::Vector3f n = Eigen::Vector3f::Zero();
  float c = 0;
  bool valid() const { return n.squaredNorm() > 0.5f; }
};

struct IcpModel {
  std::span<const Eigen::Vector3f> points_O;
  std::span<const Eigen::Vector3f> normals_O;
  const ClosestPointField* field = nullptr;
  // Per sample (optional): for samples near a convex sharp edge, the plane
  // of the face on the other side of the edge (n . x = c, outward normal);
  // n = 0 for all other samples. See IcpOptions::boundary.
  std::span<const EdgePlane> edge_planes_O;
};

struct IcpOptions {
  int iterations = 20;
  float initial_distance = 0.005f;  // metres; gate at the first iteration
  float final_distance = 0.002f;    // metres; gate from iteration shrink_iterations on
  // The gate shrinks geometrically over this many iterations (at most
  // `iterations`; 0: min(iterations / 3, 6)). Until it is final, the closest
  // sample is the voxel's own and the loop does not stop.
  int shrink_iterations = 0;
  int min_correspondences = 12;
  // Stop once an iteration (at the final gate) changes the point-to-plane
  // residuals and the boundary residuals each by less than this RMS, metres
  // (> 0). A limit on the residuals, not the step: the discrete closest
  // points make the last iterations cycle with steps of 3-40 um.
  float convergence = 2e-5f;
  // Optional per-scene-point flags (1 = on the boundary of the segment's
  // surface). A boundary point whose closest model sample lies at a convex
  // sharp edge adds a one-sided term with this weight: its distance beyond
  // the plane of the face across the edge (beyond its own face's plane too
  // when that face is turned away), zero when it is inside. It pulls the
  // model's silhouette edge out to the scene's boundary and is zero at the
  // true pose, which constrains the sliding that point-to-plane alone leaves
  // free (a disc or a box face seen head-on). Only convex edges count, so
  // concave corners beside occlusion boundaries cannot bias it.
  std::span<const uint8_t> boundary;
  float boundary_weight = 1.0f;
};

struct IcpResult {
  Pose X_BO = Pose::Identity();
  double rms = 0;        // point-to-plane RMS over the final inliers, metres
  int inliers = 0;       // correspondences within the final gate
  int iterations = 0;
  bool ok = false;       // false: too few correspondences (X_BO is the input)
};

IcpResult RefinePointToPlane(const IcpModel& model, std::span<const Eigen::Vector3f> scene_B, const Pose& X_BO,
                             const Vec3& camera_B, const IcpOptions& options);

}  // namespace bp::internal
