// What PoseEstimator::Build derives from a part's mesh, read by every step of
// an estimate (docs/perception.md). Built once, then read
// concurrently. Private to bp_pipeline. Frames: O part, B base. Metres.
#pragma once

#include <cstdint>
#include <span>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "core/cell.h"
#include "core/pose.h"
#include "pipeline/internal/closest_point_field.h"
#include "pipeline/internal/model_sampling.h"
#include "pipeline/internal/near_symmetries.h"
#include "pipeline/internal/planar_faces.h"
#include "pipeline/internal/point_to_plane_icp.h"
#include "pipeline/internal/ppf_matcher.h"
#include "pipeline/internal/resting_poses.h"
#include "pipeline/pose_estimator.h"

namespace bp::internal {

struct PoseModel {
  // Unique in the process (never reused): what a PreparedView was made by.
  uint64_t id = 0;
  PoseEstimatorOptions options;
  Symmetry symmetry;
  double diameter = 0;  // of the dense samples
  float step = 0;       // PPF sampling distance
  Eigen::Vector3f centroid_O = Eigen::Vector3f::Zero();  // of the dense samples
  OrientedPoints dense;                                  // ICP targets (Morton order)
  std::vector<EdgePlane> edge_planes;                    // per dense sample
  ClosestPointField field;                               // over the dense samples
  OrientedPoints verify;                                 // verification samples
  OrientedPoints ppf_points;                             // PPF model points
  // ExtremePoints of ppf_points and of verify: the support-plane tests.
  std::vector<Eigen::Vector3f> ppf_extreme, verify_extreme;
  PpfModel ppf;
  std::vector<RestingPose> rests;  // PoseSearch::resting_seeds
  std::vector<PlanarFace> faces;   // PoseSearch::face_seeds
  // PoseEstimatorOptions::hole_max_filled; only those farther than
  // hole_margin from the rest of the part's surface.
  std::vector<HolePoint> holes;
  std::vector<Pose> near_symmetries;  // PoseEstimatorOptions::near_symmetry_min_overlap
  std::vector<TurnAxis> turn_axes;    // PoseEstimatorOptions::turn_step_deg
  double thinnest_plate = 0;          // ThinnestPlate of the faces; infinity: none
  double lowest_upward_face = 0;      // LowestUpwardFace of the dense samples (cos 18 deg); infinity: none

  // The closest-point field's bounding sphere (ClosestPointField::grid_radius)
  // at X_BO: centre in B, squared radius.
  std::pair<Eigen::Vector3f, float> FieldSphere(const Pose& X_BO) const {
    const float r = field.grid_radius();
    return {(X_BO * field.grid_centre().cast<double>()).cast<float>(), r * r};
  }
  // True when q (in O) lies within tol of the part's surface (the nearest
  // dense sample through the closest-point field; false beyond its band).
  bool OnSurface(const Eigen::Vector3f& q, float tol) const {
    const int idx = field.Lookup(q);
    return idx >= 0 && (q - dense.points[static_cast<size_t>(idx)]).squaredNorm() <= tol * tol;
  }
  // A scene point supports the part within this of its dense surface samples.
  float SupportTolerance() const {
    return static_cast<float>(options.support_distance + 0.5 * options.icp_model_spacing);
  }
  // Points of `scene` within SupportTolerance of the part at X_BO, as a fraction.
  double ExplainedFraction(const Pose& X_BO, std::span<const Eigen::Vector3f> scene) const {
    if (scene.empty()) return 0.0;
    const Pose X_OB = X_BO.inverse();
    const Eigen::Matrix3f R = X_OB.linear().cast<float>();
    const Eigen::Vector3f t = X_OB.translation().cast<float>();
    const float tol = SupportTolerance();
    size_t on = 0;
    for (const Eigen::Vector3f& p : scene) on += OnSurface(R * p + t, tol) ? 1 : 0;
    return static_cast<double>(on) / static_cast<double>(scene.size());
  }
  // Point-to-plane ICP of scene points (B) onto the dense samples from X_BO.
  IcpResult Refine(std::span<const Eigen::Vector3f> scene, std::span<const uint8_t> boundary, const Pose& X_BO,
                   const Vec3& camera_B, float initial, float final_gate, int iterations, double convergence) const {
    IcpModel model{dense.points, dense.normals, &field, edge_planes};
    IcpOptions o;
    o.shrink_iterations = options.icp_shrink_iterations;
    o.boundary = boundary;
    o.iterations = iterations;
    o.initial_distance = initial;
    o.final_distance = final_gate;
    o.convergence = static_cast<float>(convergence);
    return RefinePointToPlane(model, scene, X_BO, camera_B, o);
  }
};

}  // namespace bp::internal
