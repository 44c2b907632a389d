// The synthetic source on the shipped default cell and meshes.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <map>
#include <vector>

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

// A robot's cycle: capture, pick, capture. After a pick only the pixels the
// moved parts can reach are rendered again (scene and projector), and the
// noise recomputes its seed-independent part (normals, projector shadow)
// only there: the frames are the bytes of a source rendering everything
// anew, through picks of top parts and of parts under others (resettles),
// on the shipped meshes with the default noise.
TEST(SyntheticDefaultCell, CapturesAfterPicksGiveTheFramesOfFreshOnes) {
  auto cell = LoadDefaultCell();
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  cell->source.num_parts = 20;
  cell->source.seed = 7;
  cell->source.simulate_picks = true;
  auto cached = MakeSyntheticSource(*cell);
  auto fresh = MakeSyntheticSource(*cell);
  ASSERT_TRUE(cached.ok() && fresh.ok());
  auto* c = dynamic_cast<SyntheticSource*>(cached->get());
  auto* f = dynamic_cast<SyntheticSource*>(fresh->get());
  ASSERT_TRUE(c != nullptr && f != nullptr);
  const auto same = [](const auto& a, const auto& b) {
    return a.width == b.width && a.height == b.height &&
           std::memcmp(a.data.data(), b.data.data(), a.data.size() * sizeof(a.data[0])) == 0;
  };
  int64_t whole = 0, partial_captures = 0;
  for (int pick = 0; pick < 12; ++pick) {
    f->ForgetRenders();
    auto a = c->Capture({});
    auto b = f->Capture({});
    ASSERT_TRUE(a.ok() && b.ok());
    ASSERT_TRUE(same(a->depth, b->depth)) << "pick " << pick;
    ASSERT_TRUE(same(a->intensity, b->intensity)) << "pick " << pick;
    ASSERT_TRUE(same(a->truth->labels, b->truth->labels)) << "pick " << pick;
    ASSERT_EQ(a->truth->parts.size(), b->truth->parts.size());
    for (size_t i = 0; i < a->truth->parts.size(); ++i) {
      EXPECT_EQ(a->truth->parts[i].visible_pixels, b->truth->parts[i].visible_pixels);
      EXPECT_EQ(a->truth->parts[i].unoccluded_pixels, b->truth->parts[i].unoccluded_pixels);
    }
    if (pick == 0) whole = f->rendered_pixels();
    EXPECT_EQ(f->rendered_pixels(), whole);
    if (pick > 0 && c->rendered_pixels() < whole) ++partial_captures;
    // Top parts (the most visible) mostly; every third pick the least
    // visible part seen, so that parts above it resettle.
    const auto& parts = a->truth->parts;
    std::vector<PartTruth> seen;
    for (const PartTruth& t : parts) {
      if (t.visible_pixels > 0) seen.push_back(t);
    }
    ASSERT_FALSE(seen.empty());
    const auto by_visible = [](const PartTruth& x, const PartTruth& y) { return x.visible_pixels < y.visible_pixels; };
    const int id = pick % 3 == 2 ? std::min_element(seen.begin(), seen.end(), by_visible)->instance_id
                                 : std::max_element(seen.begin(), seen.end(), by_visible)->instance_id;
    c->NotifyPicked(id);
    f->NotifyPicked(id);
  }
  EXPECT_GE(partial_captures, 8) << "the captures after picks rendered the whole images";
}

// Parts of the pile that rest on nothing: 0.5 mm lower (more than the
// pile's 0.2 mm bisection tolerance) they would meet neither the bin nor
// another part. The pile is dropped straight down, so a part that meets
// nothing there would fall.
std::vector<int> Hanging(const SyntheticPile& pile) {
  std::vector<int> out;
  for (const PilePart& p : pile.parts()) {
    Pose lower = p.X_WO;
    lower.translation().z() -= 0.0005;
    const int self[] = {p.instance_id};
    if (!pile.scene().Collides(*pile.class_geometry(p.class_index), lower, self)) out.push_back(p.instance_id);
  }
  return out;
}

// After every pick no part is left resting on nothing: a part resting on
// (or leaning on) a part that dropped when its support was picked drops
// too. Picks in drop order (the parts under the others first), on piles of
// the shipped parts, whose brackets and tees lean on each other.
TEST(SyntheticDefaultCell, NoPartIsLeftRestingOnNothingAfterAPick) {
  auto cell = LoadDefaultCell();
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  cell->source.num_parts = 20;
  cell->source.simulate_picks = true;
  int dropped = 0;
  for (uint64_t seed = 1; seed <= 4; ++seed) {
    cell->source.seed = seed;
    auto source = MakeSyntheticSource(*cell);
    ASSERT_TRUE(source.ok()) << source.status().ToString();
    auto* s = dynamic_cast<SyntheticSource*>(source->get());
    ASSERT_NE(s, nullptr);
    ASSERT_TRUE(Hanging(s->pile()).empty()) << "seed " << seed << ": the dropped pile";
    while (!s->pile().parts().empty()) {
      const int id = s->pile().parts().front().instance_id;
      std::map<int, double> z_before;
      for (const PilePart& p : s->pile().parts()) z_before[p.instance_id] = p.X_WO.translation().z();
      s->NotifyPicked(id);
      ASSERT_EQ(s->pile().Find(id), nullptr);
      for (const PilePart& p : s->pile().parts()) dropped += p.X_WO.translation().z() < z_before[p.instance_id] - 0.001 ? 1 : 0;
      const std::vector<int> hanging = Hanging(s->pile());
      EXPECT_TRUE(hanging.empty()) << "seed " << seed << ", part " << id << " picked: " << hanging.size()
                                   << " parts rest on nothing, the first " << hanging.front();
      for (const PilePart& p : s->pile().parts()) {
        EXPECT_FALSE(s->pile().scene().ObjectCollides(p.instance_id)) << p.instance_id;
      }
    }
  }
  EXPECT_GT(dropped, 20) << "the picks moved too few parts to test the resettling";
}

}  // namespace
}  // namespace bp
