// Face seeds (PoseSearch::face_seeds): for a view that is one plane (an
// L-bracket's plate, on which point pair features tie between every placement
// of the part's flat faces), the part with each of its large planar faces on
// the view's plane. Private to bp_pipeline. Frames: B base, O part. Metres.
#pragma once

#include <span>
#include <vector>

#include <Eigen/Core>

#include "pipeline/internal/ppf_matcher.h"
#include "pipeline/internal/verification.h"
#include "pipeline/pose_estimator.h"

namespace bp::internal {

struct PoseModel;

// Appends the `keep` best face seeds by a quick verification: the part with
// one of its planar faces on the view's plane (normal n, towards the camera),
// the face's principal axis along the view's principal axis or one of its
// longest hull edges (each in four quarter turns), placed so that the face's
// box holds the view's. scene: the view's finite points.
void AppendFaceSeeds(const PoseModel& model, std::span<const Eigen::Vector3f> scene, const Eigen::Vector3f& n,
                     const SceneView& view, const SceneSupport& support, const SegmentDepth& segment_depth, int keep,
                     std::vector<CoarsePose>& coarse);

}  // namespace bp::internal
