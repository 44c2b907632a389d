// Structured-light depth noise on a clean rendered depth image (see NoiseModel
// in core/cell.h and docs/synthetic.md).
#pragma once

#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include "core/cell.h"
#include "core/image.h"
#include "pipeline/renderer.h"

namespace bp::internal {

// Projector intrinsics: the camera's focal lengths on an image padded so that
// the projector, offset by `offset` (camera frame), covers the camera's whole
// field of view from min_depth on.
Intrinsics ProjectorIntrinsics(const Intrinsics& K, const Vec3& offset, double min_depth);

// The noise's random draws from one engine: Uniform() in [0, 1) and Normal()
// (mean 0, sigma 1) give, bit for bit, what libstdc++'s
// std::uniform_real_distribution<double>(0, 1) and
// std::normal_distribution<double>(0, 1) give from the same engine
// (generate_canonical: one 64-bit draw times 2^-64, 1 - ulp where that
// rounds to 1; Marsaglia's polar method, the second value kept for the next
// call), so frames stay the same bytes. libstdc++ takes a long-double
// logarithm on every uniform draw to find how many engine calls make 53 bits
// (one here); GCC folds it, clang does not: under ASan that logarithm was 8%
// of bp_grasp_tests' CPU (docs/reliability.md, "Timings").
class NoiseDraws {
 public:
  explicit NoiseDraws(uint64_t seed) : rng_(seed) {}
  double Uniform() {
    const double x = static_cast<double>(rng_()) * 0x1p-64;
    return x < 1.0 ? x : 0x1.fffffffffffffp-1;
  }
  double Normal() {
    if (saved_available_) {
      saved_available_ = false;
      return saved_;
    }
    double x, y, r2;
    do {
      x = 2.0 * Uniform() - 1.0;
      y = 2.0 * Uniform() - 1.0;
      r2 = x * x + y * y;
    } while (r2 > 1.0 || r2 == 0.0);
    const double mult = std::sqrt(-2 * std::log(r2) / r2);
    saved_ = x * mult;
    saved_available_ = true;
    return y * mult;
  }

 private:
  std::mt19937_64 rng_;
  double saved_ = 0.0;
  bool saved_available_ = false;
};

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
