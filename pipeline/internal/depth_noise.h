// Structured-light depth noise on a clean rendered depth image (see NoiseModel
// in core/cell.h and docs/synthetic.md).
#pragma once

#include <cstdint>

#include "core/cell.h"
#include "core/image.h"

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

// Applies, in order: grazing-angle dropout (normals estimated from the clean
// depth), projector shadow, random dropout, axial Gaussian noise, mixed pixels
// at depth edges, speckle, then the depth range. Deterministic for a given seed. With !model.enabled only the
// depth range is applied.
// Writes the noisy image of the clean `depth` into `noisy` (resized; its
// buffer is reused when the size fits; must not be `depth`).
void ApplyDepthNoise(const NoiseModel& model, const NoiseInputs& in, uint64_t seed, const DepthImage& depth,
                     DepthImage& noisy);
// In place.
void ApplyDepthNoise(const NoiseModel& model, const NoiseInputs& in, uint64_t seed, DepthImage& depth);

}  // namespace bp::internal
