#include "pipeline/internal/closest_point_field.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Geometry>
#include <limits>

#include "pipeline/internal/table_memo.h"

namespace bp::internal {

void ClosestPointField::Build(std::span<const Eigen::Vector3f> points, float voxel, float band) {
  if (!ModelTableMemoOn()) {
    Compute(points, voxel, band);
    return;
  }
  static TableMemo<ClosestPointField> memo;
  static_assert(sizeof(Eigen::Vector3f) == 3 * sizeof(float));  // no padding in the key
  TableMemoKey key;
  key.AddSpan(points).Add(voxel).Add(band);
  if (memo.Find(key, this)) return;
  Compute(points, voxel, band);
  memo.Store(key, *this);
}

void ClosestPointField::Compute(std::span<const Eigen::Vector3f> points, float voxel, float band) {
  cells_.clear();
  cells16_.clear();
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
  const float band2 = band * band;
  std::vector<float> best(n, band2);
  const int reach = static_cast<int>(std::ceil(band * inv_voxel_));
  // Each sample updates the voxels whose centres lie within the band: per
  // (z, y) row, only the x run inside the sphere (a cube of side 2 * reach
  // would visit about twice as many). The distance is summed in the order
  // Eigen's (centre - p).squaredNorm() uses for a Vector3f, dx² + (dy² + dz²),
  // so ties resolve as they did when it was computed that way.
  const float ox = origin_.x(), oy = origin_.y(), oz = origin_.z();
  const int nx = dims_.x(), ny = dims_.y(), nz = dims_.z();
  for (size_t i = 0; i < points.size(); ++i) {
    const float px = points[i].x(), py = points[i].y(), pz = points[i].z();
    const int cx = static_cast<int>((px - ox) * inv_voxel_),
              cy = static_cast<int>((py - oy) * inv_voxel_),
              cz = static_cast<int>((pz - oz) * inv_voxel_);
    const int32_t index = static_cast<int32_t>(i);
    for (int z = std::max(0, cz - reach); z <= std::min(nz - 1, cz + reach); ++z) {
      const float dz = oz + (static_cast<float>(z) + 0.5f) * voxel - pz;
      const float dz2 = dz * dz;
      if (dz2 >= band2) continue;
      for (int y = std::max(0, cy - reach); y <= std::min(ny - 1, cy + reach); ++y) {
        const float dy = oy + (static_cast<float>(y) + 0.5f) * voxel - py;
        const float dyz2 = dy * dy + dz2;
        if (dyz2 >= band2) continue;
        // |dx| < rx, one voxel of slack on each side; the d2 test decides.
        const float rx = std::sqrt(band2 - dyz2);
        const int x_lo = std::max(
            {0, cx - reach, static_cast<int>(std::floor((px - rx - ox) * inv_voxel_)) - 1});
        const int x_hi = std::min(
            {nx - 1, cx + reach, static_cast<int>(std::floor((px + rx - ox) * inv_voxel_)) + 1});
        const size_t row = (static_cast<size_t>(z) * ny + y) * nx;
        float* best_row = best.data() + row;
        int32_t* cell_row = cells_.data() + row;
        for (int x = x_lo; x <= x_hi; ++x) {
          const float dx = ox + (static_cast<float>(x) + 0.5f) * voxel - px;
          const float d2 = dx * dx + dyz2;
          if (d2 < best_row[x]) {
            best_row[x] = d2;
            cell_row[x] = index;
          }
        }
      }
    }
  }
  // Row-major (above) to bricks, padded to whole bricks.
  const int bx = (nx + kBrick - 1) / kBrick, by = (ny + kBrick - 1) / kBrick, bz = (nz + kBrick - 1) / kBrick;
  const size_t brick_cells = size_t{1} << (3 * kBrickBits);
  brick_stride_[0] = brick_cells;
  brick_stride_[1] = brick_cells * static_cast<size_t>(bx);
  brick_stride_[2] = brick_cells * static_cast<size_t>(bx) * static_cast<size_t>(by);
  const size_t stored = brick_stride_[2] * static_cast<size_t>(bz);
  const bool narrow = points.size() < kNone16;
  std::vector<int32_t> wide;
  if (narrow) {
    cells16_.assign(stored, kNone16);
  } else {
    wide.assign(stored, -1);
  }
  for (int z = 0; z < nz; ++z) {
    for (int y = 0; y < ny; ++y) {
      const int32_t* row = cells_.data() + (static_cast<size_t>(z) * ny + y) * nx;
      const size_t base = AxisOffset(y, 1) + AxisOffset(z, 2);
      for (int x = 0; x < nx; ++x) {
        const size_t k = base + AxisOffset(x, 0);
        if (narrow) {
          cells16_[k] = row[x] < 0 ? kNone16 : static_cast<uint16_t>(row[x]);
        } else {
          wide[k] = row[x];
        }
      }
    }
  }
  cells_.swap(wide);
}

}  // namespace bp::internal
