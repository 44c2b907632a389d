// Triangle meshes (parts, bin, grippers). Vertices in metres, in the model's own
// frame. Loaded from PLY (ASCII or binary) or STL (binary or ASCII).
#pragma once

#include <Eigen/Geometry>  // AlignedBox3f, Affine3f
#include <string>
#include <vector>

#include "core/status.h"

namespace bp {

struct TriangleMesh {
  std::vector<Eigen::Vector3f> vertices;
  std::vector<Eigen::Vector3i> triangles;  // counter-clockwise seen from outside

  bool empty() const { return triangles.empty(); }
  Eigen::AlignedBox3f Bounds() const;
  // Largest distance between two vertices (the part "diameter" used by ADD-S).
  double Diameter() const;
  // Total surface area, m^2.
  double Area() const;
  // Appends other, transformed by X (rotation + translation).
  void Append(const TriangleMesh& other, const Eigen::Affine3f& X = Eigen::Affine3f::Identity());
};

// @returns Corruption / NotFound / InvalidArgument with the file name on error.
Result<TriangleMesh> LoadMesh(const std::string& path);
// Writes binary little-endian PLY.
Status SaveMeshPly(const TriangleMesh& mesh, const std::string& path);

}  // namespace bp
