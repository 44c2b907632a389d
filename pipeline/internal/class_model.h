// The seam between the perception pipeline and the pose estimator: one
// ClassModel per part class turns a segment into verified hypotheses.
// Private to bp_pipeline.
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "core/cell.h"
#include "core/pose.h"
#include "core/status.h"
#include "pipeline/frame.h"
#include "pipeline/internal/part_settings.h"
#include "pipeline/internal/pose_search.h"
#include "pipeline/pose_estimator.h"

namespace bp::internal {

// What a class model sees of one segment (points and normals in B).
struct SegmentView {
  std::span<const Eigen::Vector3f> points_B;
  std::span<const Eigen::Vector3f> normals_B;  // same size as points_B, or empty
  const Frame* frame = nullptr;                // for the camera pose and the depth image
  std::optional<Eigen::Vector4d> floor_plane_B;  // (n, d): n . x + d = 0, n towards the parts
  std::optional<PoseSearch> search;              // unset: the estimator's default search
  SearchReuse reuse;                             // from an earlier estimate of the same view
};

// The estimator's view of it: the points and normals, the frame's camera
// pose and (organized frames) depth image and intrinsics, the floor plane.
SceneView SceneOf(const SegmentView& view);

struct ClassHypothesis {
  Pose X_BO = Pose::Identity();
  double score = 0.0;
  double visible_fraction = 0.0;
  double rms_residual = 0.0;
  // Of the part's seen samples (visible, not occluded), those in free space
  // in front of the measured surface (PoseHypothesis::free_space_points).
  double free_space_fraction = 0.0;
  std::vector<int> support;  // indices into SegmentView::points_B
  std::vector<Pose> alternatives;  // PoseHypothesis::alternatives
};

struct ClassEstimate {
  std::vector<ClassHypothesis> hypotheses;  // verified, best first
  std::string reason;                       // when empty
  SearchTrace trace;                        // for a later estimate of the same view
};

// Thread-safe: Estimate is called concurrently for different segments.
class ClassModel {
 public:
  virtual ~ClassModel() = default;
  virtual int class_id() const = 0;
  virtual double diameter() const = 0;
  // Extents of the model surface along its principal axes, metres, largest first.
  virtual Eigen::Vector3f extents() const = 0;
  // PlanarShare of the part seen from 64 directions: least and most.
  virtual std::pair<float, float> planar_share_range() const = 0;
  // Centroid of the part's surface in its own frame O, metres.
  virtual Eigen::Vector3f centroid_O() const = 0;
  virtual ClassEstimate Estimate(const SegmentView& view) const = 0;
  // Verification alone of the part at X_BO against the view (diagnostics);
  // score -1 when the pose sinks the part into the floor.
  virtual Result<PoseHypothesis> Score(const SegmentView& view, const Pose& X_BO) const = 0;
  // See PoseEstimator::MarkOnSurface.
  virtual void MarkOnSurface(const Pose& X_BO, std::span<const Eigen::Vector3f> points_B, float tolerance,
                             std::vector<uint8_t>* on_surface) const = 0;
  // See PoseEstimator::CountInside.
  virtual size_t CountInside(const Pose& X_BO, std::span<const Eigen::Vector3f> points_B, float min_depth) const = 0;
  // Model surface samples in O (verification spacing).
  virtual std::span<const Eigen::Vector3f> surface_points_O() const = 0;
  // How deep (metres) a point must lie in the part's material to count as
  // inside it (CountInside for acceptance): 1 mm, or 0.4 of its thinnest
  // plate when that is thinner (the closest-point field sees the nearer
  // face of a wall past half its thickness).
  virtual float inside_depth() const = 0;
  // The lowest upward face of the part lying on the floor
  // (internal::LowestUpwardFace), metres; infinity when none.
  virtual double lowest_upward_face() const = 0;
  // The estimator's options in use (scaled to the part and the camera).
  virtual const PoseEstimatorOptions& estimator_options() const = 0;
  // Whether two poses of the part differ by more than the ambiguity
  // tolerance (PoseEstimatorOptions::ambiguity_translation and
  // ambiguity_rotation_deg, the strict evaluation tolerance) modulo the
  // part's symmetry: whether one may be the other's alternative
  // (Detection::alternatives_X_BO). A model without a symmetry compares the
  // poses as they are.
  virtual bool DistinctPoses(const Pose& a, const Pose& b) const;
  // Whether the part is nearly round about an axis (PoseEstimator::turn_axes).
  virtual bool has_turn_axes() const { return false; }
  // internal::ChooseTurn on the view; a model without turn axes returns X_BO
  // unjudged (net 0).
  virtual TurnChoice ChooseTurn(const SegmentView& view, const Pose& X_BO, std::span<const Pose> others,
                                double step_deg) const {
    (void)view;
    (void)others;
    (void)step_deg;
    return {X_BO};
  }
};

// Extents of points along their principal axes (PCA), largest first, metres.
// The largest is a lower bound of the set's diameter (max pairwise distance).
// Non-finite points are ignored; fewer than 2 points give zero.
Eigen::Vector3f PrincipalExtents(std::span<const Eigen::Vector3f> points);

// The weighted share of `normals` (unit) within 15 degrees of one of their
// two main directions (greedy modes): near 1 for one or two planes (an
// L-bracket's plates), lower for curved surfaces (a pipe). At most 128
// normals (strided) are used, the modes sought among 32 of them. Non-finite normals are ignored; fewer than 2
// give 0. weights: per normal, or empty for 1 each.
float PlanarShare(std::span<const Eigen::Vector3f> normals, std::span<const float> weights = {});

// PlanarShare of a part's outward surface normals (area-uniform samples, O)
// seen from `directions` directions spread over the sphere, each normal
// weighted by its cosine to the direction (the depth image samples a face in
// proportion to its projected area): least and most over the directions.
std::pair<float, float> ModelPlanarShareRange(std::span<const Eigen::Vector3f> normals_O, int directions);

// Pre-filter: false when the segment cannot be (part of) one instance of the
// class, i.e. its extent along its first principal axis (a lower bound of its
// diameter) exceeds the model's diameter plus a tolerance for sensor noise.
bool SegmentFitsClass(const Eigen::Vector3f& segment_extents, double model_diameter);

// Builds the model of one part class: loads the mesh, refuses one in the
// wrong unit (CheckMeshScale), scales the estimator's options to the part
// and the camera (ScaledEstimatorOptions, then the part's overrides) and
// builds the tables. @returns the mesh loader's error, or InvalidArgument
// naming the part.
// camera = {}: the reference camera (the options unscaled for it).
Result<std::unique_ptr<ClassModel>> BuildClassModel(const PartSpec& part, const CameraFigures& camera = {},
                                                    const PoseEstimatorOptions& reference = {});

}  // namespace bp::internal
