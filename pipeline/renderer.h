// Depth / label / intensity rendering of rigid meshes through a pinhole camera.
// The OSMesa (software, llvmpipe) backend is the only one today; an EGL
// surfaceless backend could implement the same interface.
//
// Projection is exact for OpenCV pinhole intrinsics (distortion ignored): the
// value at pixel (u, v) is the surface seen along the ray through
// ((u - cx) / fx, (v - cy) / fy, 1) in the camera frame C (z forward, x right,
// y down). Depth is the metric z in C (not the ray length).
#pragma once

#include <algorithm>
#include <cstdint>
#include <memory>
#include <vector>

#include "core/cell.h"
#include "core/image.h"
#include "core/mesh.h"
#include "core/pose.h"
#include "core/status.h"

namespace bp {

struct RenderInstance {
  size_t mesh_index = 0;         // into RenderScene::meshes
  Pose X_WO = Pose::Identity();  // instance in the scene frame W
  uint16_t label = 0;            // written to RenderOutput::labels (0 = background)
};

struct RenderScene {
  // Meshes are uploaded once per renderer and cached by pointer identity
  // (the renderer keeps a reference, so the address is never reused).
  std::vector<std::shared_ptr<const TriangleMesh>> meshes;
  std::vector<RenderInstance> instances;
  double z_near = 0.05;  // m, clip planes in C
  double z_far = 10.0;
  Vec3 light_C = Vec3::Zero();  // point light (the projector) in C
  double ambient = 0.15;        // intensity of a surface facing away from the light, [0, 1]
};

// The pixels u0..u1 x v0..v1 of an image (inclusive; empty when u1 < u0 or
// v1 < v0).
struct PixelRect {
  int u0 = 0, v0 = 0, u1 = -1, v1 = -1;
  bool empty() const { return u1 < u0 || v1 < v0; }
  int64_t area() const { return empty() ? 0 : int64_t{u1 - u0 + 1} * (v1 - v0 + 1); }
  // The smallest rect holding both.
  void Extend(const PixelRect& r) {
    if (r.empty()) return;
    if (empty()) {
      *this = r;
      return;
    }
    u0 = std::min(u0, r.u0), v0 = std::min(v0, r.v0), u1 = std::max(u1, r.u1), v1 = std::max(v1, r.v1);
  }
};

struct RenderOutput {
  DepthImage depth;          // metres (z in C); NaN where nothing was hit
  LabelImage labels;         // RenderInstance::label of the nearest surface, 0 = nothing
  IntensityImage intensity;  // Lambertian from light_C plus ambient; 0 = nothing
};

// Not thread-safe: one renderer owns one GL context and must be used from one
// thread at a time (the thread that calls Render makes the context current).
class DepthRenderer {
 public:
  virtual ~DepthRenderer() = default;
  // X_WC: camera in the scene frame. @returns InvalidArgument for bad intrinsics
  // or mesh indices, Unavailable if the GL context cannot be made current.
  virtual Result<RenderOutput> Render(const RenderScene& scene, const Intrinsics& K,
                                      const Pose& X_WC) = 0;
  // As Render, filling `out` in place (its buffers are reused between calls).
  virtual Status RenderInto(const RenderScene& scene, const Intrinsics& K, const Pose& X_WC,
                            RenderOutput& out) = 0;
  // As RenderInto for the pixels of `region` only (clipped to the image):
  // `out` must already hold an image of K's size, and its pixels outside
  // `region` are left as they are. The pixels inside get the bytes RenderInto
  // would give them: the same triangles are set up over the same viewport and
  // projection, only fragments outside `region` are dropped (GL's scissor
  // test). InvalidArgument when `out` is not of K's size.
  virtual Status RenderRegion(const RenderScene& scene, const Intrinsics& K, const Pose& X_WC,
                              const PixelRect& region, RenderOutput& out) = 0;
};

// @returns Unavailable if no OSMesa context can be created.
Result<std::unique_ptr<DepthRenderer>> MakeOsMesaRenderer();

}  // namespace bp
