#include "pipeline/synthetic_pile.h"

#include <gtest/gtest.h>

#include "tests/test_meshes.h"

namespace bp {
namespace {

BinSpec SmallBin() {
  BinSpec bin;
  bin.inner_size = Vec3(0.3, 0.2, 0.15);
  bin.wall_thickness = 0.01;
  return bin;
}

std::vector<PileClass> TwoClasses() {
  std::vector<PileClass> c(2);
  c[0].class_id = 0;
  c[0].name = "block";
  c[0].mesh = std::make_shared<TriangleMesh>(testing::BoxMesh({0.06f, 0.04f, 0.02f}));
  c[1].class_id = 1;
  c[1].name = "puck";
  c[1].mesh = std::make_shared<TriangleMesh>(testing::CylinderMesh(0.02f, 0.03f));
  return c;
}

Result<SyntheticPile> MakePile(int n, uint64_t seed) {
  const BinSpec bin = SmallBin();
  PileOptions o;
  o.num_parts = n;
  o.seed = seed;
  return SyntheticPile::Generate(bin, testing::OpenBinMesh(bin.inner_size.cast<float>(), 0.01f),
                                 TwoClasses(), o);
}

void ExpectNoInterpenetration(const SyntheticPile& pile) {
  const auto& scene = pile.scene();
  for (const auto& p : pile.parts()) {
    EXPECT_FALSE(scene.ObjectCollides(p.instance_id)) << "part " << p.instance_id;
  }
}

TEST(SyntheticPile, SameSeedReproducesThePileExactly) {
  auto a = MakePile(10, 7), b = MakePile(10, 7), c = MakePile(10, 8);
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  ASSERT_EQ(a->parts().size(), b->parts().size());
  for (size_t i = 0; i < a->parts().size(); ++i) {
    EXPECT_EQ(a->parts()[i].class_id, b->parts()[i].class_id);
    EXPECT_TRUE(a->parts()[i].X_WO.matrix() == b->parts()[i].X_WO.matrix());
  }
  EXPECT_FALSE(a->parts()[0].X_WO.matrix() == c->parts()[0].X_WO.matrix());
}

TEST(SyntheticPile, PartsRestInsideTheBinWithoutInterpenetration) {
  auto pile = MakePile(15, 3);
  ASSERT_TRUE(pile.ok()) << pile.status().ToString();
  EXPECT_EQ(pile->parts().size() + pile->skipped(), 15u);
  EXPECT_GE(pile->parts().size(), 12u);
  ExpectNoInterpenetration(*pile);
  const BinSpec bin = SmallBin();
  int touching = 0;
  for (const auto& p : pile->parts()) {
    const auto box = pile->class_geometry(p.class_index)->WorldBounds(p.X_WO);
    EXPECT_GE(box.min().x(), -bin.inner_size.x() / 2 - 1e-6);
    EXPECT_LE(box.max().x(), bin.inner_size.x() / 2 + 1e-6);
    EXPECT_GE(box.min().y(), -bin.inner_size.y() / 2 - 1e-6);
    EXPECT_LE(box.max().y(), bin.inner_size.y() / 2 + 1e-6);
    EXPECT_GE(box.min().z(), -1e-6);
    // Resting: 0.5 mm lower it would touch something.
    Pose lower = p.X_WO;
    lower.translation().z() -= 0.0005;
    const int self[] = {p.instance_id};
    touching += pile->scene().Collides(*pile->class_geometry(p.class_index), lower, self) ? 1 : 0;
  }
  EXPECT_EQ(touching, static_cast<int>(pile->parts().size()));
}

TEST(SyntheticPile, PartsStackWhenTheFloorIsCovered) {
  auto pile = MakePile(30, 5);
  ASSERT_TRUE(pile.ok());
  int stacked = 0;
  for (const auto& p : pile->parts()) {
    const auto box = pile->class_geometry(p.class_index)->WorldBounds(p.X_WO);
    stacked += box.min().z() > 0.01 ? 1 : 0;
  }
  EXPECT_GT(stacked, 0);
  ExpectNoInterpenetration(*pile);
}

TEST(SyntheticPile, RemovingAPartLetsThePartsAboveResettle) {
  auto pile = MakePile(30, 5);
  ASSERT_TRUE(pile.ok());
  // Find a part q that rests on exactly one other part (its only support).
  int victim = -1, q = -1;
  for (const auto& p : pile->parts()) {
    Pose lower = p.X_WO;
    lower.translation().z() -= 0.0005;
    const int self[] = {p.instance_id};
    const auto support =
        pile->scene().CollidingIds(*pile->class_geometry(p.class_index), lower, self);
    if (support.size() == 1 && support[0] != SyntheticPile::kBinId) {
      victim = support[0];
      q = p.instance_id;
      break;
    }
  }
  ASSERT_NE(victim, -1) << "no stacked part in this pile";
  const double z_before = pile->Find(q)->X_WO.translation().z();
  const size_t n = pile->parts().size();
  ASSERT_TRUE(pile->RemovePart(victim).ok());
  EXPECT_EQ(pile->parts().size(), n - 1);
  EXPECT_EQ(pile->Find(victim), nullptr);
  EXPECT_FALSE(pile->scene().Contains(victim));
  EXPECT_FALSE(pile->RemovePart(victim).ok());
  ExpectNoInterpenetration(*pile);
  EXPECT_LT(pile->Find(q)->X_WO.translation().z(), z_before - 0.001)
      << "part " << q << " did not fall";
}

}  // namespace
}  // namespace bp
