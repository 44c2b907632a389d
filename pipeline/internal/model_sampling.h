// Surface sampling of triangle meshes for the pose estimator: area-weighted
// random samples with exact face normals, and normal-aware voxel downsampling.
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>  // core/mesh.h uses AlignedBox3f / Affine3f

#include "core/mesh.h"

namespace bp::internal {

struct OrientedPoints {
  std::vector<Eigen::Vector3f> points;
  std::vector<Eigen::Vector3f> normals;  // unit, outward
  size_t size() const { return points.size(); }
};

// The mesh's surface area, m^2 (degenerate and out-of-range triangles: 0).
double SurfaceArea(const TriangleMesh& mesh);

// About area / spacing^2 random points (seeded), each with its face normal.
// Degenerate (zero-area) triangles are skipped.
OrientedPoints SampleSurface(const TriangleMesh& mesh, double spacing, uint64_t seed);

// One point per voxel and normal cluster: within a voxel, points whose normals
// differ by more than max_normal_angle_deg from every existing cluster start a
// new one (keeps both sides of thin walls and sharp edges). Each output point
// is the centroid of its cluster with the normalised mean normal.
OrientedPoints VoxelDownsample(const OrientedPoints& in, double voxel, double max_normal_angle_deg);

// Largest pairwise distance (exact on up to 4000 points, strided beyond).
double PointSetDiameter(std::span<const Eigen::Vector3f> points);

}  // namespace bp::internal
