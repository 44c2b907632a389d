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
  cell_ = cell;
  inv_cell_ = 1.f / cell;
  const size_t n = points.size();
  // Counting sort through the table itself, O(n): each point finds (or
  // opens) its cell's slot and counts in it; the slots' runs in order_ are
  // laid out in slot order; the points are scattered in index order, so
  // within a cell they keep index order (half the time of a sort of (key,
  // index) pairs).
  //
  // The table holds the occupied cells, not the points: the views' hashes
  // hold 2-9 points per cell, and a table of 2 slots per point spent most
  // of Build walking and clearing empty slots. It starts at one slot per
  // point and grows fourfold (starting over) past 3/4 full, so a set with a
  // point per cell still gets a table, and the probe sequences stay short.
  std::vector<uint32_t> slot_of(n);
  for (size_t slots = std::bit_ceil(std::max<size_t>(16, n));; slots *= 4) {
    table_.assign(slots, Slot{});
    mask_ = slots - 1;
    const size_t max_used = slots / 4 * 3;
    size_t used = 0;
    size_t i = 0;
    for (; i < n; ++i) {
      const uint64_t key = Key(CellCoord(points[i].x()), CellCoord(points[i].y()), CellCoord(points[i].z()));
      uint64_t h = Mix(key) & mask_;
      while (table_[h].key != key && table_[h].key != ~0ull) h = (h + 1) & mask_;
      if (table_[h].key != key) {
        if (++used > max_used) break;
        table_[h].key = key;
      }
      ++table_[h].end;  // the count, for now
      slot_of[i] = static_cast<uint32_t>(h);
    }
    if (i == n) break;
  }
  uint32_t begin = 0;
  for (Slot& slot : table_) {
    if (slot.key == ~0ull) continue;
    slot.begin = begin;
    begin += slot.end;
    slot.end = slot.begin;  // the fill cursor, for now; the run's end once filled
  }
  order_.resize(n);
  sorted_.resize(n);
  for (size_t i = 0; i < n; ++i) {
    const uint32_t k = table_[slot_of[i]].end++;
    order_[k] = static_cast<uint32_t>(i);
    sorted_[k] = points[i];
  }
}

std::vector<std::pair<uint32_t, uint32_t>> PointHash::CellRunsByKey() const {
  std::vector<const Slot*> cells;
  for (const Slot& slot : table_) {
    if (slot.key != ~0ull) cells.push_back(&slot);
  }
  std::sort(cells.begin(), cells.end(), [](const Slot* a, const Slot* b) { return a->key < b->key; });
  std::vector<std::pair<uint32_t, uint32_t>> runs;
  runs.reserve(cells.size());
  for (const Slot* slot : cells) runs.emplace_back(slot->begin, slot->end);
  return runs;
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
  // Left at the first point within radius (the verification's support test
  // asks this once per visible sample).
  return VisitWithin(q, radius, [](int, float) { return true; });
}

}  // namespace bp::internal
