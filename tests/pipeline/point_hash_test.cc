// PointHash against brute force: fixed-radius queries find exactly the points
// within the radius, each once, and within a cell in index order (which the
// pose estimator's float sums and nearest-point ties depend on).
#include "pipeline/internal/point_hash.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <tuple>
#include <utility>
#include <vector>

#include "pipeline/internal/int_math.h"

namespace bp::internal {
namespace {

std::vector<Eigen::Vector3f> Cloud(uint32_t seed, size_t n) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-0.05f, 0.05f);
  std::vector<Eigen::Vector3f> p;
  for (size_t i = 0; i < n; ++i) p.emplace_back(u(rng), u(rng), 0.3f * u(rng));
  // Duplicates and points exactly on cell borders.
  for (size_t i = 0; i < n / 10; ++i) p.push_back(p[i * 7 % n]);
  for (int i = -3; i <= 3; ++i) p.emplace_back(0.004f * static_cast<float>(i), 0.f, -0.004f);
  return p;
}

TEST(PointHash, QueriesFindExactlyThePointsWithinTheRadius) {
  for (uint32_t seed : {1u, 2u, 3u}) {
    const std::vector<Eigen::Vector3f> pts = Cloud(seed, 3000);
    PointHash hash;
    hash.Build(pts, 0.004f);
    ASSERT_EQ(hash.size(), pts.size());
    std::mt19937 rng(seed + 100);
    std::uniform_real_distribution<float> u(-0.06f, 0.06f);
    for (int q = 0; q < 300; ++q) {
      const Eigen::Vector3f c = q % 3 == 0 ? pts[static_cast<size_t>(q)] : Eigen::Vector3f(u(rng), u(rng), u(rng) * 0.3f);
      const float radius = q % 2 == 0 ? 0.002f : 0.004f;
      std::vector<int> expected;
      int nearest = -1;
      float nearest_d2 = radius * radius;
      for (size_t i = 0; i < pts.size(); ++i) {
        const float d2 = (pts[i] - c).squaredNorm();
        if (d2 <= radius * radius) expected.push_back(static_cast<int>(i));
        if (d2 < nearest_d2) {
          nearest_d2 = d2;
          nearest = static_cast<int>(i);
        }
      }
      std::vector<int> got;
      std::vector<std::pair<int, float>> visits;
      hash.ForEachWithin(c, radius, [&](int i, float d2) {
        got.push_back(i);
        visits.emplace_back(i, d2);
      });
      std::vector<int> sorted = got;
      std::sort(sorted.begin(), sorted.end());
      EXPECT_EQ(sorted, expected) << "seed " << seed << " query " << q;
      for (const auto& [i, d2] : visits) EXPECT_FLOAT_EQ(d2, (pts[static_cast<size_t>(i)] - c).squaredNorm());
      EXPECT_EQ(hash.AnyWithin(c, radius), !expected.empty());
      float d2 = -1;
      const int n = hash.Nearest(c, radius, &d2);
      if (nearest < 0) {
        EXPECT_EQ(n, -1);
      } else {
        ASSERT_GE(n, 0);
        EXPECT_FLOAT_EQ((pts[static_cast<size_t>(n)] - c).squaredNorm(), nearest_d2);
        EXPECT_FLOAT_EQ(d2, nearest_d2);
      }
    }
  }
}

TEST(PointHash, PointsOfOneCellComeInIndexOrder) {
  // Every point in one cell (cell 1 m): a query visits them in index order.
  std::vector<Eigen::Vector3f> pts;
  for (int i = 0; i < 50; ++i) pts.emplace_back(0.1f + 0.001f * static_cast<float>((i * 17) % 50), 0.2f, 0.3f);
  PointHash hash;
  hash.Build(pts, 1.f);
  std::vector<int> got;
  hash.ForEachWithin(Eigen::Vector3f(0.12f, 0.2f, 0.3f), 0.5f, [&](int i, float) { got.push_back(i); });
  ASSERT_EQ(got.size(), pts.size());
  EXPECT_TRUE(std::is_sorted(got.begin(), got.end()));
}

TEST(PointHash, CellRunsComeInKeyOrderAndHoldEveryPointOnce) {
  const std::vector<Eigen::Vector3f> pts = Cloud(4, 2000);
  const float cell = 0.005f;
  PointHash hash;
  hash.Build(pts, cell);
  // The key PointHash orders by: z, then y, then x cell coordinate.
  const auto cell_of = [&](uint32_t i) {
    const Eigen::Vector3f c = (pts[i] * (1.f / cell)).array().floor();  // as PointHash computes it
    return std::tuple<int, int, int>(static_cast<int>(c.z()), static_cast<int>(c.y()), static_cast<int>(c.x()));
  };
  std::vector<int> seen(pts.size(), 0);
  std::tuple<int, int, int> previous{std::numeric_limits<int>::min(), 0, 0};
  for (const auto& [begin, end] : hash.CellRunsByKey()) {
    ASSERT_LT(begin, end);
    const auto here = cell_of(hash.order()[begin]);
    EXPECT_LT(previous, here);
    previous = here;
    for (uint32_t k = begin; k < end; ++k) {
      const uint32_t i = hash.order()[k];
      EXPECT_EQ(cell_of(i), here);
      if (k > begin) {
        EXPECT_LT(hash.order()[k - 1], i);
      }
      ++seen[i];
    }
  }
  for (size_t i = 0; i < pts.size(); ++i) EXPECT_EQ(seen[i], 1) << i;
}

// The extremes of the counting sort: every point in a cell of its own (as
// many occupied slots as points, more than the first table's 3/4 holds, so
// Build grows it and starts over) and every point in one cell (one run).
TEST(PointHash, OneCellPerPointAndOneCellForAll) {
  std::vector<Eigen::Vector3f> lattice;
  for (int z = 0; z < 10; ++z) {
    for (int y = 0; y < 20; ++y) {
      for (int x = 0; x < 20; ++x) lattice.emplace_back(0.01f * (x + 0.5f), 0.01f * (y + 0.5f), 0.01f * (z + 0.5f));
    }
  }
  PointHash sparse;
  sparse.Build(lattice, 0.01f);
  EXPECT_EQ(sparse.CellRunsByKey().size(), lattice.size());
  for (size_t i = 0; i < lattice.size(); ++i) {
    float d2 = -1.f;
    EXPECT_EQ(sparse.Nearest(lattice[i] + Eigen::Vector3f(0.001f, 0.f, 0.f), 0.002f, &d2), static_cast<int>(i));
    EXPECT_NEAR(d2, 1e-6f, 1e-9f);
  }
  std::vector<Eigen::Vector3f> clump(500, Eigen::Vector3f(0.25f, 0.25f, 0.25f));
  PointHash dense;
  dense.Build(clump, 1.f);
  ASSERT_EQ(dense.CellRunsByKey().size(), 1u);
  int found = 0;
  dense.ForEachWithin(clump[0], 0.1f, [&](int i, float) { EXPECT_EQ(i, found++); });
  EXPECT_EQ(found, 500);
}

TEST(PointHash, EmptySetFindsNothing) {
  PointHash hash;
  hash.Build({}, 0.01f);
  EXPECT_EQ(hash.size(), 0u);
  EXPECT_FALSE(hash.AnyWithin(Eigen::Vector3f::Zero(), 0.01f));
  EXPECT_EQ(hash.Nearest(Eigen::Vector3f::Zero(), 0.01f), -1);
  EXPECT_TRUE(hash.CellRunsByKey().empty());
}

// The cells' coordinates (and verification's depth-buffer cells) come from
// FloorToInt: std::floor's integer for finite floats in int range.
TEST(IntMath, FloorToIntIsStdFloor) {
  std::mt19937 rng(17);
  std::uniform_real_distribution<float> wide(-1e6f, 1e6f), narrow(-3.f, 3.f);
  for (int i = 0; i < 200000; ++i) {
    const float f = i % 2 == 0 ? wide(rng) : narrow(rng);
    ASSERT_EQ(FloorToInt(f), static_cast<int>(std::floor(f))) << f;
  }
  for (float f : {0.f, -0.f, 1.f, -1.f, -0.5f, 0.5f, -1e-7f, 1e-7f, -2.f, -2.000001f, 16777215.f, -16777215.f,
                  2147483520.f, -2147483648.f}) {
    EXPECT_EQ(FloorToInt(f), static_cast<int>(std::floor(f))) << f;
  }
}

}  // namespace
}  // namespace bp::internal
