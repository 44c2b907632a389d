// Private: a dense occupancy bitmap of points over their bounding box, the
// cheap pre-filter before an FCL OcTree query (as GPD filters points in the
// hand's box first), with each cell's points kept for the finer test of an
// oriented box (AnyNear). Immutable after construction; safe to share.
#pragma once

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <span>
#include <vector>

#include "core/pose.h"

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
    // The points by cell (counting sort): cell c holds points_[start_[c] ..
    // start_[c + 1] - 1].
    start_.assign(bits_.size() + 1, 0);
    for (const auto& p : points) {
      if (!p.allFinite()) continue;
      const size_t c = Index(Cell(p.cast<double>()));
      bits_[c] = 1;
      ++start_[c + 1];
    }
    for (size_t c = 1; c < start_.size(); ++c) start_[c] += start_[c - 1];
    points_.resize(start_.back());
    std::vector<uint32_t> fill(start_.begin(), start_.end() - 1);
    for (const auto& p : points) {
      if (p.allFinite()) points_[fill[Index(Cell(p.cast<double>()))]++] = p;
    }
  }

  // True if a point lies within `grow` (m, per axis) of `box_L`, a box in
  // the frame L placed at X_WL (W: the points' frame). Exact per point: a
  // false says no point is in the box grown by `grow` along L's axes, so
  // nothing within `grow` of a point (a voxel around it, a ball of radius
  // `grow`) meets the box.
  bool AnyNear(const Eigen::AlignedBox3d& box_L, const Pose& X_WL, double grow) const {
    Eigen::AlignedBox3d grown = box_L;
    grown.min().array() -= grow;
    grown.max().array() += grow;
    Eigen::AlignedBox3d world;
    for (int i = 0; i < 8; ++i) world.extend(X_WL * grown.corner(static_cast<Eigen::AlignedBox3d::CornerType>(i)));
    const Pose X_LW = X_WL.inverse();
    const Eigen::Matrix3d R = X_LW.linear();
    const Eigen::Vector3d t = X_LW.translation();
    bool any = false;
    ForCellsIn(world, [&](size_t c) {
      for (uint32_t k = start_[c]; k < start_[c + 1]; ++k) {
        const Eigen::Vector3d p_L = R * points_[k].cast<double>() + t;
        if ((p_L.array() >= grown.min().array()).all() && (p_L.array() <= grown.max().array()).all()) {
          any = true;
          return true;
        }
      }
      return false;
    });
    return any;
  }

 private:
  // Calls stop(c) for each occupied cell c overlapping `query` until it
  // returns true.
  template <typename Stop>
  void ForCellsIn(const Eigen::AlignedBox3d& query, Stop&& stop) const {
    if (bits_.empty()) return;
    const Eigen::AlignedBox3d q = query.intersection(box_);
    if (q.isEmpty()) return;
    const Eigen::Vector3i lo = Cell(q.min()), hi = Cell(q.max());
    for (int z = lo.z(); z <= hi.z(); ++z) {
      for (int y = lo.y(); y <= hi.y(); ++y) {
        const size_t row = Index(Eigen::Vector3i(0, y, z));
        for (int x = lo.x(); x <= hi.x(); ++x) {
          if (bits_[row + static_cast<size_t>(x)] && stop(row + static_cast<size_t>(x))) return;
        }
      }
    }
  }
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
  std::vector<uint32_t> start_;
  std::vector<Eigen::Vector3f> points_;  // by cell
};

}  // namespace bp::internal
