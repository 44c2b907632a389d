// Pixel arithmetic of the pose estimator's verification on an organized
// depth image (pinhole, no distortion): the pixel a point projects to, and a
// test of the pixels around it that rules out cheaply that any point of the
// image lies near a given point. Header-only; used by bp_pipeline and the
// grasp planner (its dropout rays).
#pragma once

#include <algorithm>
#include <cmath>

#include <Eigen/Core>

#include "core/cell.h"
#include "core/image.h"

namespace bp::internal {

// x rounded half away from zero, as std::lround (without the call into libm:
// verification rounds two pixel coordinates per visible model point); false
// when |x| >= 2^30 or x is NaN (no pixel of any image).
inline bool RoundToInt(double x, int* out) {
  if (!(std::abs(x) < 1073741824.0)) return false;
  const int t = static_cast<int>(x);            // towards zero
  const double f = x - static_cast<double>(t);  // exact
  *out = t + (f >= 0.5 ? 1 : 0) - (f <= -0.5 ? 1 : 0);
  return true;
}

// The pixel (rounded) a point in C projects to; false when the point is not
// in front of the camera or the pixel is off the image.
inline bool PixelOf(const Intrinsics& K, const DepthImage& depth, const Eigen::Vector3f& p_C, int* u, int* v) {
  if (!(p_C.z() > 0)) return false;
  if (!RoundToInt(K.fx * p_C.x() / p_C.z() + K.cx, u) || !RoundToInt(K.fy * p_C.y() / p_C.z() + K.cy, v)) {
    return false;
  }
  return *u >= 0 && *v >= 0 && *u < depth.width && *v < depth.height;
}

// A point lies on its pixel when it projects within `centre` pixels of the
// centre of a pixel (rounded: (u, v)) whose depth is within `depth` metres of
// its own, as the points deprojected from a depth image do.
struct OnPixelTolerance {
  double centre = 0.02;  // pixels
  float depth = 2e-5f;   // metres
};

// True when p_C (a point in C, in front of the camera) lies on its pixel.
inline bool OnItsPixel(const Intrinsics& K, const DepthImage& depth, const Eigen::Vector3f& p_C,
                       const OnPixelTolerance& tol) {
  if (!(p_C.z() > 0)) return false;
  const double x = K.fx * p_C.x() / p_C.z() + K.cx, y = K.fy * p_C.y() / p_C.z() + K.cy;
  int u = 0, v = 0;
  if (!RoundToInt(x, &u) || !RoundToInt(y, &v) || u < 0 || v < 0 || u >= depth.width || v >= depth.height) {
    return false;
  }
  return std::abs(x - u) <= tol.centre && std::abs(y - v) <= tol.centre &&
         std::abs(depth.at(u, v) - p_C.z()) <= tol.depth;  // NaN: false
}

// False only when no pixel of `depth` near (u, v), the pixel of p_C, holds a
// depth within r of p_C's (widened by the tolerance): then no point on its
// pixel (OnItsPixel with `tol`) is within r of p_C. True when one does, or
// when the window would be more than max_half_window pixels wide each way
// (the caller then asks elsewhere).
//
// A point s with |s - p| <= r has s.x / s.z - p.x / p.z = (s.x - p.x) / s.z
// + (p.x / p.z) (p.z - s.z) / s.z, at most r (1 + |p.x / p.z|) / (p.z - r) in
// size; its projection is that times fx away from p's, which is at most half
// a pixel from (u, v), and s's pixel at most tol.centre from s's projection.
inline bool DepthWindowMayHoldPointNear(const DepthImage& depth, const Intrinsics& K, const Eigen::Vector3f& p_C,
                                        int u, int v, float r, const OnPixelTolerance& tol, int max_half_window) {
  const double z_near = static_cast<double>(p_C.z()) - r;
  if (!(z_near > 0.0)) return true;
  const double margin = 0.5 + tol.centre;
  const double ru = K.fx * r * (1.0 + std::abs(p_C.x() / p_C.z())) / z_near + margin;
  const double rv = K.fy * r * (1.0 + std::abs(p_C.y() / p_C.z())) / z_near + margin;
  if (!(ru < max_half_window + 1) || !(rv < max_half_window + 1)) return true;
  const int ku = static_cast<int>(ru), kv = static_cast<int>(rv);
  // The depth tolerance twice: float rounding of p_C as of s.
  const float lo = p_C.z() - r - 2.f * tol.depth, hi = p_C.z() + r + 2.f * tol.depth;
  const int u0 = std::max(0, u - ku), u1 = std::min(depth.width - 1, u + ku);
  const int v0 = std::max(0, v - kv), v1 = std::min(depth.height - 1, v + kv);
  for (int vv = v0; vv <= v1; ++vv) {
    const float* row = &depth.at(0, vv);
    for (int uu = u0; uu <= u1; ++uu) {
      if (row[uu] >= lo && row[uu] <= hi) return true;  // NaN: no measurement, false
    }
  }
  return false;
}

}  // namespace bp::internal
