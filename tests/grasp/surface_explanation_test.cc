// Points explained by detected parts' surfaces (grasp/internal/
// surface_explanation.h): ExplainBySurfaces marks, and lists per part,
// exactly the points some part's PartSurface::Explains accepts at its pose,
// whatever its pre-filters skip.
#include "grasp/internal/surface_explanation.h"

#include <gtest/gtest.h>

#include <random>
#include <vector>

#include "core/mesh_gen.h"

namespace bp {
namespace {

TEST(SurfaceExplanation, ExplainsExactlyThePointsAPartsSurfaceExplainsAtItsPose) {
  constexpr float kRadius = 0.002f;
  const internal::PartSurface bracket = internal::PartSurface::Sample(MakeLBracket(), 0.0005, kRadius);
  const internal::PartSurface tee = internal::PartSurface::Sample(MakePipeTee(), 0.0005, kRadius);
  std::mt19937 rng(45);
  std::uniform_real_distribution<double> angle(-M_PI, M_PI), in_bin(-0.15, 0.15), unit(0.0, 1.0);
  // Twelve parts at random poses in a bin-sized box, some overlapping.
  std::vector<internal::PlacedSurface> parts;
  for (int k = 0; k < 12; ++k) {
    const Vec3 axis = Vec3(angle(rng), angle(rng), angle(rng)).normalized();
    parts.push_back({k % 2 == 0 ? &bracket : &tee,
                     MakePose(Mat3(Eigen::AngleAxisd(angle(rng), axis)), Vec3(in_bin(rng), in_bin(rng), 0.1 * unit(rng)))});
  }
  // Points on or near the parts' surfaces (their samples' neighbourhood:
  // points of the parts' own mesh vertices, jittered) and spread over the box.
  std::vector<Eigen::Vector3f> points;
  std::normal_distribution<float> jitter(0.f, 0.0015f);
  for (const internal::PlacedSurface& p : parts) {
    const TriangleMesh mesh = p.surface == &bracket ? MakeLBracket() : MakePipeTee();
    for (const Eigen::Vector3f& v : mesh.vertices) {
      points.push_back((p.X_BO * v.cast<double>()).cast<float>() + Eigen::Vector3f(jitter(rng), jitter(rng), jitter(rng)));
    }
  }
  for (int i = 0; i < 20000; ++i) points.emplace_back(in_bin(rng), in_bin(rng), 0.12 * unit(rng) - 0.01);
  const Eigen::Vector3f eye(0.f, 0.f, 1.2f);
  const float min_cos = -0.17f;
  std::vector<uint8_t> explained(points.size(), 0);
  std::vector<std::vector<uint32_t>> owned;
  internal::ExplainBySurfaces(points, parts, kRadius, eye, min_cos, explained, &owned);
  ASSERT_EQ(owned.size(), parts.size());
  int marked = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    bool any = false;
    for (size_t k = 0; k < parts.size(); ++k) {
      const Pose X_OB = parts[k].X_BO.inverse();
      const Eigen::Vector3f q = X_OB.linear().cast<float>() * points[i] + X_OB.translation().cast<float>();
      const Eigen::Vector3f eye_O = X_OB.linear().cast<float>() * eye + X_OB.translation().cast<float>();
      const bool by_k = parts[k].surface->Explains(q, kRadius, &eye_O, min_cos);
      any = any || by_k;
      EXPECT_EQ(std::binary_search(owned[k].begin(), owned[k].end(), static_cast<uint32_t>(i)), by_k)
          << "point " << i << " part " << k;
    }
    EXPECT_EQ(explained[i] != 0, any) << "point " << i;
    marked += any ? 1 : 0;
  }
  EXPECT_GT(marked, 500);
  EXPECT_LT(marked, static_cast<int>(points.size()) - 10000);
}

}  // namespace
}  // namespace bp
