// Near symmetries of a part: transforms F of O that are not symmetries of
// the part but map most of its surface onto its surface (an L-bracket turned
// over about its upright, whose base is then hidden under it, looks the same
// from above but for the upright's hole). Candidates are the 180 deg turns
// about each large planar face's normal through its centre and about each
// plate's in-plane axes through its mid-plane; those that keep at least
// PoseEstimatorOptions::near_symmetry_min_overlap of the surface, the
// max_near_symmetries that keep the most, none that the declared symmetry
// covers. Private to bp_pipeline. Frame: O part.
#pragma once

#include <vector>

#include "core/pose.h"

namespace bp::internal {

struct PoseModel;

// Most overlap first. Reads the model's faces, field, dense and verify
// samples, centroid, diameter, symmetry and options.
std::vector<Pose> FindNearSymmetries(const PoseModel& model);

}  // namespace bp::internal
