// Near symmetries of a part: transforms F of O that are not symmetries of
// the part but map most of its surface onto its surface (an L-bracket turned
// over about its upright, whose base is then hidden under it, looks the same
// from above but for the upright's hole). Candidates are the 180 deg turns
// about each large planar face's normal through its centre, about each
// plate's in-plane axes through its mid-plane and (arm_swaps) about the
// bisector of two arms' end faces through their junction; those that keep at least
// PoseEstimatorOptions::near_symmetry_min_overlap of the surface, the
// max_near_symmetries that keep the most, none that the declared symmetry
// covers. Private to bp_pipeline. Frame: O part.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "core/pose.h"

namespace bp::internal {

struct PoseModel;

// Most overlap first. Reads the model's faces, field, dense and verify
// samples, centroid, diameter, symmetry and options.
std::vector<Pose> FindNearSymmetries(const PoseModel& model);

// An axis the part is nearly round about (a pipe's run): turned about it by
// any multiple of PoseEstimatorOptions::turn_step_deg, the part keeps at
// least near_symmetry_min_overlap of its surface on its surface. Seen from a
// side that hides what is not round (a tee's branch), the turns explain a
// view equally well.
struct TurnAxis {
  Eigen::Vector3f point = Eigen::Vector3f::Zero();      // on the axis, in O
  Eigen::Vector3f direction = Eigen::Vector3f::UnitX();  // unit
  // The part turned about the axis by angle_rad: X_O'O applied as X_BO * Turn.
  Pose Turn(double angle_rad) const;
};

// Candidates are the normals of the large planar faces through their box
// centres (a tube's end faces), one per line; none the declared symmetry
// covers (a revolute part's axis). Empty with turn_step_deg 0.
std::vector<TurnAxis> FindTurnAxes(const PoseModel& model);

}  // namespace bp::internal
