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
  // Exact up to 6000 vertices (O(n^2)); above that an extreme-point estimate
  // D' with 0.997 D <= D' <= D in O(1024 n) (see mesh.cc).
  double Diameter() const;
  // Total surface area, m^2.
  double Area() const;
  // Appends other, transformed by X (rotation + translation).
  void Append(const TriangleMesh& other, const Eigen::Affine3f& X = Eigen::Affine3f::Identity());
};

// @returns Corruption / NotFound / InvalidArgument with the file name on error.
Result<TriangleMesh> LoadMesh(const std::string& path);
// The length unit a mesh file's header declares, if any: "millimetres",
// "centimetres", "inches" or "metres" from a PLY comment or obj_info line,
// a binary STL's 80-byte header or an ASCII STL's solid line (words such as
// "mm", "millimeter", "units=cm", "inch"); "" when it declares none or the
// file cannot be read. binpick meshes are in metres.
std::string MeshUnitHint(const std::string& path);
// Writes binary little-endian PLY.
Status SaveMeshPly(const TriangleMesh& mesh, const std::string& path);

}  // namespace bp
