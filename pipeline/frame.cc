#include "pipeline/frame.h"

#include <cmath>

namespace bp {

std::vector<Eigen::Vector3f> Frame::PointsInCamera() const {
  if (!organized()) {
    std::vector<Eigen::Vector3f> out;
    out.reserve(points_C.size());
    for (const auto& p : points_C) {
      if (p.allFinite()) out.push_back(p);
    }
    return out;
  }
  std::vector<Eigen::Vector3f> out;
  out.reserve(ValidPointCount());
  for (int v = 0; v < depth.height; ++v) {
    for (int u = 0; u < depth.width; ++u) {
      const float z = depth.at(u, v);
      if (std::isfinite(z) && z > 0.f) out.push_back(Deproject(intrinsics, u, v, z));
    }
  }
  return out;
}

size_t Frame::ValidPointCount() const {
  size_t n = 0;
  if (organized()) {
    for (float z : depth.data) n += (std::isfinite(z) && z > 0.f) ? 1 : 0;
  } else {
    for (const auto& p : points_C) n += p.allFinite() ? 1 : 0;
  }
  return n;
}

}  // namespace bp
