#include "pipeline/internal/closest_point_field.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Geometry>
#include <limits>

namespace bp::internal {

void ClosestPointField::Build(std::span<const Eigen::Vector3f> points, float voxel, float band) {
  cells_.clear();
  dims_.setZero();
  band_ = band;
  inv_voxel_ = 1.f / voxel;
  if (points.empty()) return;
  Eigen::AlignedBox3f box;
  for (const auto& p : points) box.extend(p);
  origin_ = box.min() - Eigen::Vector3f::Constant(band + voxel);
  const Eigen::Vector3f extent = box.max() + Eigen::Vector3f::Constant(band + voxel) - origin_;
  dims_ = (extent * inv_voxel_).array().ceil().cast<int>().matrix();
  const size_t n = static_cast<size_t>(dims_.x()) * dims_.y() * dims_.z();
  cells_.assign(n, -1);
  std::vector<float> best(n, band * band);
  const int reach = static_cast<int>(std::ceil(band * inv_voxel_));
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3f g = (points[i] - origin_) * inv_voxel_;
    const int cx = static_cast<int>(g.x()), cy = static_cast<int>(g.y()), cz = static_cast<int>(g.z());
    for (int z = std::max(0, cz - reach); z <= std::min(dims_.z() - 1, cz + reach); ++z) {
      for (int y = std::max(0, cy - reach); y <= std::min(dims_.y() - 1, cy + reach); ++y) {
        for (int x = std::max(0, cx - reach); x <= std::min(dims_.x() - 1, cx + reach); ++x) {
          const Eigen::Vector3f centre = origin_ + (Eigen::Vector3f(x, y, z) + Eigen::Vector3f::Constant(0.5f)) * voxel;
          const float d2 = (centre - points[i]).squaredNorm();
          const size_t c = (static_cast<size_t>(z) * dims_.y() + y) * dims_.x() + x;
          if (d2 < best[c]) {
            best[c] = d2;
            cells_[c] = static_cast<int32_t>(i);
          }
        }
      }
    }
  }
}

}  // namespace bp::internal
