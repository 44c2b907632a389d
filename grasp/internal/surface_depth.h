// Private to bp_grasp: where the detected parts' surfaces lie along chosen
// pixels' rays of an organized frame, for the dropout rays of the point
// obstacle (GraspPlanningOptions::dropout_reach): the space behind a detected
// part's surface, seen from the camera, is that part (already an obstacle),
// so an unseen ray ends where it meets one; and where the rays leave a
// part, for the space it hides (hidden_behind_parts).
//
// Frames (STYLE.md): B base, C camera, O part. Depth is the metric z in C
// (not the ray length), as DepthImage holds it; pixel (u, v) looks along
// ((u - cx) / fx, (v - cy) / fy, 1) in C (pinhole, no distortion: Deproject).
#pragma once

#include <cstdint>
#include <span>
#include <vector>

#include "core/cell.h"
#include "core/mesh.h"
#include "core/pose.h"

namespace bp::internal {

// A mesh (in its own frame O) placed in B.
struct PlacedMesh {
  const TriangleMesh* mesh_O = nullptr;
  Pose X_BO = Pose::Identity();
};

// The pixels u0 .. u0 + width - 1, v0 .. v0 + height - 1 of an image, row
// by row; `wanted` (width * height flags, 1 = wanted) picks those whose
// depth is asked for.
struct PixelWindow {
  int u0 = 0, v0 = 0, width = 0, height = 0;
  std::span<const uint8_t> wanted;
};

// Per pixel of `window` (row by row): the depth (m, z in C) of the nearest
// surface of `meshes` its ray meets, +infinity where it meets none or where
// the pixel is not wanted. Exact per triangle (the ray against the
// triangle's plane, inside its projected edges, edges included). The meshes
// are closed, their triangles counter-clockwise seen from outside
// (TriangleMesh): only the triangles facing the camera are rasterised, as
// the surface a ray from outside meets first faces it. Triangles with a
// vertex less than 1 mm in front of the camera are skipped (never in a bin).
// Cost:
// the window's pixels once (the wanted ones counted), the meshes'
// triangles, and the pixels of each triangle's bounding box on its rows
// that hold a wanted pixel.
std::vector<float> NearestSurfaceDepth(const Intrinsics& K, const Pose& X_BC, std::span<const PlacedMesh> meshes,
                                       const PixelWindow& window);

// The same for the farthest surface: the depth (m) where the ray last
// leaves `meshes` (their triangles facing away from the camera, the
// largest depth), 0 where it meets none or where the pixel is not wanted.
// The space behind it, seen from the camera, is hidden by the meshes
// (GraspPlanningOptions::hidden_behind_parts).
std::vector<float> FarthestSurfaceDepth(const Intrinsics& K, const Pose& X_BC, std::span<const PlacedMesh> meshes,
                                        const PixelWindow& window);

}  // namespace bp::internal
