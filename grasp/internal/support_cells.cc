#include "grasp/internal/support_cells.h"

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <bit>
#include <cmath>
#include <limits>

namespace bp::internal {
namespace {

// A set of the cubes of the support's bounds, one bit each, with the count
// of set bits before each 64-bit word once Rank() has run: an occupied
// cube's rank among the occupied ones in O(1), so that the per-cube lists
// cost in proportion to the occupied cubes, not to the bounds' volume.
class CubeBits {
 public:
  explicit CubeBits(size_t cubes) : words_((cubes + 63) / 64, 0) {}
  void Set(size_t c) { words_[c >> 6] |= uint64_t{1} << (c & 63); }
  bool Test(size_t c) const { return ((words_[c >> 6] >> (c & 63)) & 1u) != 0; }
  // The ranks, after the last Set. @returns the number of set cubes.
  size_t Rank() {
    ranks_.resize(words_.size());
    size_t n = 0;
    for (size_t w = 0; w < words_.size(); ++w) {
      ranks_[w] = static_cast<uint32_t>(n);
      n += static_cast<size_t>(std::popcount(words_[w]));
    }
    return n;
  }
  // How many set cubes come before c. REQUIRES: Rank() ran after the last Set.
  uint32_t RankOf(size_t c) const {
    const uint64_t below = words_[c >> 6] & ((uint64_t{1} << (c & 63)) - 1);
    return ranks_[c >> 6] + static_cast<uint32_t>(std::popcount(below));
  }

 private:
  std::vector<uint64_t> words_;
  std::vector<uint32_t> ranks_;
};

}  // namespace

// The support points are bucketed in cubes of edge `reach` over their
// bounds (counting sort over the occupied cubes: a start per occupied
// cube, indices in cube order); a point looks at its own cube first, then
// the other 26 around it, unless its cube has no support point in those 27
// (most of the points no detection explains: the bin's floor and walls, a
// missed part). Which support points a cube holds, and so every answer, is
// the same as a dense start per cube of the bounds would give; the bitmaps
// cost 2 bits per cube of the bounds instead of 5 bytes, zeroed per frame.
void ExplainSupportCells(std::span<const Eigen::Vector3f> points, double reach, std::vector<uint8_t>& explained) {
  const double inv = 1.0 / reach;
  const float reach2 = static_cast<float>(reach * reach);
  auto key = [inv](const Eigen::Vector3f& p) {
    return Eigen::Array3<int64_t>(static_cast<int64_t>(std::floor(inv * p.x())),
                                  static_cast<int64_t>(std::floor(inv * p.y())),
                                  static_cast<int64_t>(std::floor(inv * p.z())));
  };
  Eigen::Array3<int64_t> lo = Eigen::Array3<int64_t>::Constant(std::numeric_limits<int64_t>::max());
  Eigen::Array3<int64_t> hi = Eigen::Array3<int64_t>::Constant(std::numeric_limits<int64_t>::min());
  std::vector<int32_t> seeds;
  for (size_t i = 0; i < points.size(); ++i) {
    if (!explained[i] || !points[i].allFinite()) continue;
    const Eigen::Array3<int64_t> k = key(points[i]);
    lo = lo.min(k);
    hi = hi.max(k);
    seeds.push_back(static_cast<int32_t>(i));
  }
  if (seeds.empty()) return;
  const Eigen::Array3<int64_t> dims = hi - lo + 1;
  // 2^24 cubes: a 0.6 m cube at 2.4 mm. Larger bounds (a far outlier among
  // the supports) keep the support points alone.
  constexpr int64_t kMaxCubes = int64_t{1} << 24;
  if (dims.x() > kMaxCubes / dims.y() / dims.z()) return;
  const auto index = [&](const Eigen::Array3<int64_t>& k) {
    const Eigen::Array3<int64_t> r = k - lo;
    return static_cast<size_t>((r.z() * dims.y() + r.y()) * dims.x() + r.x());
  };
  const size_t cubes = static_cast<size_t>(dims.prod());
  std::vector<size_t> seed_cube(seeds.size());
  CubeBits occupied(cubes);
  for (size_t s = 0; s < seeds.size(); ++s) {
    seed_cube[s] = index(key(points[static_cast<size_t>(seeds[s])]));
    occupied.Set(seed_cube[s]);
  }
  const size_t num_occupied = occupied.Rank();
  // Occupied cube of rank r holds order[start[r] .. start[r + 1] - 1], in seed order.
  std::vector<uint32_t> start(num_occupied + 1, 0);
  for (size_t c : seed_cube) ++start[occupied.RankOf(c) + 1];
  for (size_t r = 1; r < start.size(); ++r) start[r] += start[r - 1];
  std::vector<int32_t> order(seeds.size());
  {
    std::vector<uint32_t> fill(start.begin(), start.end() - 1);
    for (size_t s = 0; s < seeds.size(); ++s) order[fill[occupied.RankOf(seed_cube[s])]++] = seeds[s];
  }
  const auto near_in = [&](const Eigen::Array3<int64_t>& k, const Eigen::Vector3f& p) {
    if ((k < lo).any() || (k > hi).any()) return false;
    const size_t c = index(k);
    if (!occupied.Test(c)) return false;
    const uint32_t r = occupied.RankOf(c);
    for (uint32_t j = start[r]; j < start[r + 1]; ++j) {
      if ((points[static_cast<size_t>(order[j])] - p).squaredNorm() <= reach2) return true;
    }
    return false;
  };
  // The cubes of the bounds that hold a support point or have one among
  // their 26 neighbours (each occupied cube spreads once).
  CubeBits near_support(cubes), spread(cubes);
  for (size_t s = 0; s < seeds.size(); ++s) {
    if (spread.Test(seed_cube[s])) continue;
    spread.Set(seed_cube[s]);
    const Eigen::Array3<int64_t> k = key(points[static_cast<size_t>(seeds[s])]);
    for (int dz = -1; dz <= 1; ++dz) {
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          const Eigen::Array3<int64_t> n = k + Eigen::Array3<int64_t>(dx, dy, dz);
          if ((n >= lo).all() && (n <= hi).all()) near_support.Set(index(n));
        }
      }
    }
  }
  tbb::parallel_for(tbb::blocked_range<size_t>(0, points.size(), 4096), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t i = r.begin(); i < r.end(); ++i) {
      if (explained[i] || !points[i].allFinite()) continue;
      const Eigen::Vector3f& p = points[i];
      const Eigen::Array3<int64_t> k = key(p);
      // Beyond the bounds by more than a cube: no support point within reach.
      if ((k < lo - 1).any() || (k > hi + 1).any()) continue;
      if ((k >= lo).all() && (k <= hi).all() && !near_support.Test(index(k))) continue;
      bool near = near_in(k, p);
      for (int dz = -1; dz <= 1 && !near; ++dz) {
        for (int dy = -1; dy <= 1 && !near; ++dy) {
          for (int dx = -1; dx <= 1 && !near; ++dx) {
            if (dx != 0 || dy != 0 || dz != 0) near = near_in(k + Eigen::Array3<int64_t>(dx, dy, dz), p);
          }
        }
      }
      if (near) explained[i] = 1;
    }
  });
}

}  // namespace bp::internal
