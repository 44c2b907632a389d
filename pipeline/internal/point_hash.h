// A uniform hash grid over a point set for fixed-radius queries (radius <=
// cell size; radius <= cell / 2 visits 8 cells instead of 27, which is what
// costs: each cell is a hash probe). Built in O(n) by a counting sort through
// the table; no per-point heap allocation. Keeps a copy of the points in cell
// order (the caller's need not outlive it). Immutable after Build, so const queries are thread-safe.
#pragma once

#include <cstdint>
#include <span>
#include <utility>
#include <vector>

#include <Eigen/Core>

#include "pipeline/internal/int_math.h"

namespace bp::internal {

class PointHash {
 public:
  // REQUIRES: cell > 0 and all points finite.
  void Build(std::span<const Eigen::Vector3f> points, float cell);

  // Calls f(index, squared_distance) for every point within radius of q.
  // REQUIRES: radius <= cell size.
  template <typename F>
  void ForEachWithin(const Eigen::Vector3f& q, float radius, F&& f) const {
    VisitWithin(q, radius, [&](int index, float d2) {
      f(index, d2);
      return false;
    });
  }

  // Whether pred(index, squared_distance) holds for a point within radius
  // of q; stops at the first that does. REQUIRES: radius <= cell size.
  template <typename Pred>
  bool AnyWithinWhere(const Eigen::Vector3f& q, float radius, Pred&& pred) const {
    return VisitWithin(q, radius, pred);
  }

  // Nearest point within radius, or -1. *d2 gets its squared distance.
  int Nearest(const Eigen::Vector3f& q, float radius, float* d2 = nullptr) const;
  bool AnyWithin(const Eigen::Vector3f& q, float radius) const;

  // The points grouped by cell: the occupied cells' runs [begin, end) of
  // order(), in ascending cell-key order (z, then y, then x), each run in
  // point index order. Voxel subsampling walks the cells so.
  std::vector<std::pair<uint32_t, uint32_t>> CellRunsByKey() const;
  std::span<const uint32_t> order() const { return order_; }

  float cell() const { return cell_; }
  size_t size() const { return sorted_.size(); }

 private:
  int CellCoord(float v) const { return FloorToInt(v * inv_cell_); }
  static uint64_t Key(int x, int y, int z) {
    // 21 bits per axis, offset so negative coordinates stay positive.
    constexpr int kOff = 1 << 20;
    return (static_cast<uint64_t>(x + kOff) & 0x1FFFFF) | ((static_cast<uint64_t>(y + kOff) & 0x1FFFFF) << 21) |
           ((static_cast<uint64_t>(z + kOff) & 0x1FFFFF) << 42);
  }
  std::pair<uint32_t, uint32_t> Range(uint64_t key) const;
  // Calls stop(index, squared_distance) for the points within radius of q,
  // in cell order, until it returns true. @returns whether it did.
  // REQUIRES: radius <= cell size.
  template <typename F>
  bool VisitWithin(const Eigen::Vector3f& q, float radius, F&& stop) const {
    const float r2 = radius * radius;
    // radius <= cell: the ball overlaps at most 2 cells per axis.
    const int x0 = CellCoord(q.x() - radius), x1 = CellCoord(q.x() + radius);
    const int y0 = CellCoord(q.y() - radius), y1 = CellCoord(q.y() + radius);
    const int z0 = CellCoord(q.z() - radius), z1 = CellCoord(q.z() + radius);
    for (int z = z0; z <= z1; ++z) {
      for (int y = y0; y <= y1; ++y) {
        for (int x = x0; x <= x1; ++x) {
          const auto [begin, end] = Range(Key(x, y, z));
          for (uint32_t k = begin; k < end; ++k) {
            const float d2 = (sorted_[k] - q).squaredNorm();
            if (d2 <= r2 && stop(static_cast<int>(order_[k]), d2)) return true;
          }
        }
      }
    }
    return false;
  }

  float cell_ = 1.f, inv_cell_ = 1.f;
  std::vector<uint32_t> order_;  // point indices sorted by cell
  std::vector<Eigen::Vector3f> sorted_;  // the points in that order (a query reads one run per cell)
  // Open-addressing table: cell key -> [begin, end) in order_.
  struct Slot {
    uint64_t key = ~0ull;
    uint32_t begin = 0, end = 0;
  };
  std::vector<Slot> table_;
  uint64_t mask_ = 0;
};

}  // namespace bp::internal
