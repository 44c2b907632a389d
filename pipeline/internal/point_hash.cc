#include "pipeline/internal/point_hash.h"

#include <algorithm>
#include <bit>
#include <cmath>

namespace bp::internal {
namespace {
inline uint64_t Mix(uint64_t k) {
  k ^= k >> 33;
  k *= 0xff51afd7ed558ccdULL;
  k ^= k >> 33;
  return k;
}
}  // namespace

void PointHash::Build(std::span<const Eigen::Vector3f> points, float cell) {
  points_ = points;
  cell_ = cell;
  inv_cell_ = 1.f / cell;
  const size_t n = points.size();
  std::vector<uint64_t> keys(n);
  for (size_t i = 0; i < n; ++i) {
    keys[i] = Key(CellCoord(points[i].x()), CellCoord(points[i].y()), CellCoord(points[i].z()));
  }
  order_.resize(n);
  for (size_t i = 0; i < n; ++i) order_[i] = static_cast<uint32_t>(i);
  std::sort(order_.begin(), order_.end(), [&](uint32_t a, uint32_t b) { return keys[a] < keys[b]; });
  const size_t slots = std::bit_ceil(std::max<size_t>(16, 2 * n));
  table_.assign(slots, Slot{});
  mask_ = slots - 1;
  for (size_t k = 0; k < n;) {
    const uint64_t key = keys[order_[k]];
    size_t e = k + 1;
    while (e < n && keys[order_[e]] == key) ++e;
    uint64_t h = Mix(key) & mask_;
    while (table_[h].key != ~0ull) h = (h + 1) & mask_;
    table_[h] = Slot{key, static_cast<uint32_t>(k), static_cast<uint32_t>(e)};
    k = e;
  }
}

std::pair<uint32_t, uint32_t> PointHash::Range(uint64_t key) const {
  if (table_.empty()) return {0, 0};
  uint64_t h = Mix(key) & mask_;
  while (true) {
    const Slot& s = table_[h];
    if (s.key == key) return {s.begin, s.end};
    if (s.key == ~0ull) return {0, 0};
    h = (h + 1) & mask_;
  }
}

int PointHash::Nearest(const Eigen::Vector3f& q, float radius, float* d2_out) const {
  int best = -1;
  float best_d2 = radius * radius;
  ForEachWithin(q, radius, [&](int i, float d2) {
    if (d2 <= best_d2) {
      best_d2 = d2;
      best = i;
    }
  });
  if (d2_out) *d2_out = best_d2;
  return best;
}

bool PointHash::AnyWithin(const Eigen::Vector3f& q, float radius) const {
  bool any = false;
  ForEachWithin(q, radius, [&](int, float) { any = true; });
  return any;
}

}  // namespace bp::internal
