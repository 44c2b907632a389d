// The perception pose stage's class pre-filter (internal/class_model.h) on the
// synthetic ground truth of the shipped default cell.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "pipeline/internal/class_model.h"
#include "pipeline/synthetic_source.h"

namespace bp {
namespace {

TEST(ClassPrefilter, NeverRejectsTheTrueClassOfAVisiblePart) {
  auto cell = LoadDefaultCell();
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  std::map<int, double> diameter;
  for (const PartSpec& part : cell->parts) {
    auto model = internal::BuildClassModel(part);
    ASSERT_TRUE(model.ok()) << model.status().ToString();
    diameter[part.class_id] = (*model)->diameter();
  }
  int checked = 0, rejected_pairs = 0;
  for (uint64_t seed : {1u, 2u, 3u}) {
    Cell scene_cell = *cell;
    scene_cell.source.seed = seed;  // default depth noise stays on
    auto source = MakeSyntheticSource(scene_cell);
    ASSERT_TRUE(source.ok()) << source.status().ToString();
    auto frame = (*source)->Capture({});
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    ASSERT_TRUE(frame->truth.has_value());
    // Every labelled pixel's point in B, grouped by instance.
    std::map<int, std::vector<Eigen::Vector3f>> points;
    for (int v = 0; v < frame->depth.height; ++v) {
      for (int u = 0; u < frame->depth.width; ++u) {
        const uint16_t label = frame->truth->labels.at(u, v);
        const float z = frame->depth.at(u, v);
        if (label == 0 || label == GroundTruth::kBinLabel || !std::isfinite(z)) continue;
        points[label].push_back((frame->X_BC * Deproject(frame->intrinsics, u, v, z).cast<double>()).cast<float>());
      }
    }
    for (const PartTruth& t : frame->truth->parts) {
      const auto it = points.find(t.instance_id);
      if (it == points.end() || it->second.size() < 50) continue;
      const Eigen::Vector3f e = internal::PrincipalExtents(it->second);
      EXPECT_TRUE(internal::SegmentFitsClass(e, diameter.at(t.class_id)))
          << "seed " << seed << " instance " << t.instance_id << " extent " << e.x() << " diameter "
          << diameter.at(t.class_id);
      ++checked;
    }
    // Two whole parts together are usually too large for either's class: the
    // filter does reject something.
    for (size_t a = 0; a + 1 < frame->truth->parts.size(); ++a) {
      const PartTruth& pa = frame->truth->parts[a];
      const PartTruth& pb = frame->truth->parts[a + 1];
      if (!points.contains(pa.instance_id) || !points.contains(pb.instance_id)) continue;
      std::vector<Eigen::Vector3f> both = points[pa.instance_id];
      both.insert(both.end(), points[pb.instance_id].begin(), points[pb.instance_id].end());
      rejected_pairs += !internal::SegmentFitsClass(internal::PrincipalExtents(both), diameter.at(pa.class_id));
    }
  }
  EXPECT_GE(checked, 30);
  EXPECT_GE(rejected_pairs, 10);
}

TEST(ClassPrefilter, PrincipalExtentsOfABoxAreItsSidesLargestFirst) {
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i <= 10; ++i) {
    for (int j = 0; j <= 10; ++j) {
      for (int k = 0; k <= 10; ++k) points.emplace_back(0.01f * i, 0.03f * j, 0.002f * k);
    }
  }
  points.emplace_back(NAN, 0.f, 0.f);
  const Eigen::Vector3f e = internal::PrincipalExtents(points);
  EXPECT_NEAR(e.x(), 0.3f, 1e-5f);
  EXPECT_NEAR(e.y(), 0.1f, 1e-5f);
  EXPECT_NEAR(e.z(), 0.02f, 1e-5f);
  EXPECT_EQ(internal::PrincipalExtents(std::vector<Eigen::Vector3f>{}), Eigen::Vector3f::Zero());
}

// Unit normals around `axis`'s great circle from angle 0 to `span` (radians).
std::vector<Eigen::Vector3f> Arc(double span, int n) {
  std::vector<Eigen::Vector3f> normals;
  for (int i = 0; i < n; ++i) {
    const double a = span * i / (n - 1);
    normals.emplace_back(static_cast<float>(std::cos(a)), 0.f, static_cast<float>(std::sin(a)));
  }
  return normals;
}

TEST(ClassPrefilter, PlanarShareIsOneForTwoPlanesAndLowForACylinder) {
  std::vector<Eigen::Vector3f> two_planes(300, Eigen::Vector3f::UnitZ());
  two_planes.insert(two_planes.end(), 200, Eigen::Vector3f::UnitX());
  two_planes.emplace_back(NAN, 0.f, 0.f);
  EXPECT_FLOAT_EQ(internal::PlanarShare(two_planes), 1.f);
  // Half a cylinder: two 30-degree windows of 180 degrees of normals.
  EXPECT_NEAR(internal::PlanarShare(Arc(M_PI, 1000)), 60.0 / 180.0, 0.02);
  // Three planes 90 degrees apart, the third twice as heavy: it and one other.
  // (120 normals: all of them are used.)
  std::vector<Eigen::Vector3f> three(40, Eigen::Vector3f::UnitX());
  three.insert(three.end(), 40, Eigen::Vector3f::UnitY());
  three.insert(three.end(), 40, Eigen::Vector3f::UnitZ());
  std::vector<float> weights(120, 1.f);
  std::fill(weights.begin() + 80, weights.end(), 2.f);
  EXPECT_NEAR(internal::PlanarShare(three, weights), 3.0 / 4.0, 1e-5);
  EXPECT_FLOAT_EQ(internal::PlanarShare(std::vector<Eigen::Vector3f>{Eigen::Vector3f::UnitZ()}), 0.f);
}

TEST(ClassPrefilter, PlanarShareRangesTellTheBracketFromTheTee) {
  // A planar part seen from anywhere shows its planes; a pipe never shows
  // much of one direction.
  std::vector<Eigen::Vector3f> box;
  for (int s : {-1, 1}) {
    for (int a = 0; a < 3; ++a) box.insert(box.end(), 50, static_cast<float>(s) * Eigen::Vector3f::Unit(a));
  }
  const auto [box_lo, box_hi] = internal::ModelPlanarShareRange(box, 64);
  EXPECT_GT(box_lo, 0.6f);  // 3 faces seen, 2 of them counted, at worst
  EXPECT_NEAR(box_hi, 1.f, 1e-5f);
  auto cell = LoadDefaultCell();
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  std::map<std::string, std::pair<float, float>> range;
  for (const PartSpec& part : cell->parts) {
    auto model = internal::BuildClassModel(part);
    ASSERT_TRUE(model.ok()) << model.status().ToString();
    range[part.name] = (*model)->planar_share_range();
    EXPECT_LE(range[part.name].first, range[part.name].second) << part.name;
  }
  ASSERT_TRUE(range.contains("l_bracket") && range.contains("pipe_tee"));
  EXPECT_GT(range["l_bracket"].first, range["pipe_tee"].second);
}

}  // namespace
}  // namespace bp
