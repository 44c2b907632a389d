// Perception's first stage on a noisy organized frame: an edge-preserving
// average of the depth image, so that the later stages, whose tolerances are
// a few times the noise they were tuned at, see about that noise (docs/
// perception_pipeline.md, "Depth noise and smoothing"). Private to
// bp_pipeline. Metres.
#pragma once

#include "core/image.h"
#include "pipeline/internal/fit_limit.h"

namespace bp::internal {

// The half width r (pixels) of the smallest window that brings the frame's
// noise at its median depth, sigma, down to target_sigma (metres): a full
// (2r+1)^2 window divides independent noise by 2r+1, so
// r = ceil((sigma / target_sigma - 1) / 2), clamped to [1, max_radius];
// 0 (no smoothing) when sigma <= target_sigma, without a noise figure, or
// when target_sigma <= 0 or max_radius < 1.
int SmoothingRadius(const DepthNoise& noise, double target_sigma, int max_radius);

// Each finite pixel becomes the mean of the finite pixels of its (2r+1)^2
// window whose depth lies within gate_sigmas x sqrt(2) x sigma(z) of its own
// (two rows, then columns, passes: a depth edge, a neighbour part, a mixed
// pixel stay out of the average). NaN pixels stay NaN: holes are not filled.
// Bands of rows in parallel on the caller's oneTBB arena; the result does not
// depend on the schedule. radius <= 0: a copy.
DepthImage SmoothDepth(const DepthImage& depth, int radius, const DepthNoise& noise, double gate_sigmas);

}  // namespace bp::internal
