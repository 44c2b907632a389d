// Structured-light depth noise on a clean rendered depth image (see NoiseModel
// in core/cell.h and docs/synthetic.md).
#pragma once

#include <cstdint>
#include <vector>

#include "core/cell.h"
#include "core/image.h"
#include "pipeline/renderer.h"

namespace bp::internal {

// Projector intrinsics: the camera's focal lengths on an image padded so that
// the projector, offset by `offset` (camera frame), covers the camera's whole
// field of view from min_depth on.
Intrinsics ProjectorIntrinsics(const Intrinsics& K, const Vec3& offset, double min_depth);

struct NoiseInputs {
  const Intrinsics* K = nullptr;                // camera
  const DepthImage* projector_depth = nullptr;  // null: no projector shadowing
  const Intrinsics* K_projector = nullptr;
  Vec3 projector_offset = Vec3::Zero();  // projector origin in C; same orientation
  double min_depth = 0.0, max_depth = 1e9;
};

// What the noise computes from the clean depth and the projector's depth map
// alone, not from the seed, kept between captures: per pixel of the clean
// depth, its grazing class (from the normal, ViewCosine; on the ramp, its
// dropout probability) and whether the projector lights it. A capture recomputes it only where its inputs changed
// (NoiseChanges); the noisy image is the same bytes either way.
struct NoiseGeometry {
  // Per pixel: bits 0-1 the grazing class (kNoDepth, kFacing, kRamp: dropped
  // at random, kDropped), bit 2 set when the projector does not light it.
  enum : uint8_t { kNoDepth = 0, kFacing = 1, kRamp = 2, kDropped = 3, kClassMask = 3, kShadowed = 4 };
  std::vector<uint8_t> code;
  // The projector pixel (u, v) whose 2 x 2 block the shadow test read, or
  // u = -1 when it read none (the pixel is outside the map, or no depth).
  std::vector<int16_t> projector_u, projector_v;
  // kRamp pixels: the probability of the grazing dropout, (angle from the
  // normal - grazing_start_deg) / (grazing_full_deg - grazing_start_deg).
  std::vector<double> ramp_drop;
  // What it was computed with: recomputed whole when any of it differs.
  int width = 0, height = 0;
  double grazing_start_deg = 0, grazing_full_deg = 0;
  bool shadow = false;
  Intrinsics K, K_projector;
  Vec3 projector_offset = Vec3::Zero();
};

// Where the inputs of a NoiseGeometry changed since it was computed.
struct NoiseChanges {
  bool all = true;       // everything (a new view, a forgotten cache)
  PixelRect depth;       // clean depth pixels
  PixelRect projector;   // projector depth map pixels
  static NoiseChanges None() {
    NoiseChanges c;
    c.all = false;
    return c;
  }
  void Extend(const NoiseChanges& c) {
    all = all || c.all;
    depth.Extend(c.depth);
    projector.Extend(c.projector);
  }
};

// Applies, in order: grazing-angle dropout (normals estimated from the clean
// depth), projector shadow, random dropout, axial Gaussian noise, mixed pixels
// at depth edges, speckle, then the depth range. Deterministic for a given seed. With !model.enabled only the
// depth range is applied.
// Writes the noisy image of the clean `depth` into `noisy` (resized; its
// buffer is reused when the size fits; must not be `depth`).
void ApplyDepthNoise(const NoiseModel& model, const NoiseInputs& in, uint64_t seed, const DepthImage& depth,
                     DepthImage& noisy);
// As above, reading the seed-independent part of each pixel from `geometry`,
// updated first where `changes` says the clean depth or the projector map
// changed since it was computed (everywhere when it was computed for another
// image size, model or camera; and every time for a projector map wider or
// taller than 32767 pixels, whose coordinates the cache cannot hold).
void ApplyDepthNoise(const NoiseModel& model, const NoiseInputs& in, uint64_t seed, const DepthImage& depth,
                     DepthImage& noisy, NoiseGeometry& geometry, const NoiseChanges& changes);
// In place.
void ApplyDepthNoise(const NoiseModel& model, const NoiseInputs& in, uint64_t seed, DepthImage& depth);

}  // namespace bp::internal
