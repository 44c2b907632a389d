// The model table memo (pipeline/internal/table_memo.h): a closest-point
// field, PPF table or model geometry (surface samples, diameter, extreme
// points, edge planes) copied from the memo answers every lookup as a fresh
// build from the same inputs does, and inputs that differ in one point, or
// in one parameter, are built again, not copied.
#include "pipeline/internal/table_memo.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <vector>

#include "core/mesh_gen.h"
#include "pipeline/internal/closest_point_field.h"
#include "pipeline/internal/model_geometry.h"
#include "pipeline/internal/model_sampling.h"
#include "pipeline/internal/ppf_matcher.h"
#include "pipeline/pose_estimator.h"

namespace bp::internal {
namespace {

// Sets the memo for the test's scope and restores the process's setting
// (bp_pipeline_tests runs with it on).
class MemoScope {
 public:
  explicit MemoScope(bool on) : was_(ModelTableMemoOn()) { SetModelTableMemo(on); }
  ~MemoScope() { SetModelTableMemo(was_); }

 private:
  bool was_;
};

// Lookup and Nearest of the field at the centres of a grid of voxels
// (step 1.3 mm) over the points' box and band.
std::vector<int> Answers(const ClosestPointField& field, const std::vector<Eigen::Vector3f>& points) {
  Eigen::AlignedBox3f box;
  for (const auto& p : points) box.extend(p);
  box.extend(box.min() - Eigen::Vector3f::Constant(0.01f));
  box.extend(box.max() + Eigen::Vector3f::Constant(0.01f));
  std::vector<int> out;
  for (float z = box.min().z(); z <= box.max().z(); z += 0.0013f) {
    for (float y = box.min().y(); y <= box.max().y(); y += 0.0013f) {
      for (float x = box.min().x(); x <= box.max().x(); x += 0.0013f) {
        out.push_back(field.Lookup({x, y, z}));
        out.push_back(field.Nearest({x, y, z}, points));
      }
    }
  }
  return out;
}

TEST(ModelTableMemo, AFieldCopiedFromTheMemoAnswersAsAFreshBuild) {
  const std::vector<Eigen::Vector3f> points = SampleSurface(MakeLBracket(), 0.002, 1).points;
  std::vector<Eigen::Vector3f> moved = points;
  moved[moved.size() / 2] += Eigen::Vector3f(0.001f, 0.f, 0.f);
  ClosestPointField fresh, fresh_moved, fresh_band;
  {
    MemoScope off(false);
    fresh.Build(points, 0.001f, 0.006f);
    fresh_moved.Build(moved, 0.001f, 0.006f);
    fresh_band.Build(points, 0.001f, 0.004f);
  }
  MemoScope on(true);
  ClosestPointField first, copied, moved_field, band_field;
  first.Build(points, 0.001f, 0.006f);
  const size_t hits = ModelTableMemoHits();
  copied.Build(points, 0.001f, 0.006f);
  EXPECT_EQ(ModelTableMemoHits(), hits + 1);
  moved_field.Build(moved, 0.001f, 0.006f);
  band_field.Build(points, 0.001f, 0.004f);
  EXPECT_EQ(ModelTableMemoHits(), hits + 1);

  const std::vector<int> expected = Answers(fresh, points);
  EXPECT_EQ(Answers(first, points), expected);
  EXPECT_EQ(Answers(copied, points), expected);
  EXPECT_EQ(copied.memory_bytes(), fresh.memory_bytes());
  // Built again from their own inputs: their own answers, not the first's.
  EXPECT_EQ(Answers(moved_field, moved), Answers(fresh_moved, moved));
  EXPECT_NE(Answers(moved_field, moved), Answers(fresh, moved));
  EXPECT_EQ(Answers(band_field, points), Answers(fresh_band, points));
  EXPECT_NE(Answers(band_field, points), expected);
}

TEST(ModelTableMemo, APpfTableCopiedFromTheMemoMatchesAsAFreshBuild) {
  const OrientedPoints m = SampleSurface(MakeLBracket(), 0.004, 1);
  const float diameter = static_cast<float>(PointSetDiameter(m.points));
  PpfParams params;
  params.distance_step = 0.05f * diameter;
  params.max_bucket_entries = 50;
  PpfParams coarser = params;
  coarser.angle_bins = 12;
  coarser.alpha_bins = 24;
  // The part turned and moved, all its samples seen.
  Pose X_BO = Pose::Identity();
  X_BO.linear() = Eigen::AngleAxisd(0.7, Vec3::UnitZ()).toRotationMatrix();
  X_BO.translation() = Vec3(0.6, -0.05, 0.04);
  std::vector<Eigen::Vector3f> scene, scene_normals;
  for (size_t i = 0; i < m.size(); ++i) {
    scene.push_back((X_BO * m.points[i].cast<double>()).cast<float>());
    scene_normals.push_back((X_BO.linear() * m.normals[i].cast<double>()).cast<float>());
  }
  PpfMatchOptions options;
  options.reference_stride = 3;
  const auto poses = [&](const PpfModel& model) {
    std::vector<std::pair<int, Eigen::Matrix4d>> out;
    for (const CoarsePose& p : model.Match(scene, scene_normals, {}, options, Symmetry{})) {
      out.emplace_back(p.votes, p.X_BO.matrix());
    }
    return out;
  };
  PpfModel fresh, fresh_coarser;
  {
    MemoScope off(false);
    ASSERT_TRUE(fresh.Build(m.points, m.normals, params, diameter).ok());
    ASSERT_TRUE(fresh_coarser.Build(m.points, m.normals, coarser, diameter).ok());
  }
  MemoScope on(true);
  PpfModel first, copied, coarser_model;
  ASSERT_TRUE(first.Build(m.points, m.normals, params, diameter).ok());
  const size_t hits = ModelTableMemoHits();
  ASSERT_TRUE(copied.Build(m.points, m.normals, params, diameter).ok());
  EXPECT_EQ(ModelTableMemoHits(), hits + 1);
  ASSERT_TRUE(coarser_model.Build(m.points, m.normals, coarser, diameter).ok());
  EXPECT_EQ(ModelTableMemoHits(), hits + 1);

  ASSERT_GT(fresh.pair_count(), 0u);
  EXPECT_EQ(copied.pair_count(), fresh.pair_count());
  const auto expected = poses(fresh);
  ASSERT_FALSE(expected.empty());
  EXPECT_EQ(poses(first), expected);
  EXPECT_EQ(poses(copied), expected);
  EXPECT_EQ(coarser_model.pair_count(), fresh_coarser.pair_count());
  EXPECT_NE(coarser_model.pair_count(), fresh.pair_count());
  EXPECT_EQ(poses(coarser_model), poses(fresh_coarser));
}

// The samples, diameter, extreme points and edge planes of a part: bytes as
// compared by the memo's key (floats compared bit for bit).
struct Geometry {
  OrientedPoints samples;
  double diameter = 0.0;
  std::vector<Eigen::Vector3f> extreme;
  std::vector<EdgePlane> planes;
};
Geometry BuildGeometry(const TriangleMesh& mesh, double spacing, uint64_t seed) {
  Geometry g;
  g.samples = SampleSurface(mesh, spacing, seed);
  g.diameter = PointSetDiameter(g.samples.points);
  g.extreme = ExtremePoints(g.samples.points);
  g.planes = BuildEdgePlanes(g.samples, spacing);
  return g;
}
void ExpectSame(const Geometry& a, const Geometry& b) {
  EXPECT_EQ(a.samples.points, b.samples.points);
  EXPECT_EQ(a.samples.normals, b.samples.normals);
  EXPECT_EQ(a.diameter, b.diameter);
  EXPECT_EQ(a.extreme, b.extreme);
  ASSERT_EQ(a.planes.size(), b.planes.size());
  for (size_t i = 0; i < a.planes.size(); ++i) {
    EXPECT_EQ(a.planes[i].n, b.planes[i].n) << i;
    EXPECT_EQ(a.planes[i].c, b.planes[i].c) << i;
  }
}

TEST(ModelTableMemo, ModelGeometryCopiedFromTheMemoIsAFreshBuildAndOtherInputsBuildAgain) {
  const TriangleMesh bracket = MakeLBracket();
  TriangleMesh moved = bracket;
  moved.vertices[0] += Eigen::Vector3f(0.001f, 0.f, 0.f);
  Geometry fresh, fresh_moved, fresh_seed;
  {
    MemoScope off(false);
    fresh = BuildGeometry(bracket, 0.0029, 1);
    fresh_moved = BuildGeometry(moved, 0.0029, 1);
    fresh_seed = BuildGeometry(bracket, 0.0029, 2);
  }
  ASSERT_GT(fresh.samples.size(), 100u);
  ASSERT_FALSE(fresh.extreme.empty());
  ASSERT_TRUE(std::any_of(fresh.planes.begin(), fresh.planes.end(), [](const EdgePlane& p) { return p.valid(); }));
  MemoScope on(true);
  const Geometry first = BuildGeometry(bracket, 0.0029, 1);
  const size_t hits = ModelTableMemoHits();
  const Geometry copied = BuildGeometry(bracket, 0.0029, 1);
  EXPECT_EQ(ModelTableMemoHits(), hits + 4);  // samples, diameter, extreme points, edge planes
  ExpectSame(first, fresh);
  ExpectSame(copied, fresh);
  // One vertex moved, or another seed: samples built again, and from them
  // everything else (other samples, other keys).
  const Geometry other_mesh = BuildGeometry(moved, 0.0029, 1);
  const Geometry other_seed = BuildGeometry(bracket, 0.0029, 2);
  EXPECT_EQ(ModelTableMemoHits(), hits + 4);
  ExpectSame(other_mesh, fresh_moved);
  ExpectSame(other_seed, fresh_seed);
  EXPECT_NE(other_seed.samples.points, fresh.samples.points);
  EXPECT_NE(other_mesh.samples.points, fresh.samples.points);
}

}  // namespace
}  // namespace bp::internal
