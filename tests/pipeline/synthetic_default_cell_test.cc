// The synthetic source on the shipped default cell and meshes.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "core/mesh.h"
#include "pipeline/synthetic_source.h"

namespace bp {
namespace {

TEST(SyntheticDefaultCell, CapturesAConsistentPileOfTheShippedParts) {
  auto cell = LoadDefaultCell();
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  cell->source.num_parts = 12;
  for (auto& c : cell->camera.configs) c.noise.enabled = false;
  auto source = MakeSyntheticSource(*cell);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  auto* synthetic = dynamic_cast<SyntheticSource*>(source->get());
  ASSERT_NE(synthetic, nullptr);
  EXPECT_EQ(static_cast<int>(synthetic->pile().parts().size()) + synthetic->pile().skipped(), 12);
  EXPECT_GE(synthetic->pile().parts().size(), 10u);
  for (const auto& p : synthetic->pile().parts()) {
    EXPECT_FALSE(synthetic->pile().scene().ObjectCollides(p.instance_id)) << p.instance_id;
  }

  auto frame = (*source)->Capture({});
  ASSERT_TRUE(frame.ok()) << frame.status().ToString();
  ASSERT_TRUE(frame->truth.has_value());
  EXPECT_EQ(frame->depth.width, 640);
  EXPECT_EQ(frame->truth->parts.size(), synthetic->pile().parts().size());
  std::vector<TriangleMesh> meshes;
  for (const auto& p : cell->parts) meshes.push_back(*LoadMesh(p.mesh));

  // Every 8th labelled pixel lies within 0.5 mm of the plane of one of its
  // part's triangles whose bounds (grown by 0.5 mm) contain it.
  int checked = 0, off = 0;
  for (int v = 0; v < frame->depth.height; v += 8) {
    for (int u = 0; u < frame->depth.width; u += 8) {
      const uint16_t label = frame->truth->labels.at(u, v);
      const float z = frame->depth.at(u, v);
      if (label == 0 || label == GroundTruth::kBinLabel || !std::isfinite(z)) continue;
      const auto it = std::find_if(frame->truth->parts.begin(), frame->truth->parts.end(),
                                   [&](const PartTruth& t) { return t.instance_id == label; });
      ASSERT_NE(it, frame->truth->parts.end());
      const Eigen::Vector3f p_O =
          (it->X_BO.inverse() * frame->X_BC * Deproject(frame->intrinsics, u, v, z).cast<double>())
              .cast<float>();
      const TriangleMesh& m = meshes[it->class_id];
      double best = 1e9;
      for (const auto& t : m.triangles) {
        const Eigen::Vector3f a = m.vertices[t[0]], b = m.vertices[t[1]], c = m.vertices[t[2]];
        Eigen::AlignedBox3f box(a);
        box.extend(b).extend(c);
        if (box.exteriorDistance(p_O) > 0.0005f) continue;
        const Eigen::Vector3f n = (b - a).cross(c - a).normalized();
        best = std::min(best, static_cast<double>(std::abs(n.dot(p_O - a))));
      }
      ++checked;
      off += best > 0.0005 ? 1 : 0;
    }
  }
  EXPECT_GT(checked, 100);
  EXPECT_EQ(off, 0);
}

}  // namespace
}  // namespace bp
