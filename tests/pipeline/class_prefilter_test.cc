// The perception pose stage's class pre-filter (internal/class_model.h) on the
// synthetic ground truth of the shipped default cell.
#include <gtest/gtest.h>

#include <cmath>
#include <map>
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

}  // namespace
}  // namespace bp
