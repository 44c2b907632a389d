// Private: a dense occupancy bitmap of points over their bounding box, the
// cheap pre-filter before an FCL OcTree query (as GPD filters points in the
// hand's box first). Immutable after construction; safe to share.
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <span>
#include <vector>

namespace bp::internal {

class OccupancyGrid {
 public:
  OccupancyGrid() = default;
  OccupancyGrid(std::span<const Eigen::Vector3f> points, double cell) : cell_(cell) {
    for (const auto& p : points) {
      if (p.allFinite()) box_.extend(p.cast<double>());
    }
    if (box_.isEmpty()) return;
    dims_ = ((box_.sizes() / cell_).array().floor().cast<int>() + 1).matrix();
    bits_.assign(static_cast<size_t>(dims_.prod()), 0);
    for (const auto& p : points) {
      if (p.allFinite()) bits_[Index(Cell(p.cast<double>()))] = 1;
    }
  }

  // True if any occupied cell overlaps `query` (conservative: whole cells).
  bool AnyIn(const Eigen::AlignedBox3d& query) const {
    if (bits_.empty()) return false;
    const Eigen::AlignedBox3d q = query.intersection(box_);
    if (q.isEmpty()) return false;
    const Eigen::Vector3i lo = Cell(q.min()), hi = Cell(q.max());
    for (int z = lo.z(); z <= hi.z(); ++z) {
      for (int y = lo.y(); y <= hi.y(); ++y) {
        const size_t row = Index(Eigen::Vector3i(0, y, z));
        for (int x = lo.x(); x <= hi.x(); ++x) {
          if (bits_[row + static_cast<size_t>(x)]) return true;
        }
      }
    }
    return false;
  }

 private:
  Eigen::Vector3i Cell(const Eigen::Vector3d& p) const {
    const Eigen::Vector3i c = ((p - box_.min()) / cell_).array().floor().cast<int>().matrix();
    return c.cwiseMax(0).cwiseMin(dims_ - Eigen::Vector3i::Ones());
  }
  size_t Index(const Eigen::Vector3i& c) const {
    return (static_cast<size_t>(c.z()) * dims_.y() + static_cast<size_t>(c.y())) * dims_.x() +
           static_cast<size_t>(c.x());
  }

  double cell_ = 0.01;
  Eigen::AlignedBox3d box_;
  Eigen::Vector3i dims_ = Eigen::Vector3i::Zero();
  std::vector<uint8_t> bits_;
};

}  // namespace bp::internal
