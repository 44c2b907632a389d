// Geometry helpers of the pose estimator's model building and seeding: 2D
// convex hulls, plane frames, extreme points, sample ordering, half turns and
// the planes across convex sharp edges. Private to bp_pipeline. Frames: O
// part (model samples), B base. Metres.
#pragma once

#include <span>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "core/pose.h"
#include "pipeline/internal/model_sampling.h"
#include "pipeline/internal/point_to_plane_icp.h"

namespace bp::internal {

// 2D convex hull (Andrew's monotone chain), counter-clockwise.
std::vector<Eigen::Vector2f> ConvexHull2(std::vector<Eigen::Vector2f> p);

// An orthonormal basis (u, v) of the plane normal to unit d.
std::pair<Eigen::Vector3f, Eigen::Vector3f> PlaneBasis(const Eigen::Vector3f& d);

// Centroid *c of pts, their in-plane principal axes (u, v = n x u) in the
// plane normal to unit n, and the box [lo, hi] of their (u, v) coordinates
// about c.
void PlaneFrame(std::span<const Eigen::Vector3f> pts, const Eigen::Vector3f& n, Eigen::Vector3f* c,
                Eigen::Vector3f* u, Eigen::Vector3f* v, Eigen::Vector2f* lo, Eigen::Vector2f* hi);

// The points of `pts` that are lowest along one of ~2500 directions spread
// over the sphere: nearly the convex hull's vertices. The minimum of a linear
// function over `pts` (how deep a pose sinks the part into a plane) is then
// taken over these alone, off the exact minimum by at most
// radius * (1 - cos(2 deg)), 0.04 mm for a part of 130 mm.
std::vector<Eigen::Vector3f> ExtremePoints(std::span<const Eigen::Vector3f> pts);

// Reorders the samples along a Morton (Z-order) curve over 2 mm cells, so
// that samples near each other in space are near each other in memory (ICP
// reads the samples a view's points map to).
void SortByMortonCode(OrientedPoints& s);

// The 180 deg turn about the line through c along unit axis a.
Pose HalfTurn(const Eigen::Vector3f& a, const Eigen::Vector3f& c);

// Per dense sample near a convex sharp edge, the plane of the face across
// the edge (neighbours within 2.5 spacing whose normal is more than 30 deg
// off and that lie below the sample's tangent plane; their mean normal and
// offset); an invalid EdgePlane elsewhere. spacing: the samples', metres.
std::vector<EdgePlane> BuildEdgePlanes(const OrientedPoints& dense, double spacing);

}  // namespace bp::internal
