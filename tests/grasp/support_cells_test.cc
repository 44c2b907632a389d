// The points a support sample stands for (grasp/internal/support_cells.h):
// every point within the distance of a support point, and no other, against
// the pairwise test over every point and support point.
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "grasp/internal/support_cells.h"

namespace bp {
namespace {

// explained after the rule, by testing each point against every support point.
std::vector<uint8_t> PairwiseExplained(const std::vector<Eigen::Vector3f>& points, double reach,
                                       const std::vector<uint8_t>& support) {
  const float reach2 = static_cast<float>(reach * reach);
  std::vector<size_t> seeds;
  for (size_t j = 0; j < points.size(); ++j) {
    if (support[j] && points[j].allFinite()) seeds.push_back(j);
  }
  std::vector<uint8_t> out = support;
  for (size_t i = 0; i < points.size(); ++i) {
    if (out[i] || !points[i].allFinite()) continue;
    for (size_t j : seeds) {
      if ((points[j] - points[i]).squaredNorm() <= reach2) out[i] = 1;
    }
  }
  return out;
}

TEST(SupportCells, ExplainsExactlyThePointsWithinReachOfASupportPoint) {
  constexpr double kReach = 0.0024;  // twice perception's grid spacing
  std::mt19937 rng(12);
  // Clusters a few reaches wide (a part's surface and the points round it)
  // in a bin-sized box, and a floor of points; about one point in six is
  // support, most of them in the first clusters.
  std::uniform_real_distribution<float> in_bin(-0.2f, 0.2f), in_cluster(-0.006f, 0.006f), unit(0.f, 1.f);
  std::vector<Eigen::Vector3f> points;
  std::vector<uint8_t> support;
  for (int c = 0; c < 40; ++c) {
    const Eigen::Vector3f centre(in_bin(rng), in_bin(rng), 0.5f * (in_bin(rng) + 0.2f));
    for (int i = 0; i < 150; ++i) {
      points.push_back(centre + Eigen::Vector3f(in_cluster(rng), in_cluster(rng), in_cluster(rng)));
      support.push_back(c < 25 && unit(rng) < 0.3f ? 1 : 0);
    }
  }
  for (float x = -0.2f; x <= 0.2f; x += 0.004f) {
    for (float y = -0.2f; y <= 0.2f; y += 0.004f) {
      points.emplace_back(x, y, 0.0005f * unit(rng));
      support.push_back(unit(rng) < 0.002f ? 1 : 0);
    }
  }
  points.emplace_back(std::numeric_limits<float>::quiet_NaN(), 0.f, 0.f);
  support.push_back(0);
  const std::vector<uint8_t> expected = PairwiseExplained(points, kReach, support);
  std::vector<uint8_t> explained = support;
  internal::ExplainSupportCells(points, kReach, explained);
  int added = 0, left = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    EXPECT_EQ(explained[i], expected[i]) << "point " << i;
    if (!support[i]) (expected[i] ? added : left) += 1;
  }
  // Both answers occur: the test is not one-sided.
  EXPECT_GT(added, 500);
  EXPECT_GT(left, 5000);
}

TEST(SupportCells, BoundsBeyondTheCubeLimitKeepTheSupportAlone) {
  // Two support points 50 m apart: more than 2^24 cubes of 2.4 mm between them.
  std::vector<Eigen::Vector3f> points = {Eigen::Vector3f(0, 0, 0), Eigen::Vector3f(50.f, 50.f, 50.f),
                                         Eigen::Vector3f(0.001f, 0, 0)};
  std::vector<uint8_t> explained = {1, 1, 0};
  internal::ExplainSupportCells(points, 0.0024, explained);
  EXPECT_EQ(explained[2], 0);
  explained = {1, 0, 0};
  internal::ExplainSupportCells(points, 0.0024, explained);
  EXPECT_EQ(explained, (std::vector<uint8_t>{1, 0, 1}));
}

}  // namespace
}  // namespace bp
