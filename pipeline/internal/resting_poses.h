// The orientations in which a part rests on a flat floor, and the pose seeds
// they give for a view on the bin floor (PoseSearch::resting_seeds: the last
// parts of a bin, lying in views PPF voting cannot resolve). Private to
// bp_pipeline. Frames: O part, B base. Metres.
#pragma once

#include <span>
#include <vector>

#include <Eigen/Core>

#include "core/cell.h"
#include "core/mesh.h"
#include "pipeline/internal/model_sampling.h"
#include "pipeline/internal/ppf_matcher.h"

namespace bp::internal {

struct PoseModel;

struct RestingPose {
  Eigen::Vector3f down;  // unit, in O, pointing into the floor
  float depth = 0;       // largest down . p over the samples: the contact height
  // Seed anchors (AnchorRestingPoses), over the PPF samples: the centroid of
  // the samples within 3 mm of the top, and of the upward faces.
  Eigen::Vector3f top_O = Eigen::Vector3f::Zero();
  Eigen::Vector3f up_O = Eigen::Vector3f::Zero();
};

// The orientations in which the part rests on a flat floor. Candidates are
// the mesh's face normals (merged within 1 deg); one is a resting direction d
// (pointing into the floor) when the samples `pts` within `tol` of the lowest
// in that direction span an area whose convex hull holds the projection of
// the centroid (so the part neither tips nor rolls). Directions within 3 deg
// are one, and so are directions a symmetry of the part maps onto each other.
std::vector<RestingPose> RestingPoses(const TriangleMesh& mesh, std::span<const Eigen::Vector3f> pts,
                                      const Eigen::Vector3f& centroid, const Symmetry& symmetry, float tol);

// Sets each resting pose's seed anchors (top_O, up_O) over `samples`.
void AnchorRestingPoses(const OrientedPoints& samples, std::vector<RestingPose>& rests);

// The lowest upward face of the part over its resting orientations: the
// smallest height above the floor of a sample whose normal is within
// acos(min_up) of up (what a floor band of that height would erase);
// infinity when no sample faces up. Metres.
double LowestUpwardFace(const OrientedPoints& samples, const std::vector<RestingPose>& rests, float min_up);

// Appends the part lying on `plane` (n, d: n . x + d = 0, n towards the
// parts) in each of the model's resting orientations, its top over the view's
// top: at 10 deg steps of yaw plus the two yaws that align its top-view
// principal axis with the view's, plus tilted copies when the view's upward
// faces tilt (a part leaning on a neighbour). scene: the view's points;
// sub_p / sub_n: its subsampled points and their normals (towards the
// camera).
void AppendRestingSeeds(const PoseModel& model, std::span<const Eigen::Vector3f> scene,
                        std::span<const Eigen::Vector3f> sub_p, std::span<const Eigen::Vector3f> sub_n,
                        const Eigen::Vector4d& plane, std::vector<CoarsePose>& coarse);

}  // namespace bp::internal
