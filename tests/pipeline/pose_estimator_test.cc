#include "pipeline/pose_estimator.h"
#include "pipeline/internal/pose_search.h"

#include <cmath>
#include <functional>
#include <future>
#include <limits>
#include <random>

#include <gtest/gtest.h>

#include "core/mesh_gen.h"
#include "tests/pipeline/pose_test_util.h"

namespace bp {
namespace {

using testing::DefaultCamera;
using testing::Render;
using testing::RenderedScene;
using testing::TestCamera;

constexpr double kDeg = M_PI / 180.0;

SceneView ViewOf(const std::vector<Eigen::Vector3f>& pts, const TestCamera& cam) {
  SceneView v;
  v.points_B = pts;
  v.X_BC = cam.X_BC;
  return v;
}

// The floor z = 0 as the support plane.
SceneView OnFloor(SceneView v) {
  v.support_plane_B = Eigen::Vector4d(0, 0, 1, 0);
  return v;
}

struct PartCase {
  const char* name;
  TriangleMesh mesh;
  Symmetry symmetry;
};

Symmetry BlockSymmetry() {
  Symmetry s;
  s.kind = Symmetry::Kind::kDiscrete;
  s.order = 2;
  s.extra.push_back(MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), Vec3::Zero()));
  return s;
}

std::vector<PartCase> TestParts() {
  return {{"l_bracket", testing::MakeTestLBracket(), Symmetry{}},
          {"flanged_cylinder", testing::MakeTestFlangedCylinder(), testing::RevoluteZ()},
          {"block", testing::MakeTestBlock(), BlockSymmetry()}};
}

// Built once: model tables take a few hundred ms per part.
const PoseEstimator& Estimator(int part) {
  static const std::vector<std::unique_ptr<PoseEstimator>> estimators = [] {
    std::vector<std::unique_ptr<PoseEstimator>> v;
    for (const PartCase& p : TestParts()) {
      auto e = PoseEstimator::Build(p.mesh, p.symmetry);
      EXPECT_TRUE(e.ok()) << e.status().ToString();
      v.push_back(std::move(e).value());
    }
    return v;
  }();
  return *estimators[part];
}

// A floor slab under z = 0 (top face at z = 0).
TriangleMesh Floor() { return testing::MakeBox({-0.3f, -0.3f, -0.02f}, {0.3f, 0.3f, 0.f}); }

// Lowest z of the mesh at pose X.
double MinZ(const TriangleMesh& mesh, const Pose& X) {
  double z = std::numeric_limits<double>::infinity();
  for (const auto& v : mesh.vertices) z = std::min(z, (X * v.cast<double>()).z());
  return z;
}

// Pose with the given rotation, resting on the floor at (x, y).
Pose Resting(const TriangleMesh& mesh, const Mat3& R, double x, double y) {
  Pose X = MakePose(R, Vec3(x, y, 0));
  X.translation().z() -= MinZ(mesh, X);
  return X;
}

TEST(PoseEstimator, FindsSinglePartAtKnownPoseWithinHalfMillimetreAndHalfDegree) {
  const TestCamera cam = DefaultCamera();
  std::mt19937_64 rng{42};
  const std::vector<PartCase> parts = TestParts();
  for (size_t k = 0; k < parts.size(); ++k) {
    const PartCase& part = parts[k];
    for (int trial = 0; trial < 4; ++trial) {
      const Pose X_BO = MakePose(testing::RandomRotation(rng, 60 * kDeg), Vec3(0.01 * trial, -0.02, 0.03));
      const RenderedScene scene = Render({{&part.mesh, X_BO}}, cam, 0.0002, 7 + trial);
      ASSERT_GT(scene.points_B.size(), 300u);
      auto r = Estimator(k).Estimate(ViewOf(scene.points_B, cam));
      ASSERT_TRUE(r.ok()) << r.status().ToString();
      ASSERT_FALSE(r->hypotheses.empty()) << part.name << " trial " << trial << ": " << r->no_result_reason;
      const PoseHypothesis& h = r->hypotheses.front();
      EXPECT_LT(SymmetricTranslationError(h.X_BO, X_BO, part.symmetry), 0.0005) << part.name << " trial " << trial;
      EXPECT_LT(SymmetricRotationError(h.X_BO, X_BO, part.symmetry), 0.5 * kDeg) << part.name << " trial " << trial;
      EXPECT_GT(h.score, 0.8) << part.name;
      EXPECT_GT(h.supporting_indices.size(), scene.points_B.size() * 9 / 10) << part.name;
      EXPECT_TRUE(h.X_BO.matrix().allFinite());
    }
  }
}

TEST(PoseEstimator, FindsTheShippedPartsAtKnownPoses) {
  const TestCamera cam = DefaultCamera();
  Symmetry tee;
  tee.kind = Symmetry::Kind::kDiscrete;
  tee.order = 2;
  const std::vector<PartCase> parts = {{"flanged_bushing", MakeFlangedBushing(), testing::RevoluteZ()},
                                       {"l_bracket", MakeLBracket(), Symmetry{}},
                                       {"pipe_tee", MakePipeTee(), tee}};
  const TriangleMesh floor = Floor();
  std::mt19937_64 rng{99};
  for (const PartCase& part : parts) {
    auto est = PoseEstimator::Build(part.mesh, part.symmetry);
    ASSERT_TRUE(est.ok()) << est.status().ToString();
    for (int trial = 0; trial < 2; ++trial) {
      const Pose X_BO = Resting(part.mesh, testing::RandomRotation(rng, 70 * kDeg), 0.01 * trial, -0.01);
      const RenderedScene scene = Render({{&part.mesh, X_BO}, {&floor, Pose::Identity()}}, cam, 0.0003, 31 + trial);
      const std::vector<Eigen::Vector3f> segment = testing::PointsWithLabels(scene, {1});
      SceneView view = OnFloor(ViewOf(segment, cam));
      view.depth = &scene.depth;
      view.intrinsics = cam.K;
      auto r = (*est)->Estimate(view);
      ASSERT_TRUE(r.ok());
      ASSERT_FALSE(r->hypotheses.empty()) << part.name << " trial " << trial << ": " << r->no_result_reason;
      const PoseHypothesis& h = r->hypotheses.front();
      EXPECT_LT(SymmetricTranslationError(h.X_BO, X_BO, part.symmetry), 0.0005) << part.name << " trial " << trial;
      EXPECT_LT(SymmetricRotationError(h.X_BO, X_BO, part.symmetry), 0.5 * kDeg) << part.name << " trial " << trial;
    }
  }
}

// A wider search of the same view (as the perception's second look) does
// not refine again the coarse poses an earlier estimate refined
// (internal::SearchReuse::skip_coarse).
TEST(PoseEstimator, SkipsTheCoarsePosesAnEarlierEstimateRefined) {
  const TestCamera cam = DefaultCamera();
  const PartCase part = TestParts()[0];
  std::mt19937_64 rng{5};
  const Pose X_BO = MakePose(testing::RandomRotation(rng, 60 * kDeg), Vec3(0.0, 0.01, 0.03));
  const RenderedScene scene = Render({{&part.mesh, X_BO}}, cam, 0.0003, 3);
  const SceneView view = ViewOf(scene.points_B, cam);
  const PoseEstimator& est = Estimator(0);
  const internal::PoseModel& model = internal::PoseEstimatorAccess::Model(est);
  internal::SearchTrace first;
  ASSERT_TRUE(internal::EstimatePose(model, view, est.default_search(), {}, &first).ok());
  ASSERT_FALSE(first.coarse_poses.empty());
  EXPECT_EQ(first.coarse_skipped, 0);

  const PoseSearch wide{.max_reference_points = 20, .max_coarse_poses = 12, .peaks_per_reference = 2,
                        .peaks_examined = 16};
  internal::SearchTrace all, rest;
  ASSERT_TRUE(internal::EstimatePose(model, view, wide, {}, &all).ok());
  auto rest_estimate = internal::EstimatePose(model, view, wide, {.skip_coarse = first.coarse_poses}, &rest);
  ASSERT_TRUE(rest_estimate.ok());
  EXPECT_GT(rest.coarse_skipped, 0);
  EXPECT_EQ(rest.coarse_poses.size() + static_cast<size_t>(rest.coarse_skipped), all.coarse_poses.size());
  EXPECT_EQ(rest_estimate->coarse_refined, static_cast<int>(rest.coarse_poses.size()));
  const double near_t = PoseEstimatorOptions{}.cluster_relative_translation * est.diameter();
  const double near_r = PoseEstimatorOptions{}.cluster_rotation_deg * kDeg;
  for (const Pose& X : rest.coarse_poses) {
    for (const Pose& Y : first.coarse_poses) {
      EXPECT_FALSE((X.translation() - Y.translation()).norm() < near_t &&
                   SymmetricRotationError(X, Y, part.symmetry) < near_r);
    }
  }

  // Everything skipped: no hypothesis, and the reason says why.
  internal::SearchTrace none_trace;
  auto none = internal::EstimatePose(model, view, wide, {.skip_coarse = all.coarse_poses}, &none_trace);
  ASSERT_TRUE(none.ok());
  EXPECT_TRUE(none->hypotheses.empty());
  EXPECT_EQ(none_trace.coarse_skipped, static_cast<int>(all.coarse_poses.size()));
  EXPECT_NE(none->no_result_reason.find("refined by an earlier estimate"), std::string::npos)
      << none->no_result_reason;
}

// PoseSearch::stop_score: the first ICP pass ends at the first coarse pose
// that passes with at least that score and explains the view; the same
// part comes out, from fewer refined poses.
TEST(PoseEstimator, StopsTheFirstPassAtAPoseThatExplainsTheView) {
  const TestCamera cam = DefaultCamera();
  const std::vector<PartCase> parts = TestParts();
  std::mt19937_64 rng{21};
  size_t refined_all = 0, refined_stop = 0;
  for (size_t k = 0; k < parts.size(); ++k) {
    for (int trial = 0; trial < 2; ++trial) {
      const Pose X_BO = MakePose(testing::RandomRotation(rng, 60 * kDeg), Vec3(0.01 * trial, 0.0, 0.03));
      const RenderedScene scene = Render({{&parts[k].mesh, X_BO}}, cam, 0.0002, 50 + trial);
      const SceneView view = ViewOf(scene.points_B, cam);
      PoseSearch search{.max_reference_points = 20, .max_coarse_poses = 4};
      auto all = Estimator(k).Estimate(view, search);
      search.stop_score = 0.9;
      auto stop = Estimator(k).Estimate(view, search);
      ASSERT_TRUE(all.ok() && stop.ok());
      ASSERT_FALSE(all->hypotheses.empty() || stop->hypotheses.empty()) << parts[k].name << " trial " << trial;
      EXPECT_LE(stop->coarse_refined, all->coarse_refined);
      refined_all += static_cast<size_t>(all->coarse_refined);
      refined_stop += static_cast<size_t>(stop->coarse_refined);
      const Pose& X = stop->hypotheses.front().X_BO;
      EXPECT_LT(SymmetricTranslationError(X, X_BO, parts[k].symmetry), 0.0005) << parts[k].name << " trial " << trial;
      EXPECT_LT(SymmetricRotationError(X, X_BO, parts[k].symmetry), 0.5 * kDeg) << parts[k].name << " trial " << trial;
    }
  }
  EXPECT_LT(refined_stop, refined_all);
  // Out of [0, 1]: InvalidArgument.
  const RenderedScene scene = Render({{&parts[0].mesh, Pose::Identity()}}, cam, 0.0002, 50);
  for (const double bad : {-0.1, 1.5, std::nan("")}) {
    PoseSearch search;
    search.stop_score = bad;
    EXPECT_EQ(Estimator(0).Estimate(ViewOf(scene.points_B, cam), search).status().code(),
              Status::Code::kInvalidArgument)
        << bad;
  }
}

// internal::SearchReuse::keep_prepared / prepared: a second, wider estimate
// of the same view (the perception's second look) reuses what the first
// derived from it, PPF peaks included, and finds what it would have found
// deriving it again. The prepared view names its estimator and its points:
// another estimator's, or one of other points, is refused.
TEST(PoseEstimator, ReusesWhatAnEarlierEstimateDerivedFromTheView) {
  const TestCamera cam = DefaultCamera();
  const PartCase part = TestParts()[0];
  const TriangleMesh floor = Floor();
  const Pose X_BO = Resting(part.mesh, Mat3(Eigen::AngleAxisd(0.4, Vec3::UnitZ())), 0.01, 0.0);
  const RenderedScene scene = Render({{&part.mesh, X_BO}, {&floor, Pose::Identity()}}, cam, 0.0003, 4);
  const std::vector<Eigen::Vector3f> segment = testing::PointsWithLabels(scene, {1});
  // As the pipeline calls it, with the floor: several PPF peaks per reference point.
  SceneView view = OnFloor(ViewOf(segment, cam));
  view.depth = &scene.depth;
  view.intrinsics = cam.K;
  const PoseEstimator& est = Estimator(0);
  const internal::PoseModel& model = internal::PoseEstimatorAccess::Model(est);
  internal::SearchTrace plain;
  ASSERT_TRUE(internal::EstimatePose(model, view, est.default_search(), {}, &plain).ok());
  EXPECT_EQ(plain.prepared, nullptr);
  internal::SearchTrace kept;
  ASSERT_TRUE(internal::EstimatePose(model, view, est.default_search(), {.keep_prepared = true}, &kept).ok());
  ASSERT_NE(kept.prepared, nullptr);

  const PoseSearch wide{.max_reference_points = 20, .max_coarse_poses = 12, .peaks_per_reference = 2,
                        .peaks_examined = 16};
  internal::SearchTrace fresh_trace, reused_trace;
  auto fresh = internal::EstimatePose(model, view, wide, {}, &fresh_trace);
  const internal::SearchReuse reuse{.prepared = kept.prepared};
  auto reused = internal::EstimatePose(model, view, wide, reuse, &reused_trace);
  ASSERT_TRUE(fresh.ok() && reused.ok());
  EXPECT_EQ(reused->timings.prepare_ms, 0.0);
  EXPECT_EQ(reused->sampled_points, fresh->sampled_points);
  EXPECT_EQ(reused_trace.coarse_poses.size(), fresh_trace.coarse_poses.size());
  for (size_t i = 0; i < std::min(reused_trace.coarse_poses.size(), fresh_trace.coarse_poses.size()); ++i) {
    EXPECT_TRUE(reused_trace.coarse_poses[i].isApprox(fresh_trace.coarse_poses[i], 1e-12)) << i;
  }
  ASSERT_EQ(reused->hypotheses.size(), fresh->hypotheses.size());
  ASSERT_FALSE(fresh->hypotheses.empty());
  for (size_t i = 0; i < fresh->hypotheses.size(); ++i) {
    EXPECT_TRUE(reused->hypotheses[i].X_BO.isApprox(fresh->hypotheses[i].X_BO, 1e-12));
    EXPECT_EQ(reused->hypotheses[i].score, fresh->hypotheses[i].score);
    EXPECT_EQ(reused->hypotheses[i].supporting_indices, fresh->hypotheses[i].supporting_indices);
  }
  // Another estimator's (also one built later from the same mesh, wherever
  // it is allocated), fewer points, or as many points moved: InvalidArgument.
  const internal::PoseModel& other = internal::PoseEstimatorAccess::Model(Estimator(1));
  EXPECT_EQ(internal::EstimatePose(other, view, wide, reuse).status().code(), Status::Code::kInvalidArgument);
  for (int i = 0; i < 3; ++i) {
    auto rebuilt = PoseEstimator::Build(part.mesh, part.symmetry);
    ASSERT_TRUE(rebuilt.ok());
    EXPECT_EQ(internal::EstimatePose(internal::PoseEstimatorAccess::Model(**rebuilt), view, wide, reuse)
                  .status()
                  .code(),
              Status::Code::kInvalidArgument);
  }
  const std::vector<Eigen::Vector3f> half(segment.begin(), segment.begin() + segment.size() / 2);
  EXPECT_EQ(internal::EstimatePose(model, OnFloor(ViewOf(half, cam)), wide, reuse).status().code(),
            Status::Code::kInvalidArgument);
  std::vector<Eigen::Vector3f> moved = segment;
  for (Eigen::Vector3f& p : moved) p.x() += 0.001f;
  EXPECT_EQ(internal::EstimatePose(model, OnFloor(ViewOf(moved, cam)), wide, reuse).status().code(),
            Status::Code::kInvalidArgument);
}

// internal::SearchReuse::base: what preparing a view derives whatever the
// estimator (its finite points, their spread, the support structure), made
// once and shared by every estimator's estimate of the view, also one of
// the same points with other normals (the perception's residual views
// matched again with the estimator's own normals). Each finds exactly what
// it finds deriving it alone. A base of another view is refused.
TEST(PoseEstimator, SharesAViewsBaseBetweenItsEstimates) {
  const TestCamera cam = DefaultCamera();
  const std::vector<PartCase> parts = TestParts();
  const TriangleMesh floor = Floor();
  const Pose X_BO = Resting(parts[0].mesh, Mat3(Eigen::AngleAxisd(0.4, Vec3::UnitZ())), 0.01, 0.0);
  const RenderedScene scene = Render({{&parts[0].mesh, X_BO}, {&floor, Pose::Identity()}}, cam, 0.0003, 4);
  std::vector<Eigen::Vector3f> segment = testing::PointsWithLabels(scene, {1});
  // Non-finite points are left out of the base as of a derived view.
  segment.insert(segment.begin() + static_cast<std::ptrdiff_t>(segment.size() / 2),
                 Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN()));
  SceneView view = OnFloor(ViewOf(segment, cam));
  view.depth = &scene.depth;
  view.intrinsics = cam.K;
  // The same points with normals (the estimator then averages them instead
  // of estimating its own): another view of the same base.
  std::vector<Eigen::Vector3f> normals(segment.size(), Eigen::Vector3f::UnitZ());
  SceneView with_normals = view;
  with_normals.normals_B = normals;

  const auto base = std::make_shared<const internal::ViewBase>(view);
  EXPECT_EQ(base->view_points(), segment.size());
  EXPECT_EQ(base->pts().size(), segment.size() - 1);
  int found = 0;
  for (const SceneView* v : {&view, &with_normals}) {
    for (size_t k = 0; k < parts.size(); ++k) {
      const internal::PoseModel& model = internal::PoseEstimatorAccess::Model(Estimator(static_cast<int>(k)));
      const PoseSearch search = Estimator(static_cast<int>(k)).default_search();
      auto alone = internal::EstimatePose(model, *v, search);
      auto shared = internal::EstimatePose(model, *v, search, {.base = base});
      ASSERT_TRUE(alone.ok() && shared.ok()) << parts[k].name;
      EXPECT_EQ(shared->scene_points, alone->scene_points) << parts[k].name;
      EXPECT_EQ(shared->sampled_points, alone->sampled_points) << parts[k].name;
      EXPECT_EQ(shared->coarse_refined, alone->coarse_refined) << parts[k].name;
      EXPECT_EQ(shared->no_result_reason, alone->no_result_reason) << parts[k].name;
      ASSERT_EQ(shared->hypotheses.size(), alone->hypotheses.size()) << parts[k].name;
      for (size_t i = 0; i < alone->hypotheses.size(); ++i) {
        const PoseHypothesis& a = alone->hypotheses[i];
        const PoseHypothesis& b = shared->hypotheses[i];
        EXPECT_EQ(b.X_BO.matrix(), a.X_BO.matrix()) << parts[k].name << " " << i;
        EXPECT_EQ(b.score, a.score) << parts[k].name << " " << i;
        EXPECT_EQ(b.supporting_indices, a.supporting_indices) << parts[k].name << " " << i;
        EXPECT_EQ(b.alternatives.size(), a.alternatives.size()) << parts[k].name << " " << i;
      }
      found += alone->hypotheses.empty() ? 0 : 1;
    }
  }
  EXPECT_GE(found, 2);  // the bracket at least, with either normals
  // The support structure: built once, for one cell.
  const float cell = 2.f * static_cast<float>(PoseEstimatorOptions{}.support_distance);
  const internal::SceneSupport* support = base->Support(cell, view);
  ASSERT_NE(support, nullptr);
  EXPECT_EQ(base->Support(cell, view), support);
  EXPECT_EQ(base->Support(2.f * cell, view), nullptr);
  // Another view's base: InvalidArgument.
  const std::vector<Eigen::Vector3f> half(segment.begin(), segment.begin() + static_cast<std::ptrdiff_t>(segment.size() / 2));
  const internal::PoseModel& model = internal::PoseEstimatorAccess::Model(Estimator(0));
  EXPECT_EQ(internal::EstimatePose(model, OnFloor(ViewOf(half, cam)), Estimator(0).default_search(), {.base = base})
                .status()
                .code(),
            Status::Code::kInvalidArgument);
}

TEST(PoseEstimator, FindsPartLyingFlatSeenHeadOn) {
  // The stable resting poses: plane faces seen head-on leave the in-plane
  // position to the silhouette only.
  const TestCamera cam = DefaultCamera();
  const std::vector<PartCase> parts = TestParts();
  const TriangleMesh floor = Floor();
  for (size_t k = 0; k < parts.size(); ++k) {
    const Pose X_BO = Resting(parts[k].mesh, Mat3(Eigen::AngleAxisd(0.3, Vec3::UnitZ())), 0.02, 0.01);
    const RenderedScene scene = Render({{&parts[k].mesh, X_BO}, {&floor, Pose::Identity()}}, cam, 0.0002, 3);
    const std::vector<Eigen::Vector3f> segment = testing::PointsWithLabels(scene, {1});
    auto r = Estimator(k).Estimate(ViewOf(segment, cam));
    ASSERT_TRUE(r.ok());
    ASSERT_FALSE(r->hypotheses.empty()) << parts[k].name << ": " << r->no_result_reason;
    EXPECT_LT(SymmetricTranslationError(r->hypotheses[0].X_BO, X_BO, parts[k].symmetry), 0.0005) << parts[k].name;
    EXPECT_LT(SymmetricRotationError(r->hypotheses[0].X_BO, X_BO, parts[k].symmetry), 0.5 * kDeg) << parts[k].name;
  }
}

TEST(PoseEstimator, FindsPartWithHalfItsSurfaceHiddenByAnOccluder) {
  const TestCamera cam = DefaultCamera();
  const PartCase part = TestParts()[0];
  const Pose X_BO = MakePose(Mat3(Eigen::AngleAxisd(0.5, Vec3(1, 1, 0).normalized())), Vec3(0.0, 0.0, 0.03));
  const Eigen::Vector3d centre = X_BO * Vec3(0.045, 0, 0.02);
  // A plate above the part hiding everything with y < centre.y (the end of
  // the bracket whose cap faces away from the camera: hiding the other end
  // would leave a pure extrusion, whose position along y nothing observes).
  const TriangleMesh plate = testing::MakeBox({-0.2f, -0.2f, 0.15f}, {0.2f, static_cast<float>(centre.y()), 0.16f});
  const RenderedScene alone = Render({{&part.mesh, X_BO}}, cam, 0.0002, 5);
  const RenderedScene scene = Render({{&part.mesh, X_BO}, {&plate, Pose::Identity()}}, cam, 0.0002, 5);
  const std::vector<Eigen::Vector3f> segment = testing::PointsWithLabels(scene, {1});
  const double visible = static_cast<double>(segment.size()) / alone.points_B.size();
  ASSERT_GT(visible, 0.35);
  ASSERT_LT(visible, 0.65);
  for (const bool with_depth : {false, true}) {
    SceneView view = ViewOf(segment, cam);
    if (with_depth) {
      view.depth = &scene.depth;
      view.intrinsics = cam.K;
    }
    auto r = Estimator(0).Estimate(view);
    ASSERT_TRUE(r.ok());
    ASSERT_FALSE(r->hypotheses.empty()) << r->no_result_reason;
    const PoseHypothesis& h = r->hypotheses[0];
    EXPECT_LT(SymmetricTranslationError(h.X_BO, X_BO, part.symmetry), 0.001);
    EXPECT_LT(SymmetricRotationError(h.X_BO, X_BO, part.symmetry), 1.0 * kDeg);
    if (with_depth) {
      // The occluded half is no evidence against the part.
      EXPECT_GT(h.occluded_points, h.visible_points / 4);
      EXPECT_GT(h.score, 0.8);
    }
  }
}

TEST(PoseEstimator, FindsPartInSegmentWithFloorAndClutter) {
  const TestCamera cam = DefaultCamera();
  const std::vector<PartCase> parts = TestParts();
  const TriangleMesh floor = Floor();
  const TriangleMesh clutter = testing::MakeBox({0.f, 0.f, 0.f}, {0.03f, 0.02f, 0.015f});
  std::mt19937_64 rng{7};
  for (size_t k = 0; k < parts.size(); ++k) {
    const Pose X_BO = Resting(parts[k].mesh, testing::RandomRotation(rng, 40 * kDeg), 0.0, 0.0);
    const Pose X_BK = MakePose(Mat3(Eigen::AngleAxisd(0.4, Vec3::UnitZ())), Vec3(0.035, 0.035, 0.0));
    const RenderedScene scene =
        Render({{&parts[k].mesh, X_BO}, {&floor, Pose::Identity()}, {&clutter, X_BK}}, cam, 0.0002, 11);
    // An under-segmented blob: everything within 7 cm of the part, floor included.
    std::vector<Eigen::Vector3f> segment;
    int part_points = 0;
    for (size_t i = 0; i < scene.points_B.size(); ++i) {
      if ((scene.points_B[i].cast<double>() - X_BO.translation()).head<2>().norm() < 0.07) {
        segment.push_back(scene.points_B[i]);
        part_points += scene.point_label[i] == 1;
      }
    }
    ASSERT_LT(part_points, static_cast<int>(segment.size()) / 2) << "most of the segment is not the part";
    auto r = Estimator(k).Estimate(OnFloor(ViewOf(segment, cam)));
    ASSERT_TRUE(r.ok());
    ASSERT_FALSE(r->hypotheses.empty()) << parts[k].name << ": " << r->no_result_reason;
    const PoseHypothesis& h = r->hypotheses[0];
    EXPECT_LT(SymmetricTranslationError(h.X_BO, X_BO, parts[k].symmetry), 0.001) << parts[k].name;
    EXPECT_LT(SymmetricRotationError(h.X_BO, X_BO, parts[k].symmetry), 1.0 * kDeg) << parts[k].name;
  }
}

// PoseEstimatorOptions::quick_screen_*: in the first pass, a refined coarse
// pose is verified on every 12th model sample first and rejected below 0.3;
// the hypotheses are those of the pass without the screen.
TEST(PoseEstimator, ScreensRefinedCoarsePosesOnFewerSamplesFirst) {
  const TestCamera cam = DefaultCamera();
  const std::vector<PartCase> parts = TestParts();
  const TriangleMesh floor = Floor();
  const TriangleMesh clutter = testing::MakeBox({0.f, 0.f, 0.f}, {0.03f, 0.02f, 0.015f});
  std::mt19937_64 rng{17};
  int screened = 0;
  for (size_t k = 0; k < parts.size(); ++k) {
    PoseEstimatorOptions no_screen;
    no_screen.quick_screen_min_score = 0.0;
    auto unscreened = PoseEstimator::Build(parts[k].mesh, parts[k].symmetry, no_screen);
    ASSERT_TRUE(unscreened.ok()) << unscreened.status().ToString();
    for (int trial = 0; trial < 2; ++trial) {
      const Pose X_BO = Resting(parts[k].mesh, testing::RandomRotation(rng, 40 * kDeg), 0.0, 0.0);
      const Pose X_BK = MakePose(Mat3(Eigen::AngleAxisd(0.4, Vec3::UnitZ())), Vec3(0.06, 0.06, 0.0));
      const RenderedScene scene =
          Render({{&parts[k].mesh, X_BO}, {&floor, Pose::Identity()}, {&clutter, X_BK}}, cam, 0.0002, 30 + trial);
      // The part and a box beside it (labels 1 and 3): wrong coarse poses.
      const std::vector<Eigen::Vector3f> points = testing::PointsWithLabels(scene, {1, 3});
      SceneView view = OnFloor(ViewOf(points, cam));
      view.depth = &scene.depth;
      view.intrinsics = cam.K;
      auto with = Estimator(k).Estimate(view);
      auto without = (*unscreened)->Estimate(view);
      ASSERT_TRUE(with.ok() && without.ok());
      EXPECT_EQ(without->screened_out, 0);
      screened += with->screened_out;
      ASSERT_FALSE(with->hypotheses.empty()) << parts[k].name << ": " << with->no_result_reason;
      ASSERT_EQ(with->hypotheses.size(), without->hypotheses.size()) << parts[k].name << " trial " << trial;
      for (size_t i = 0; i < with->hypotheses.size(); ++i) {
        EXPECT_TRUE(with->hypotheses[i].X_BO.isApprox(without->hypotheses[i].X_BO, 1e-12));
        EXPECT_EQ(with->hypotheses[i].score, without->hypotheses[i].score);
      }
      EXPECT_LT(SymmetricTranslationError(with->hypotheses[0].X_BO, X_BO, parts[k].symmetry), 0.001)
          << parts[k].name << " trial " << trial;
    }
  }
  EXPECT_GT(screened, 0);
}

TEST(PoseEstimator, GivesOneHypothesisPerPartForTwoTouchingParts) {
  const TestCamera cam = DefaultCamera();
  const PartCase part = TestParts()[0];
  const TriangleMesh floor = Floor();
  const Pose X_B1 = Resting(part.mesh, Mat3(Eigen::AngleAxisd(0.2, Vec3::UnitZ())), -0.03, -0.025);
  const Pose X_B2 = Resting(part.mesh, Mat3(Eigen::AngleAxisd(M_PI + 0.1, Vec3::UnitZ())), 0.06, 0.02);
  const RenderedScene scene =
      Render({{&part.mesh, X_B1}, {&part.mesh, X_B2}, {&floor, Pose::Identity()}}, cam, 0.0002, 13);
  const std::vector<Eigen::Vector3f> segment = testing::PointsWithLabels(scene, {1, 2});
  // As the pipeline calls it: with the depth image and the floor.
  SceneView view = OnFloor(ViewOf(segment, cam));
  view.depth = &scene.depth;
  view.intrinsics = cam.K;
  // With the default coarse_stop_score: the first good pose explains only
  // about half the view, so the first pass goes on to the other part.
  auto r = Estimator(0).Estimate(view);
  ASSERT_TRUE(r.ok());
  ASSERT_EQ(r->hypotheses.size(), 2u) << r->no_result_reason;
  for (const Pose& truth : {X_B1, X_B2}) {
    double best_t = 1e9, best_r = 1e9;
    for (const PoseHypothesis& h : r->hypotheses) {
      if (SymmetricTranslationError(h.X_BO, truth, part.symmetry) < best_t) {
        best_t = SymmetricTranslationError(h.X_BO, truth, part.symmetry);
        best_r = SymmetricRotationError(h.X_BO, truth, part.symmetry);
      }
    }
    EXPECT_LT(best_t, 0.001);
    EXPECT_LT(best_r, 1.0 * kDeg);
  }
}

TEST(PoseEstimator, FloorOnlySegmentGivesNoHypothesis) {
  const TestCamera cam = DefaultCamera();
  const TriangleMesh floor = Floor();
  const RenderedScene scene = Render({{&floor, Pose::Identity()}}, cam, 0.0002, 17);
  std::vector<Eigen::Vector3f> segment;
  for (const auto& p : scene.points_B) {
    if (p.head<2>().norm() < 0.05f) segment.push_back(p);
  }
  // Without the plane, a part face flush with the floor would explain the
  // patch perfectly (see SceneView::support_plane_B).
  for (int k = 0; k < 3; ++k) {
    auto r = Estimator(k).Estimate(OnFloor(ViewOf(segment, cam)));
    ASSERT_TRUE(r.ok());
    EXPECT_TRUE(r->hypotheses.empty()) << "part " << k << " score " << r->hypotheses[0].score;
    EXPECT_FALSE(r->no_result_reason.empty());
  }
}

TEST(PoseEstimator, DegenerateSegmentsGiveNoHypothesisAndAReason) {
  const TestCamera cam = DefaultCamera();
  const float nan = std::numeric_limits<float>::quiet_NaN();
  std::vector<std::vector<Eigen::Vector3f>> cases;
  cases.push_back({});                                                     // empty
  cases.push_back({{0, 0, 0}, {0.01f, 0, 0}, {0, 0.01f, 0}});              // 3 points
  cases.push_back(std::vector<Eigen::Vector3f>(500, Eigen::Vector3f(nan, nan, nan)));  // all NaN
  std::vector<Eigen::Vector3f> line;
  for (int i = 0; i < 500; ++i) line.emplace_back(0.0002f * i, 0.0001f * i, 0.01f);
  cases.push_back(line);  // collinear
  cases.push_back(std::vector<Eigen::Vector3f>(500, Eigen::Vector3f(0.1f, 0.2f, 0.03f)));  // one point repeated
  for (size_t c = 0; c < cases.size(); ++c) {
    for (int k = 0; k < 3; ++k) {
      auto r = Estimator(k).Estimate(ViewOf(cases[c], cam));
      ASSERT_TRUE(r.ok()) << "case " << c;
      EXPECT_TRUE(r->hypotheses.empty()) << "case " << c;
      EXPECT_FALSE(r->no_result_reason.empty()) << "case " << c;
    }
  }
  // Mismatched normals are a caller's error, reported, not a crash.
  std::vector<Eigen::Vector3f> normals(2, Eigen::Vector3f::UnitZ());
  SceneView v = ViewOf(line, cam);
  v.normals_B = normals;
  EXPECT_FALSE(Estimator(0).Estimate(v).ok());
}

TEST(PoseEstimator, IgnoresNaNPointsMixedIntoAValidSegment) {
  const TestCamera cam = DefaultCamera();
  const PartCase part = TestParts()[0];
  const Pose X_BO = MakePose(Mat3(Eigen::AngleAxisd(0.4, Vec3(1, 0, 1).normalized())), Vec3(0, 0, 0.03));
  const RenderedScene scene = Render({{&part.mesh, X_BO}}, cam, 0.0002, 19);
  std::vector<Eigen::Vector3f> segment;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  for (size_t i = 0; i < scene.points_B.size(); ++i) {
    segment.push_back(scene.points_B[i]);
    if (i % 3 == 0) segment.emplace_back(nan, 0.f, nan);
  }
  auto r = Estimator(0).Estimate(ViewOf(segment, cam));
  ASSERT_TRUE(r.ok());
  ASSERT_FALSE(r->hypotheses.empty()) << r->no_result_reason;
  EXPECT_LT(SymmetricTranslationError(r->hypotheses[0].X_BO, X_BO, part.symmetry), 0.0005);
  for (int i : r->hypotheses[0].supporting_indices) EXPECT_TRUE(segment[i].allFinite());
}

TEST(PoseEstimator, ConcurrentEstimatesMatchSequentialOnes) {
  const TestCamera cam = DefaultCamera();
  const PartCase part = TestParts()[1];
  std::vector<RenderedScene> scenes;
  std::mt19937_64 rng{23};
  for (int i = 0; i < 4; ++i) {
    scenes.push_back(Render({{&part.mesh, MakePose(testing::RandomRotation(rng, 1.0), Vec3(0, 0, 0.03))}}, cam,
                            0.0002, 29 + i));
  }
  std::vector<Pose> sequential;
  for (const auto& s : scenes) sequential.push_back(Estimator(1).Estimate(ViewOf(s.points_B, cam))->hypotheses.at(0).X_BO);
  std::vector<std::future<Pose>> futures;
  for (const auto& s : scenes) {
    futures.push_back(std::async(std::launch::async, [&s, &cam] {
      return Estimator(1).Estimate(ViewOf(s.points_B, cam))->hypotheses.at(0).X_BO;
    }));
  }
  for (size_t i = 0; i < futures.size(); ++i) EXPECT_TRUE(futures[i].get().isApprox(sequential[i], 0.0));
}

TEST(PoseEstimator, BuildRejectsEmptyMeshAndBadOptions) {
  EXPECT_FALSE(PoseEstimator::Build(TriangleMesh{}, Symmetry{}).ok());
  PoseEstimatorOptions o;
  o.ppf_relative_sampling = 0;
  EXPECT_FALSE(PoseEstimator::Build(testing::MakeTestBlock(), Symmetry{}, o).ok());
  // Build with one option set to a bad value: InvalidArgument.
  const auto rejects = [](auto PoseEstimatorOptions::*field, auto bad) {
    PoseEstimatorOptions options;
    options.*field = bad;
    return PoseEstimator::Build(testing::MakeTestBlock(), Symmetry{}, options).status().code() ==
           Status::Code::kInvalidArgument;
  };
  for (const double bad : {0.0, -1e-5, std::nan("")}) {
    EXPECT_TRUE(rejects(&PoseEstimatorOptions::icp_convergence, bad)) << bad;
    EXPECT_TRUE(rejects(&PoseEstimatorOptions::icp_coarse_convergence, bad)) << bad;
  }
  for (const double bad : {-0.1, 1.5, std::nan("")}) EXPECT_TRUE(rejects(&PoseEstimatorOptions::coarse_stop_score, bad)) << bad;
  for (const double bad : {-0.1, 1.5, std::nan("")}) EXPECT_TRUE(rejects(&PoseEstimatorOptions::quick_screen_min_score, bad)) << bad;
  for (const int bad : {0, -3}) {
    EXPECT_TRUE(rejects(&PoseEstimatorOptions::quick_screen_stride, bad)) << bad;
    EXPECT_TRUE(rejects(&PoseEstimatorOptions::icp_shrink_iterations, bad)) << bad;
    EXPECT_TRUE(rejects(&PoseEstimatorOptions::icp_coarse_iterations, bad)) << bad;
  }
  TriangleMesh flat;  // zero area
  flat.vertices = {{0, 0, 0}, {1, 0, 0}, {2, 0, 0}};
  flat.triangles = {{0, 1, 2}};
  EXPECT_FALSE(PoseEstimator::Build(flat, Symmetry{}).ok());
}

TEST(PoseEstimator, CountInsideCountsPointsInTheMaterialOnly) {
  // The test block spans x in [-30, 30], y in [-20, 20], z in [-10, 10] mm in O.
  const PoseEstimator& block = Estimator(2);
  const Pose X_BO = MakePose(Mat3(Eigen::AngleAxisd(0.4, Vec3(1, 2, 3).normalized())), Vec3(0.1, -0.05, 0.2));
  const auto in_B = [&](std::vector<Eigen::Vector3f> pts_O) {
    for (auto& p : pts_O) p = (X_BO * p.cast<double>()).cast<float>();
    return pts_O;
  };
  // 2 mm under each face, and the same points 2 mm outside.
  const std::vector<Eigen::Vector3f> inside = in_B({{0.028f, 0.f, 0.f},
                                                    {0.f, -0.018f, 0.003f},
                                                    {0.01f, 0.01f, 0.008f},
                                                    {-0.02f, 0.f, -0.008f}});
  const std::vector<Eigen::Vector3f> outside = in_B({{0.032f, 0.f, 0.f},
                                                     {0.f, -0.022f, 0.003f},
                                                     {0.01f, 0.01f, 0.012f},
                                                     {-0.02f, 0.f, -0.012f},
                                                     {0.f, 0.f, 0.f}});  // the centre: deeper than the band
  EXPECT_EQ(block.CountInside(X_BO, inside, 0.001f), 4u);
  EXPECT_EQ(block.CountInside(X_BO, inside, 0.003f), 0u);  // not 3 mm deep
  EXPECT_EQ(block.CountInside(X_BO, outside, 0.001f), 0u);
  // A copy of the block moved 4 mm along x overlaps it; one moved 61 mm does not.
  std::vector<Eigen::Vector3f> surface_B;
  for (const Eigen::Vector3f& p : block.surface_points_O()) surface_B.push_back((X_BO * p.cast<double>()).cast<float>());
  const Pose shifted = X_BO * MakePose(Mat3::Identity(), Vec3(0.004, 0, 0));
  const Pose apart = X_BO * MakePose(Mat3::Identity(), Vec3(0.061, 0, 0));
  EXPECT_GT(block.CountInside(shifted, surface_B, 0.001f), surface_B.size() / 20);
  EXPECT_EQ(block.CountInside(apart, surface_B, 0.001f), 0u);
}

// The shipped L-bracket (base x in [0, 90], z in [0, 5]; upright x in
// [0, 5], z in [0, 60]; y in [-25, 25] mm) has, among its near symmetries,
// the turn over about its upright, (x, y, z) -> (x, -y, 60 - z), and the
// turn end for end about its base plate, (x, y, z) -> (90 - x, y, 5 - z).
// The bushing, revolute about z, is nearly the same upside down; no near
// symmetry of it is a turn about its axis (that is its symmetry).
TEST(PoseEstimator, FindsTheNearSymmetriesOfTheShippedParts) {
  auto bracket = PoseEstimator::Build(MakeLBracket(), Symmetry{});
  ASSERT_TRUE(bracket.ok()) << bracket.status().ToString();
  const std::vector<Pose>& F = (*bracket)->near_symmetries();
  EXPECT_LE(F.size(), 4u);
  const auto has = [&](const std::function<Vec3(const Vec3&)>& map) {
    for (const Pose& f : F) {
      double worst = 0;
      for (const Vec3& c : {Vec3(0, -0.025, 0), Vec3(0.09, 0.025, 0.005), Vec3(0.005, 0.025, 0.06), Vec3(0.05, 0, 0.03)}) {
        worst = std::max(worst, (f * c - map(c)).norm());
      }
      if (worst < 0.0015) return true;
    }
    return false;
  };
  EXPECT_TRUE(has([](const Vec3& p) { return Vec3(p.x(), -p.y(), 0.06 - p.z()); }));
  EXPECT_TRUE(has([](const Vec3& p) { return Vec3(0.09 - p.x(), p.y(), 0.005 - p.z()); }));
  EXPECT_FALSE(has([](const Vec3& p) { return p; }));

  auto bushing = PoseEstimator::Build(MakeFlangedBushing(), testing::RevoluteZ());
  ASSERT_TRUE(bushing.ok()) << bushing.status().ToString();
  ASSERT_FALSE((*bushing)->near_symmetries().empty());
  for (const Pose& f : (*bushing)->near_symmetries()) {
    EXPECT_LT(f.rotation().col(2).z(), -0.99) << "a near symmetry that keeps the axis is the symmetry itself";
  }

  PoseEstimatorOptions none;
  none.max_near_symmetries = 0;
  auto plain = PoseEstimator::Build(MakeLBracket(), Symmetry{}, none);
  ASSERT_TRUE(plain.ok());
  EXPECT_TRUE((*plain)->near_symmetries().empty());
  PoseEstimatorOptions bad;
  bad.near_symmetry_min_overlap = 1.5;
  EXPECT_EQ(PoseEstimator::Build(MakeLBracket(), Symmetry{}, bad).status().code(), Status::Code::kInvalidArgument);
}

// The shipped tee's three arms are alike (outer radius 20 mm, 50 mm from the
// junction): a half-turn about the bisector of the run's +x end and the
// branch end swaps them, (x, y, z) -> (z, -y, x), and keeps two of the
// three arms on the tee (arm_swaps). Without arm_swaps no near symmetry
// maps the run end onto the branch end.
TEST(PoseEstimator, FindsTheArmSwapOfATee) {
  Symmetry tee;
  tee.kind = Symmetry::Kind::kDiscrete;
  tee.order = 2;
  const auto swaps_arms = [&](const std::vector<Pose>& F) {
    for (const Pose& f : F) {
      // Either run end onto the branch end and the branch end back onto it
      // (the tee's half-turn about z makes both run ends one).
      const Vec3 branch_end = f * Vec3(0, 0, 0.05);
      const bool run_to_branch = (f * Vec3(0.05, 0, 0) - Vec3(0, 0, 0.05)).norm() < 0.002 ||
                                 (f * Vec3(-0.05, 0, 0) - Vec3(0, 0, 0.05)).norm() < 0.002;
      const bool branch_to_run = std::abs(std::abs(branch_end.x()) - 0.05) < 0.002 && branch_end.tail<2>().norm() < 0.002;
      if (run_to_branch && branch_to_run) return true;
    }
    return false;
  };
  auto est = PoseEstimator::Build(MakePipeTee(), tee);
  ASSERT_TRUE(est.ok()) << est.status().ToString();
  EXPECT_TRUE(swaps_arms((*est)->near_symmetries()));
  PoseEstimatorOptions off;
  off.arm_swaps = false;
  auto plain = PoseEstimator::Build(MakePipeTee(), tee, off);
  ASSERT_TRUE(plain.ok());
  EXPECT_FALSE(swaps_arms((*plain)->near_symmetries()));
}

// A pipe tee is nearly round about its run (the branch aside): its one turn
// axis. A revolute part's axis is its declared symmetry, not a turn axis.
TEST(PoseEstimator, FindsTheTurnAxisOfATeesRunAndNoneOfARevolutePart) {
  Symmetry tee;
  tee.kind = Symmetry::Kind::kDiscrete;
  tee.order = 2;
  auto est = PoseEstimator::Build(MakePipeTee(), tee);
  ASSERT_TRUE(est.ok()) << est.status().ToString();
  const auto axes = (*est)->turn_axes();
  ASSERT_EQ(axes.size(), 1u);
  EXPECT_GT(std::abs(axes[0].second.x()), std::cos(1 * kDeg));
  EXPECT_LT(axes[0].first.tail<2>().norm(), 0.001);  // on the run's axis (part x)
  auto bushing = PoseEstimator::Build(MakeFlangedBushing(), testing::RevoluteZ());
  ASSERT_TRUE(bushing.ok());
  EXPECT_TRUE((*bushing)->turn_axes().empty());
  PoseEstimatorOptions none;
  none.turn_step_deg = 0;
  auto off = PoseEstimator::Build(MakePipeTee(), tee, none);
  ASSERT_TRUE(off.ok());
  EXPECT_TRUE((*off)->turn_axes().empty());
  PoseEstimatorOptions bad;
  bad.turn_step_deg = 200;
  EXPECT_FALSE(PoseEstimator::Build(MakePipeTee(), tee, bad).ok());
  bad = PoseEstimatorOptions{};
  bad.ambiguity_slack = 1.0;
  EXPECT_FALSE(PoseEstimator::Build(MakePipeTee(), tee, bad).ok());
}

TEST(PoseEstimator, AFlangeFittedIntoALargerPlateFillsTheBoreAndIsRejected) {
  // The false detection the hole test is for: a bushing upside down with its
  // flange's bottom face in a plate's top face (its hub inside the plate,
  // where nothing can be seen). The flange alone explains the plate well;
  // only the plate's surface going on through the bore says otherwise.
  auto bushing = PoseEstimator::Build(MakeFlangedBushing(), testing::RevoluteZ());
  ASSERT_TRUE(bushing.ok()) << bushing.status().ToString();
  const TestCamera cam = DefaultCamera();
  const TriangleMesh floor = Floor();
  // Raised above the floor (on something out of view) so that the hub, 32
  // mm below the face, stays above the floor.
  const TriangleMesh plate = testing::MakeBox({-0.06f, -0.05f, 0.055f}, {0.06f, 0.05f, 0.06f});
  const RenderedScene scene = Render({{&plate, Pose::Identity()}, {&floor, Pose::Identity()}}, cam, 0.0002, 11);
  const std::vector<Eigen::Vector3f> plate_points = testing::PointsWithLabels(scene, {1});
  SceneView view = OnFloor(ViewOf(plate_points, cam));
  view.depth = &scene.depth;
  view.intrinsics = cam.K;
  const Pose fitted = MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), Vec3(0.01, 0.0, 0.06));
  auto h = (*bushing)->Score(view, fitted);
  ASSERT_TRUE(h.ok());
  EXPECT_GT(h->score, 0.9) << "the flange explains the plate: without the hole test it would be a detection";
  EXPECT_GE(h->hole_points, 8);
  EXPECT_GT(h->filled_hole_points, h->hole_points * 9 / 10);
  // The full search over the plate finds flanges in it, and the test
  // rejects every one (the bore lands on the plate wherever the flange is).
  auto r = (*bushing)->Estimate(view);
  ASSERT_TRUE(r.ok());
  EXPECT_TRUE(r->hypotheses.empty()) << r->hypotheses.size() << " bushings on a plain plate";
  EXPECT_NE(r->no_result_reason.find("holes"), std::string::npos) << r->no_result_reason;

  // A real bushing, either way up on the floor: through the bore the camera
  // sees the floor 40 mm below, nothing fills it, and it is found.
  const TriangleMesh part = MakeFlangedBushing();
  for (const bool upside_down : {false, true}) {
    const Mat3 R(Eigen::AngleAxisd(upside_down ? M_PI : 0.0, Vec3::UnitX()));
    const Pose X_BO = Resting(part, R, 0.01, -0.02);
    const RenderedScene real = Render({{&part, X_BO}, {&floor, Pose::Identity()}}, cam, 0.0002, 12);
    const std::vector<Eigen::Vector3f> segment = testing::PointsWithLabels(real, {1});
    SceneView v = OnFloor(ViewOf(segment, cam));
    v.depth = &real.depth;
    v.intrinsics = cam.K;
    auto truth = (*bushing)->Score(v, X_BO);
    ASSERT_TRUE(truth.ok());
    EXPECT_GE(truth->hole_points, 8) << upside_down;
    EXPECT_EQ(truth->filled_hole_points, 0) << upside_down;
    auto found = (*bushing)->Estimate(v);
    ASSERT_TRUE(found.ok());
    ASSERT_FALSE(found->hypotheses.empty()) << upside_down << ": " << found->no_result_reason;
    EXPECT_LT(SymmetricTranslationError(found->hypotheses[0].X_BO, X_BO, testing::RevoluteZ()), 0.0005);
  }

  PoseEstimatorOptions bad;
  bad.hole_margin = 0;
  EXPECT_EQ(PoseEstimator::Build(MakeFlangedBushing(), testing::RevoluteZ(), bad).status().code(),
            Status::Code::kInvalidArgument);
}

TEST(SymmetricPoseError, RevolutePartRotatedAboutItsAxisHasZeroError) {
  const Symmetry s = testing::RevoluteZ();
  const Pose X = MakePose(Mat3(Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized())), Vec3(0.1, 0.2, 0.3));
  for (double a : {0.3, 1.7, M_PI}) {
    const Pose Y = X * MakePose(Mat3(Eigen::AngleAxisd(a, Vec3::UnitZ())), Vec3::Zero());
    EXPECT_NEAR(SymmetricRotationError(X, Y, s), 0.0, 1e-9);
    EXPECT_NEAR(SymmetricTranslationError(X, Y, s), 0.0, 1e-12);
    EXPECT_GT(SymmetricRotationError(X, Y, Symmetry{}), a - 1e-9);
  }
  // Tilting the axis is an error of the tilt angle.
  const Pose T = X * MakePose(Mat3(Eigen::AngleAxisd(0.2, Vec3::UnitX()) * Eigen::AngleAxisd(1.0, Vec3::UnitZ())),
                              Vec3::Zero());
  EXPECT_NEAR(SymmetricRotationError(X, T, s), 0.2, 1e-9);
}

TEST(SymmetricPoseError, DiscreteSymmetryTakesTheNearestEquivalentRotation) {
  Symmetry s;
  s.kind = Symmetry::Kind::kDiscrete;
  s.order = 2;
  const Pose X = MakePose(Mat3(Eigen::AngleAxisd(0.4, Vec3(0, 1, 1).normalized())), Vec3(0, 0, 0.1));
  const auto rz = [](double a) { return MakePose(Mat3(Eigen::AngleAxisd(a, Vec3::UnitZ())), Vec3::Zero()); };
  EXPECT_NEAR(SymmetricRotationError(X, X * rz(M_PI), s), 0.0, 1e-9);
  EXPECT_NEAR(SymmetricRotationError(X, X * rz(M_PI / 2), s), M_PI / 2, 1e-9);
  EXPECT_NEAR(SymmetricRotationError(X, X * rz(M_PI + 0.1), s), 0.1, 1e-9);
  // An extra flip about x is equivalent too.
  const Symmetry b = BlockSymmetry();
  const Pose flip = MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), Vec3::Zero());
  EXPECT_NEAR(SymmetricRotationError(X, X * flip * rz(M_PI), b), 0.0, 1e-9);
  EXPECT_GT(SymmetricRotationError(X, X * flip, s), 3.0);
}

TEST(SymmetricPoseError, AddSIsZeroForSymmetricPosesAndGrowsWithOffset) {
  const PoseEstimator& e = Estimator(1);  // revolute
  const Pose X = MakePose(Mat3(Eigen::AngleAxisd(0.3, Vec3::UnitX())), Vec3(0, 0, 0.05));
  const Pose Y = X * MakePose(Mat3(Eigen::AngleAxisd(1.0, Vec3::UnitZ())), Vec3::Zero());
  EXPECT_LT(AddS(e.surface_points_O(), X, Y), 0.001);  // within the sample spacing
  Pose Z = X;
  Z.translation().x() += 0.005;
  EXPECT_GT(AddS(e.surface_points_O(), X, Z), 0.002);
}

}  // namespace
}  // namespace bp
