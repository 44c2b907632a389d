#include "pipeline/fill_level.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace bp {

FillLevel MeasureFillLevel(std::span<const Eigen::Vector3f> points_B, const Pose& X_BW,
                           const Eigen::Vector2d& half_extent, const FillLevelOptions& options) {
  FillLevel fill;
  if (!(options.cell_size > 0) || !(half_extent.array() > 0).all()) return fill;
  const int nx = std::max(1, static_cast<int>(std::ceil(2 * half_extent.x() / options.cell_size)));
  const int ny = std::max(1, static_cast<int>(std::ceil(2 * half_extent.y() / options.cell_size)));
  std::vector<float> top(static_cast<size_t>(nx) * ny, 0.0f);
  const Eigen::Affine3f X_WB = X_BW.inverse().cast<float>();
  const float hx = static_cast<float>(half_extent.x()), hy = static_cast<float>(half_extent.y());
  const float inv = static_cast<float>(1.0 / options.cell_size);
  float highest = 0.0f;
  for (const Eigen::Vector3f& p_B : points_B) {
    const Eigen::Vector3f p = X_WB * p_B;
    if (!(std::abs(p.x()) <= hx && std::abs(p.y()) <= hy)) continue;  // NaN fails too
    const int ix = std::min(nx - 1, static_cast<int>((p.x() + hx) * inv));
    const int iy = std::min(ny - 1, static_cast<int>((p.y() + hy) * inv));
    float& t = top[static_cast<size_t>(iy) * nx + ix];
    t = std::max(t, p.z());
    highest = std::max(highest, p.z());
  }
  double sum = 0;
  int occupied = 0;
  for (float t : top) {
    sum += t;
    occupied += t > options.occupied_height ? 1 : 0;
  }
  fill.cells = nx * ny;
  fill.mean_height = sum / fill.cells;
  fill.max_height = highest;
  fill.occupied_fraction = static_cast<double>(occupied) / fill.cells;
  return fill;
}

}  // namespace bp
