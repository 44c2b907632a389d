// The part's large planar faces and the holes they enclose, found once per
// part from its mesh: face seeds lay a face on a planar view
// (PoseSearch::face_seeds), near symmetries turn the part about them, and
// verification checks the holes (PoseEstimatorOptions::hole_max_filled).
// Private to bp_pipeline. Frame: O part. Metres.
#pragma once

#include <vector>

#include <Eigen/Core>

#include "core/mesh.h"
#include "pipeline/internal/model_sampling.h"

namespace bp::internal {

// A planar face of the part.
struct PlanarFace {
  Eigen::Vector3f n = Eigen::Vector3f::UnitZ();  // outward unit normal, O
  Eigen::Vector3f c = Eigen::Vector3f::Zero();   // centroid of the face's samples, O
  Eigen::Vector3f u = Eigen::Vector3f::UnitX();  // in-plane principal axis (largest extent)
  Eigen::Vector3f v = Eigen::Vector3f::UnitY();  // n x u
  Eigen::Vector2f lo = Eigen::Vector2f::Zero(), hi = Eigen::Vector2f::Zero();  // samples' box in (u, v) about c
};

// A face is "large" when both its extents are at least this, metres: it can
// seed poses and carry a near symmetry.
constexpr float kMinFaceExtent = 0.015f;

// A point of a planar face's plane in one of its holes.
struct HolePoint {
  Eigen::Vector3f p;  // O
  Eigen::Vector3f n;  // the face's outward normal, O
};

// The part's large planar faces: mesh triangles whose normals agree within
// 2 deg and whose planes within 0.6 mm, each group with the dense samples on
// it. Appends to *holes (optional) the points of each face's plane that the
// face encloses but does not cover, at least hole_margin from it (a bore, a
// bracket's hole; not the notch of an L-shaped face), on a 1 mm grid
// (coarser for faces of more than 250k grid points).
std::vector<PlanarFace> PlanarFaces(const TriangleMesh& mesh, const OrientedPoints& dense, float hole_margin,
                                    std::vector<HolePoint>* holes);

// The thinnest plate among the faces: the smallest distance between a face
// and an antiparallel face behind it whose centre falls inside its box;
// infinity when there is none. Metres.
double ThinnestPlate(const std::vector<PlanarFace>& faces);

}  // namespace bp::internal
