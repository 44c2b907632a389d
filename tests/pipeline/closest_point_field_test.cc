// ClosestPointField against the brute force it replaced: every voxel within
// the band holds the sample nearest its centre, the same index (ties too),
// and every voxel beyond it holds -1.
#include "pipeline/internal/closest_point_field.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>
#include <vector>

#include "core/mesh_gen.h"
#include "pipeline/internal/model_sampling.h"

namespace bp::internal {
namespace {

struct Reference {
  Eigen::Vector3f origin;
  Eigen::Vector3i dims;
  std::vector<int32_t> cells;
};

// The cube scan ClosestPointField::Build used before it clipped to the band's
// sphere, verbatim.
Reference BruteForce(const std::vector<Eigen::Vector3f>& points, float voxel, float band) {
  Reference r;
  const float inv_voxel = 1.f / voxel;
  Eigen::AlignedBox3f box;
  for (const auto& p : points) box.extend(p);
  r.origin = box.min() - Eigen::Vector3f::Constant(band + voxel);
  const Eigen::Vector3f extent = box.max() + Eigen::Vector3f::Constant(band + voxel) - r.origin;
  r.dims = (extent * inv_voxel).array().ceil().cast<int>().matrix();
  const size_t n = static_cast<size_t>(r.dims.x()) * r.dims.y() * r.dims.z();
  r.cells.assign(n, -1);
  std::vector<float> best(n, band * band);
  const int reach = static_cast<int>(std::ceil(band * inv_voxel));
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3f g = (points[i] - r.origin) * inv_voxel;
    const int cx = static_cast<int>(g.x()), cy = static_cast<int>(g.y()),
              cz = static_cast<int>(g.z());
    for (int z = std::max(0, cz - reach); z <= std::min(r.dims.z() - 1, cz + reach); ++z) {
      for (int y = std::max(0, cy - reach); y <= std::min(r.dims.y() - 1, cy + reach); ++y) {
        for (int x = std::max(0, cx - reach); x <= std::min(r.dims.x() - 1, cx + reach); ++x) {
          const Eigen::Vector3f centre =
              r.origin + (Eigen::Vector3f(x, y, z) + Eigen::Vector3f::Constant(0.5f)) * voxel;
          const float d2 = (centre - points[i]).squaredNorm();
          const size_t c = (static_cast<size_t>(z) * r.dims.y() + y) * r.dims.x() + x;
          if (d2 < best[c]) {
            best[c] = d2;
            r.cells[c] = static_cast<int32_t>(i);
          }
        }
      }
    }
  }
  return r;
}

// Compares the field with the reference at every voxel centre. @returns the
// number of voxels inside the band (so a test can see it checked something).
int ExpectSameAsBruteForce(const std::vector<Eigen::Vector3f>& points, float voxel, float band) {
  ClosestPointField field;
  field.Build(points, voxel, band);
  const Reference ref = BruteForce(points, voxel, band);
  int inside = 0, mismatches = 0;
  for (int z = 0; z < ref.dims.z(); ++z) {
    for (int y = 0; y < ref.dims.y(); ++y) {
      for (int x = 0; x < ref.dims.x(); ++x) {
        const Eigen::Vector3f centre =
            ref.origin + (Eigen::Vector3f(x, y, z) + Eigen::Vector3f::Constant(0.5f)) * voxel;
        const int expected =
            ref.cells[(static_cast<size_t>(z) * ref.dims.y() + y) * ref.dims.x() + x];
        if (expected >= 0) ++inside;
        if (field.Lookup(centre) != expected && ++mismatches <= 5) {
          ADD_FAILURE() << "voxel (" << x << ", " << y << ", " << z << "): " << field.Lookup(centre)
                        << ", brute force " << expected;
        }
      }
    }
  }
  EXPECT_EQ(mismatches, 0);
  return inside;
}

TEST(ClosestPointField, RandomCloudsMatchTheBruteForceScanVoxelForVoxel) {
  std::mt19937 rng(7);
  for (int trial = 0; trial < 6; ++trial) {
    std::uniform_real_distribution<float> coord(-0.02f, 0.03f);
    std::vector<Eigen::Vector3f> points;
    const int n = 50 + 150 * trial;
    for (int i = 0; i < n; ++i) points.emplace_back(coord(rng), coord(rng), coord(rng));
    // Duplicates make exact ties: the lower index must keep the voxel.
    points.push_back(points[3]);
    points.push_back(points[n / 2]);
    const float voxel = 0.001f * (1 + trial % 3);
    const float band = voxel * (1.5f + trial);
    EXPECT_GT(ExpectSameAsBruteForce(points, voxel, band), 0) << "trial " << trial;
  }
}

TEST(ClosestPointField, TheShippedLBracketSamplingMatchesTheBruteForceScan) {
  // The pose estimator's use: dense surface samples, 1 mm voxels, a band of
  // several voxels.
  const OrientedPoints dense = SampleSurface(MakeLBracket(), 0.0015, 1);
  ASSERT_GT(dense.points.size(), 1000u);
  EXPECT_GT(ExpectSameAsBruteForce(dense.points, 0.0015f, 0.006f), 10000);
}

TEST(ClosestPointField, NoPointOutsideTheGridSphereHasASample) {
  // CountInside and MarkOnSurface skip points outside the sphere before
  // transforming them: Lookup and Nearest must give -1 for every such point.
  const OrientedPoints dense = SampleSurface(MakeLBracket(), 0.0015, 1);
  ClosestPointField field;
  field.Build(dense.points, 0.0015f, 0.006f);
  const Eigen::Vector3f c = field.grid_centre();
  const float r = field.grid_radius();
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(-1.f, 1.f);
  int found_inside = 0, outside = 0;
  for (int i = 0; i < 200000; ++i) {
    const Eigen::Vector3f q = c + 1.2f * r * Eigen::Vector3f(u(rng), u(rng), u(rng));
    const bool has = field.Lookup(q) >= 0 || field.Nearest(q, dense.points) >= 0;
    if ((q - c).norm() > r) {
      ++outside;
      EXPECT_FALSE(has) << "a sample for a point " << (q - c).norm() - r << " m outside the sphere";
    } else {
      found_inside += has ? 1 : 0;
    }
  }
  EXPECT_GT(outside, 10000);
  EXPECT_GT(found_inside, 1000);
}

}  // namespace
}  // namespace bp::internal
