// Perception's stages one at a time (pipeline/internal/): segmentation on
// rendered frames, acceptance with spherical parts whose geometry is exact,
// the residual views, the depth noise measurement and smoothing,
// verification and the model tables of a box.
#include <gtest/gtest.h>

#include <limits>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <memory>
#include <numeric>
#include <random>
#include <set>
#include <vector>

#include <tbb/task_arena.h>

#include "core/mesh_gen.h"
#include "pipeline/internal/acceptance.h"
#include "pipeline/internal/depth_smoothing.h"
#include "pipeline/internal/enclosing_parts.h"
#include "pipeline/internal/fit_limit.h"
#include "pipeline/internal/planar_faces.h"
#include "pipeline/internal/pose_model.h"
#include "pipeline/internal/pose_search.h"
#include "pipeline/internal/resting_poses.h"
#include "pipeline/internal/roi_cloud.h"
#include "pipeline/internal/segmentation.h"
#include "pipeline/internal/verification.h"
#include "pipeline/internal/view_preparation.h"
#include "pipeline/internal/view_passes.h"
#include "tests/pipeline/pose_test_util.h"

namespace bp::internal {
namespace {

using testing::DefaultCamera;
using testing::MakeBox;
using testing::Render;
using testing::RenderedScene;
using testing::TestCamera;

// The bin frame W = B: floor at z = 0, the camera 1 m above it looking down.
struct Scene {
  Frame frame;
  RoiCloud roi;
};

// Renders boxes (lo, hi in B) on a floor; crops from `roi_floor` above the
// floor up to 0.3 m.
Scene RenderBoxes(const std::vector<std::pair<Eigen::Vector3f, Eigen::Vector3f>>& boxes, float roi_floor,
                  double sigma = 0.0002) {
  const TestCamera cam = DefaultCamera();
  const TriangleMesh floor = MakeBox({-0.5f, -0.5f, -0.01f}, {0.5f, 0.5f, 0.f});
  std::vector<TriangleMesh> meshes;
  for (const auto& [lo, hi] : boxes) meshes.push_back(MakeBox(lo, hi));
  std::vector<std::pair<const TriangleMesh*, Pose>> objects = {{&floor, Pose::Identity()}};
  for (const TriangleMesh& m : meshes) objects.emplace_back(&m, Pose::Identity());
  const RenderedScene rendered = Render(objects, cam, sigma, 7);
  Scene s;
  s.frame.intrinsics = cam.K;
  s.frame.depth = rendered.depth;
  s.frame.X_BC = cam.X_BC;
  RoiBox box;
  box.min_W = Eigen::Vector3f(-0.2f, -0.15f, roi_floor);
  box.max_W = Eigen::Vector3f(0.2f, 0.15f, 0.3f);
  CropToRoi(s.frame, Pose::Identity(), box, &s.roi);
  return s;
}

Segments SegmentGrid(const Scene& s, const SegmentationOptions& options = {}) {
  return GroupGridSegments(s.roi, LabelGrid(s.roi, s.frame, Pose::Identity(), options), options);
}

// The B box a segment's samples lie in.
Eigen::AlignedBox3f BoundsOf(const Segments& segments, size_t s) {
  Eigen::AlignedBox3f b;
  for (int32_t k = segments.range[s].first; k < segments.range[s].second; ++k) b.extend(segments.points[k]);
  return b;
}

TEST(Segmentation, TwoSeparateBoxesAreTwoSegmentsLargestFirst) {
  const Scene s = RenderBoxes({{{-0.1f, -0.05f, 0.f}, {-0.02f, 0.03f, 0.04f}}, {{0.04f, 0.f, 0.f}, {0.08f, 0.04f, 0.02f}}},
                              0.01f);
  const Segments segments = SegmentGrid(s);
  ASSERT_EQ(segments.range.size(), 2u);
  EXPECT_GT(segments.range[0].second - segments.range[0].first, segments.range[1].second - segments.range[1].first);
  // The larger is the first box's top, the smaller the second's.
  EXPECT_NEAR(BoundsOf(segments, 0).center().x(), -0.06f, 0.01f);
  EXPECT_NEAR(BoundsOf(segments, 1).center().x(), 0.06f, 0.01f);
  EXPECT_TRUE(segments.region_views.empty());
  ASSERT_EQ(segments.points.size(), segments.normals.size());
  ASSERT_EQ(segments.points.size(), segments.roi_index.size());
  for (size_t k = 0; k < segments.points.size(); ++k) {
    EXPECT_EQ(segments.points[k], s.roi.points_B[static_cast<size_t>(segments.roi_index[k])]);
  }
  // The ROI points on the first box's top carry its segment (all but pixels
  // on its border, whose normals lean); each top is one connected region.
  ASSERT_EQ(segments.segment_of_point.size(), s.roi.points_B.size());
  std::set<int32_t> first_top, second_top;
  int top = 0, top_in_segment = 0;
  for (size_t i = 0; i < s.roi.points_B.size(); ++i) {
    const Eigen::Vector3f& p = s.roi.points_B[i];
    if (p.z() > 0.035f) {
      ++top;
      top_in_segment += segments.segment_of_point[i] == 0;
      first_top.insert(segments.region_of_point[i]);
    } else if (p.z() > 0.015f && p.z() < 0.025f && p.x() > 0.045f && p.x() < 0.075f) {
      second_top.insert(segments.region_of_point[i]);
    }
  }
  EXPECT_GT(top_in_segment, 0.95 * top);
  ASSERT_EQ(first_top.size(), 1u);
  ASSERT_EQ(second_top.size(), 1u);
  EXPECT_NE(*first_top.begin(), *second_top.begin());
  EXPECT_GE(LargestRegionPoints(segments.region_of_point), segments.range[0].second - segments.range[0].first);
}

TEST(Segmentation, TheFloorBandIsNoSegment) {
  // The ROI reaches below the floor: the floor lies within the floor band,
  // a 20 mm box above it.
  const Scene s = RenderBoxes({{{0.04f, 0.f, 0.f}, {0.08f, 0.04f, 0.02f}}}, -0.005f);
  const Segments segments = SegmentGrid(s);
  ASSERT_EQ(segments.range.size(), 1u);
  EXPECT_GT(BoundsOf(segments, 0).min().z(), 0.015f);
  // With no floor band, the floor is a segment too.
  SegmentationOptions no_band;
  no_band.floor_band = 0.f;
  EXPECT_GT(SegmentGrid(s, no_band).range.size(), 1u);
}

TEST(Segmentation, SegmentsAreTheSameOnOneThreadAndTwo) {
  const Scene s = RenderBoxes({{{-0.1f, -0.05f, 0.f}, {-0.02f, 0.03f, 0.04f}},
                               {{-0.02f, -0.02f, 0.f}, {0.03f, 0.02f, 0.025f}},
                               {{0.05f, 0.f, 0.f}, {0.09f, 0.06f, 0.015f}}},
                              0.01f);
  Segments one, two;
  tbb::task_arena(1).execute([&] { one = SegmentGrid(s); });
  tbb::task_arena(2).execute([&] { two = SegmentGrid(s); });
  EXPECT_EQ(one.range, two.range);
  EXPECT_EQ(one.points, two.points);
  EXPECT_EQ(one.roi_index, two.roi_index);
  EXPECT_EQ(one.region_views, two.region_views);
  EXPECT_EQ(one.segment_of_point, two.segment_of_point);
  EXPECT_EQ(one.region_of_point, two.region_of_point);
}

TEST(Segmentation, ASegmentViewTakesTheSamplesNearItWithAContextRadius) {
  // Two boxes 10 mm apart: each view alone, then with the other's samples.
  const Scene s = RenderBoxes({{{-0.05f, -0.02f, 0.f}, {-0.005f, 0.02f, 0.03f}}, {{0.005f, -0.02f, 0.f}, {0.05f, 0.02f, 0.02f}}},
                              0.01f);
  const Segments segments = SegmentGrid(s);
  ASSERT_EQ(segments.range.size(), 2u);
  const std::vector<ViewIndices> alone = SegmentViews(segments, 0.f);
  ASSERT_EQ(alone.size(), 2u);
  for (size_t v = 0; v < 2; ++v) {
    EXPECT_EQ(alone[v].size(), static_cast<size_t>(segments.range[v].second - segments.range[v].first));
  }
  const std::vector<ViewIndices> context = SegmentViews(segments, 0.06f);
  EXPECT_GT(context[0].size(), alone[0].size());
  EXPECT_TRUE(std::equal(alone[0].begin(), alone[0].end(), context[0].begin()));  // its own samples first
}

TEST(Segmentation, AnUnorganizedCloudIsSegmentedByVoxelConnectivity) {
  RoiCloud roi;
  std::mt19937 rng{3};
  std::uniform_real_distribution<float> u(0.f, 0.03f);
  for (const float x0 : {0.f, 0.1f}) {
    for (int i = 0; i < 400; ++i) roi.points_B.emplace_back(x0 + u(rng), u(rng), 0.02f + 0.1f * u(rng));
  }
  for (int i = 0; i < 20; ++i) roi.points_B.emplace_back(0.5f + 0.02f * static_cast<float>(i), 0.3f, 0.02f);
  auto [region_of_point, regions] = LabelCloud(roi, 0.003f);
  EXPECT_GE(regions, 3);
  const Segments segments = GroupCloudSegments(roi, std::move(region_of_point), regions, 150);
  ASSERT_EQ(segments.range.size(), 2u);
  EXPECT_TRUE(segments.normals.empty());
  for (size_t i = 0; i < roi.points_B.size(); ++i) {
    EXPECT_EQ(segments.segment_of_point[i], i < 400 ? 0 : i < 800 ? 1 : -1) << i;
  }
}

// A sphere of radius r centred on O's origin: surface samples, on-surface
// and inside tests in closed form.
class SphereModel final : public ClassModel {
 public:
  SphereModel(int class_id, float r) : class_id_(class_id), r_(r) {
    const int n = 400;
    const double golden = M_PI * (3.0 - std::sqrt(5.0));
    for (int k = 0; k < n; ++k) {
      const double z = 1.0 - 2.0 * (k + 0.5) / n, rho = std::sqrt(1.0 - z * z);
      surface_.push_back(r * Eigen::Vector3f(static_cast<float>(rho * std::cos(golden * k)),
                                             static_cast<float>(rho * std::sin(golden * k)), static_cast<float>(z)));
    }
  }
  int class_id() const override { return class_id_; }
  double diameter() const override { return 2.0 * r_; }
  Eigen::Vector3f extents() const override { return Eigen::Vector3f::Constant(2 * r_); }
  std::pair<float, float> planar_share_range() const override { return {0.f, 1.f}; }
  Eigen::Vector3f centroid_O() const override { return Eigen::Vector3f::Zero(); }
  ClassEstimate Estimate(const SegmentView&) const override { return {}; }
  Result<PoseHypothesis> Score(const SegmentView&, const Pose&) const override { return PoseHypothesis{}; }
  void MarkOnSurface(const Pose& X_BO, std::span<const Eigen::Vector3f> points_B, float tolerance,
                     std::vector<uint8_t>* on) const override {
    for (size_t i = 0; i < points_B.size(); ++i) {
      const float d = (points_B[i] - X_BO.translation().cast<float>()).norm();
      if (std::abs(d - r_) <= tolerance) (*on)[i] = 1;
    }
  }
  size_t CountInside(const Pose& X_BO, std::span<const Eigen::Vector3f> points_B, float min_depth) const override {
    size_t n = 0;
    for (const Eigen::Vector3f& p : points_B) n += (p - X_BO.translation().cast<float>()).norm() < r_ - min_depth;
    return n;
  }
  std::span<const Eigen::Vector3f> surface_points_O() const override { return surface_; }
  float inside_depth() const override { return 0.001f; }
  double lowest_upward_face() const override { return std::numeric_limits<double>::infinity(); }
  const PoseEstimatorOptions& estimator_options() const override { return options_; }

 private:
  PoseEstimatorOptions options_;
  int class_id_;
  float r_;
  std::vector<Eigen::Vector3f> surface_;
};

Candidate SphereAt(const SphereModel& m, const Vec3& c, double score, std::vector<int32_t> support) {
  Candidate out;
  out.class_id = m.class_id();
  out.diameter = m.diameter();
  out.centre_B = c;
  out.h.X_BO = MakePose(Mat3::Identity(), c);
  out.h.score = score;
  out.support_roi = std::move(support);
  return out;
}

std::vector<int32_t> Range(int32_t b, int32_t e) {
  std::vector<int32_t> v(static_cast<size_t>(e - b));
  std::iota(v.begin(), v.end(), b);
  return v;
}

TEST(Acceptance, OfTwoCandidatesForOnePartTheBetterScoreIsKeptInEitherOrder) {
  const SphereModel sphere(0, 0.02f);
  const std::vector<const ClassModel*> models = {&sphere};
  for (const bool better_first : {true, false}) {
    Acceptance acceptance(1000, models);
    const Candidate good = SphereAt(sphere, Vec3(0, 0, 0.02), 0.95, Range(0, 100));
    const Candidate close = SphereAt(sphere, Vec3(0.005, 0, 0.02), 0.9, Range(50, 150));
    if (better_first) {
      acceptance.Accept({good});
      acceptance.Accept({close});
    } else {
      acceptance.Accept({close});  // an earlier wave's
      acceptance.Accept({good});   // replaces it
    }
    const std::vector<Detection> d = acceptance.TakeDetections();
    ASSERT_EQ(d.size(), 1u);
    EXPECT_EQ(d[0].score, 0.95);
  }
}

TEST(Acceptance, ReplacingADetectionReleasesItsSupport) {
  const SphereModel sphere(0, 0.02f);
  const std::vector<const ClassModel*> models = {&sphere};
  Acceptance acceptance(1000, models);
  acceptance.Accept({SphereAt(sphere, Vec3(0, 0, 0.02), 0.8, Range(0, 200))});
  EXPECT_EQ(acceptance.claims(150), 1);
  acceptance.Accept({SphereAt(sphere, Vec3(0.002, 0, 0.02), 0.9, Range(0, 100))});
  EXPECT_EQ(acceptance.claims(50), 1);
  EXPECT_EQ(acceptance.claims(150), 0);
  EXPECT_FALSE(acceptance.never_accepted());
}

// PerceptionOptions::near_centre_min_shared: candidates whose surface
// centres lie within the NMS distance conflict only when the candidate's
// support lies on the detection's surface. Two touching spheres given the
// same surface centre (parts whose centroids lie off their material, an
// L-bracket's corner) are both kept; the same sphere found again from
// other points of its surface is still one part; without the rule the
// closeness alone makes them one.
TEST(Acceptance, CloseCentresConflictOnlyWhenTheSupportLiesOnTheDetection) {
  const SphereModel sphere(0, 0.02f);
  const std::vector<const ClassModel*> models = {&sphere};
  std::vector<Eigen::Vector3f> roi;
  const Vec3 a(0, 0, 0.02), b(0.04, 0, 0.02), centre(0.02, 0, 0.02);
  for (const Vec3& c : {a, b}) {  // 0-399 on a, 400-799 on b
    for (const Eigen::Vector3f& p : sphere.surface_points_O()) roi.push_back(p + c.cast<float>());
  }
  const auto at = [&](const Vec3& x, double score, std::vector<int32_t> support) {
    Candidate c = SphereAt(sphere, x, score, std::move(support));
    c.centre_B = centre;  // the two surface centres coincide
    return c;
  };
  const auto kept = [&](double min_shared, const Candidate& second) {
    Acceptance acceptance(roi.size(), models, min_shared, roi);
    acceptance.Accept({at(a, 0.95, Range(0, 200))});
    acceptance.Accept({second});
    return acceptance.TakeDetections().size();
  };
  const Candidate neighbour = at(b, 0.9, Range(400, 600));
  const Candidate again = at(a + Vec3(0.001, 0, 0), 0.9, Range(200, 400));  // a's other points
  EXPECT_EQ(kept(0.3, neighbour), 2u);
  EXPECT_EQ(kept(0.3, again), 1u);
  EXPECT_EQ(kept(0.0, neighbour), 1u);
  // Without the ROI points the rule cannot judge and closeness decides.
  Acceptance blind(roi.size(), models, 0.3);
  blind.Accept({at(a, 0.95, Range(0, 200))});
  blind.Accept({neighbour});
  EXPECT_EQ(blind.TakeDetections().size(), 1u);
}

TEST(Acceptance, PartsThatWouldInterpenetrateConflictAndTheBetterOneStays) {
  const SphereModel sphere(0, 0.02f);
  const std::vector<const ClassModel*> models = {&sphere};
  Acceptance acceptance(1000, models);
  // 25 mm apart: beyond the NMS distance (0.3 x 40 mm), 15 mm deep in each other.
  acceptance.Accept({SphereAt(sphere, Vec3(0, 0, 0.02), 0.9, Range(0, 100)),
                     SphereAt(sphere, Vec3(0.025, 0, 0.02), 0.85, Range(100, 200))});
  ASSERT_EQ(acceptance.TakeDetections().size(), 1u);
  // 40 mm apart, touching: both stay.
  Acceptance touching(1000, models);
  touching.Accept({SphereAt(sphere, Vec3(0, 0, 0.02), 0.9, Range(0, 100)),
                   SphereAt(sphere, Vec3(0.04, 0, 0.02), 0.85, Range(100, 200))});
  EXPECT_EQ(touching.TakeDetections().size(), 2u);
}

// Supersede (the enclosing pass): a larger part replaces a live detection
// whatever their scores, its support released, unless it also conflicts
// with another live detection.
TEST(Acceptance, ALargerPartSupersedesTheDetectionItEnclosesUnlessItMeetsAnother) {
  const SphereModel small(0, 0.01f), large(1, 0.03f);
  const std::vector<const ClassModel*> models = {&small, &large};
  Acceptance acceptance(1000, models);
  acceptance.Accept({SphereAt(small, Vec3(0, 0, 0.03), 0.95, Range(0, 100)),
                     SphereAt(small, Vec3(0.3, 0, 0.03), 0.9, Range(100, 200))});
  ASSERT_EQ(acceptance.Live().size(), 2u);
  const size_t inner = acceptance.Live()[0], far = acceptance.Live()[1];
  EXPECT_EQ(acceptance.detection(inner).score, 0.95);
  // A large sphere about the first, scoring lower: replaces it.
  EXPECT_TRUE(acceptance.Supersede(inner, SphereAt(large, Vec3(0.002, 0, 0.03), 0.7, Range(50, 400))));
  EXPECT_EQ(acceptance.claims(10), 0);
  EXPECT_EQ(acceptance.claims(300), 1);
  // One over the other detection that would sink into the large one: refused.
  EXPECT_FALSE(acceptance.Supersede(far, SphereAt(large, Vec3(0.04, 0, 0.03), 0.99, Range(100, 200))));
  EXPECT_FALSE(acceptance.Supersede(inner, SphereAt(large, Vec3(0, 0, 0.03), 0.99, Range(0, 100))));  // dropped
  const std::vector<Detection> d = acceptance.TakeDetections();
  ASSERT_EQ(d.size(), 2u);
  EXPECT_EQ(d[0].class_id, 0);
  EXPECT_EQ(d[1].class_id, 1);
  EXPECT_EQ(d[1].score, 0.7);
}

TEST(Acceptance, ACandidateWhoseSupportOthersClaimIsDroppedUnlessOneOfThemHoldsATenth) {
  const SphereModel sphere(0, 0.01f);
  const std::vector<const ClassModel*> models = {&sphere};
  Acceptance acceptance(2000, models);
  // 20 detections far apart, each claiming 5 points of what comes next.
  std::vector<Candidate> spread;
  for (int k = 0; k < 20; ++k) spread.push_back(SphereAt(sphere, Vec3(0.1 * k, 1.0, 0.0), 0.9, Range(5 * k, 5 * k + 5)));
  acceptance.Accept(spread);
  // 100 points, 100% claimed, no one detection holding 10 of them: dropped
  // even at a better score.
  acceptance.Accept({SphereAt(sphere, Vec3(5.0, 5.0, 0.0), 0.99, Range(0, 100))});
  EXPECT_EQ(acceptance.TakeDetections().size(), 20u);
}

TEST(Acceptance, TheExplainedFractionCountsViewPointsOnLiveDetectionsSurfaces) {
  const SphereModel sphere(0, 0.02f);
  const std::vector<const ClassModel*> models = {&sphere};
  Acceptance acceptance(10, models);
  acceptance.Accept({SphereAt(sphere, Vec3(0, 0, 0), 0.8, {0})});
  Segments segments;
  segments.points = {{0.02f, 0.f, 0.f}, {0.f, 0.021f, 0.f}, {0.f, 0.f, 0.05f}, {0.f, -0.02f, 0.f}};
  EXPECT_DOUBLE_EQ(acceptance.ExplainedFraction(segments, {0, 1, 2, 3}), 0.75);
  EXPECT_DOUBLE_EQ(acceptance.ExplainedFraction(segments, {0, 1, 2, 3}, 0.9), 0.0);  // scores below 0.9 ignored
  EXPECT_DOUBLE_EQ(acceptance.ExplainedFraction(segments, {}), 0.0);
}

TEST(ViewPasses, AResidualViewIsTheUnclaimedPartOfASegmentWhenEnoughIsLeft) {
  const SphereModel sphere(0, 0.02f);
  const std::vector<const ClassModel*> models = {&sphere};
  Segments segments;
  segments.points.resize(1000, Eigen::Vector3f::Zero());
  segments.roi_index = Range(0, 1000);
  segments.range = {{0, 600}, {600, 800}, {800, 1000}};
  Acceptance acceptance(1000, models);
  // Segment 0: 400 of 600 claimed (200 left, a third); segment 1: all claimed;
  // segment 2: 10 claimed (190 left, but under min_segment_points = 195).
  acceptance.Accept({SphereAt(sphere, Vec3(0, 0, 0), 0.9, Range(0, 400)),
                     SphereAt(sphere, Vec3(1, 0, 0), 0.9, Range(600, 800)),
                     SphereAt(sphere, Vec3(2, 0, 0), 0.9, Range(800, 810))});
  const std::vector<ViewIndices> residual = ResidualViews(segments, acceptance, 195);
  ASSERT_EQ(residual.size(), 1u);
  EXPECT_EQ(residual[0], Range(400, 600));
}

TEST(Acceptance, ASampleIsUnexplainedOffEveryLiveDetectionsSurfaceAndOutOfItsSupport) {
  const SphereModel sphere(0, 0.02f);
  const std::vector<const ClassModel*> models = {&sphere};
  Acceptance acceptance(10, models);
  acceptance.Accept({SphereAt(sphere, Vec3(0, 0, 0), 0.8, {2})});
  Segments segments;
  // On the surface; 2 mm off it; in the support, far off; neither.
  segments.points = {{0.02f, 0.f, 0.f}, {0.f, 0.022f, 0.f}, {0.f, 0.f, 0.05f}, {0.f, 0.f, 0.03f}};
  segments.roi_index = {0, 1, 2, 3};
  EXPECT_EQ(acceptance.UnexplainedSamples(segments), (std::vector<uint8_t>{0, 0, 0, 1}));
}

// The enclosing pass's view of a small detection: every sample within half
// the larger diameter plus a quarter of its own of its centre that no other
// detection explains, in sample order, whatever order the samples lie in
// space (here shuffled), and its share on the detection flagged.
TEST(EnclosingParts, AViewHoldsTheSamplesWithinReachNoOtherDetectionExplainsInSampleOrder) {
  const SphereModel small(0, 0.01f), large(1, 0.03f);
  const std::vector<const ClassModel*> models = {&small, &large};
  Segments segments;
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> coord(-0.1f, 0.1f);
  for (int k = 0; k < 6000; ++k) segments.points.emplace_back(coord(rng), coord(rng), coord(rng));
  // Every 50th on the small detection's surface (r 10 mm about the origin).
  for (size_t k = 0; k < 6000; k += 50) segments.points[k] = 0.01f * segments.points[k].normalized();
  segments.roi_index = Range(0, 6000);
  Acceptance acceptance(6000, models);
  // The small detection, with samples 1-20 as its support, and a neighbour
  // 30 mm away whose surface explains samples near it.
  acceptance.Accept({SphereAt(small, Vec3(0, 0, 0), 0.9, Range(1, 21)),
                     SphereAt(small, Vec3(0.03, 0, 0), 0.9, {})});
  const std::vector<size_t> live = acceptance.Live();
  ASSERT_EQ(live.size(), 2u);
  const size_t detection =
      acceptance.detection(live[0]).X_BO.translation().norm() == 0.0 ? live[0] : live[1];
  const std::vector<EnclosingView> views = EnclosingViews(segments, acceptance, models, 1);
  const auto of = std::find_if(views.begin(), views.end(),
                               [&](const EnclosingView& v) { return v.detection == detection; });
  ASSERT_NE(of, views.end());
  EXPECT_EQ(of->model, 1);
  const std::vector<uint8_t> left = acceptance.UnexplainedSamples(segments);
  const auto r = static_cast<float>(0.5 * large.diameter() + 0.25 * small.diameter());
  ViewIndices expected;
  std::vector<uint8_t> expected_on;
  for (size_t s = 0; s < segments.points.size(); ++s) {
    if (segments.points[s].squaredNorm() > r * r) continue;
    const bool on = std::abs(segments.points[s].norm() - 0.01f) <= 0.0025f || (s >= 1 && s < 21);
    if (!on && !left[s]) continue;
    expected.push_back(static_cast<int32_t>(s));
    expected_on.push_back(on ? 1 : 0);
  }
  ASSERT_GT(expected.size(), 100u);
  EXPECT_EQ(of->view, expected);
  EXPECT_EQ(of->on_detection, expected_on);
}

// A 50 x 50 mm plate sampled every 2 mm (z = 0, with +-0.5 mm of
// alternating noise), and an L of two such plates (z = 0 and x = 0).
std::vector<Eigen::Vector3f> PlatePoints(bool l_shape) {
  std::vector<Eigen::Vector3f> points;
  for (int i = 0; i < 25; ++i) {
    for (int j = 0; j < 25; ++j) {
      const float a = 0.002f * static_cast<float>(i), b = 0.002f * static_cast<float>(j);
      const float noise = (i + j) % 2 == 0 ? 0.0005f : -0.0005f;
      points.emplace_back(a + 0.002f, b, noise);
      if (l_shape) points.emplace_back(noise, b, a + 0.002f);
    }
  }
  return points;
}

TEST(Acceptance, ShareOnOnePlaneCountsThePointsNearTheirLeastSquaresPlane) {
  const std::vector<Eigen::Vector3f> plate = PlatePoints(false);
  const std::vector<Eigen::Vector3f> l_shape = PlatePoints(true);
  EXPECT_DOUBLE_EQ(ShareOnOnePlane(plate, 0.0015), 1.0);
  EXPECT_LT(ShareOnOnePlane(plate, 0.0004), 0.01);  // the noise lies 0.5 mm off it
  // The best plane through an L cuts both plates: far fewer than 95% on it.
  EXPECT_LT(ShareOnOnePlane(l_shape, 0.0015), 0.6);
  EXPECT_DOUBLE_EQ(ShareOnOnePlane(std::vector<Eigen::Vector3f>(plate.begin(), plate.begin() + 2), 0.0015), 1.0);
}

// The shipped L-bracket lying on its side, seen from above: the camera sees
// its side face (y = -25 mm in O, the L of the base and the upright, 5 mm
// wide) on a 1.5 mm pixel pitch, 0.3 mm of depth noise, and every third
// point of the face's outline (within 1.5 mm of it) has a mixed pixel
// behind it, 3-30 mm further along the line of sight.
struct EdgeOnView {
  Pose X_BO;
  Pose X_BC;
  std::vector<Eigen::Vector3f> face, points;  // points: the face's, then the mixed pixels
};
EdgeOnView EdgeOnBracket() {
  EdgeOnView v;
  v.X_BO = MakePose(Mat3(Eigen::AngleAxisd(-M_PI / 2, Vec3::UnitX())), Vec3(0.0, 0.0, 0.025));
  v.X_BC = MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), Vec3(0.04, 0.03, 1.0));
  std::mt19937 rng(7);
  std::normal_distribution<float> noise(0.f, 0.0003f);
  std::uniform_real_distribution<float> behind(0.003f, 0.03f);
  const auto on_l = [](float x, float z) { return (x <= 0.090f && z <= 0.005f) || (x <= 0.005f && z <= 0.060f); };
  std::vector<Eigen::Vector3f> mixed;
  int outline = 0;
  for (float x = 0.0005f; x < 0.090f; x += 0.0015f) {
    for (float z = 0.0005f; z < 0.060f; z += 0.0015f) {
      if (!on_l(x, z)) continue;
      const Eigen::Vector3f p = (v.X_BO * Vec3(x, -0.025, z)).cast<float>() + Eigen::Vector3f(0, 0, noise(rng));
      v.face.push_back(p);
      const bool edge = !on_l(x + 0.0015f, z) || !on_l(x, z + 0.0015f) || x < 0.0015f || z < 0.0015f;
      if (edge && outline++ % 3 == 0) {
        const Eigen::Vector3f ray = (p - v.X_BC.translation().cast<float>()).normalized();
        mixed.push_back(p + behind(rng) * ray);
      }
    }
  }
  v.points = v.face;
  v.points.insert(v.points.end(), mixed.begin(), mixed.end());
  return v;
}

TEST(ViewPreparation, AViewMostlyOnOnePlaneLeavesItsMixedPixelsOffThePlaneItFits) {
  const EdgeOnView v = EdgeOnBracket();
  ASSERT_GT(v.points.size(), v.face.size() + 20);  // mixed pixels: 10-15% of the view
  SceneView view;
  view.points_B = v.points;
  view.X_BC = v.X_BC;
  const ViewBase base(view);
  // The mixed pixels lift the least-squares plane's RMS past 1 mm.
  EXPECT_FALSE(base.view_plane().has_value());
  const ViewBase::MostlyPlanar& mostly = base.OnMostlyOnePlane();
  ASSERT_TRUE(mostly.normal.has_value());
  EXPECT_GT(mostly.normal->dot(Eigen::Vector3f::UnitZ()), 0.999f);  // towards the camera
  // The face's points, within 1.5 mm of the plane; the mixed pixels 3 mm
  // or more behind it left out.
  EXPECT_EQ(mostly.pts.size(), v.face.size());
  EXPECT_NEAR(mostly.share, static_cast<double>(v.face.size()) / static_cast<double>(v.points.size()), 1e-9);
  // The same view without its mixed pixels passes the RMS test alone.
  view.points_B = v.face;
  EXPECT_TRUE(ViewBase(view).view_plane().has_value());
}

TEST(ViewPreparation, AViewOnTwoPlatesHasNoPlaneHoldingMostOfIt) {
  // An L of two plates of 625 points each.
  std::vector<Eigen::Vector3f> l_shape = PlatePoints(true);
  for (Eigen::Vector3f& p : l_shape) p += Eigen::Vector3f(0.f, 0.f, 0.01f);
  SceneView view;
  view.points_B = l_shape;
  view.X_BC = MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX()) * Eigen::AngleAxisd(0.6, Vec3::UnitY())),
                       Vec3(0.3, 0.02, 0.8));
  const ViewBase base(view);
  EXPECT_FALSE(base.view_plane().has_value());
  EXPECT_LT(base.OnMostlyOnePlane().share, 0.6);
}

// With planar_view_min_share the estimator lays the bracket's side face on
// the plane of the edge-on view (face seeds) and finds its pose; without,
// point pair voting on one plane and its mixed pixels does not.
TEST(ViewPreparation, TheEdgeOnBracketIsFoundWithTheShareTest) {
  const EdgeOnView v = EdgeOnBracket();
  SceneView view;
  view.points_B = v.points;
  view.X_BC = v.X_BC;
  PoseEstimatorOptions on;
  on.planar_view_min_share = 0.75;
  const auto with = PoseEstimator::Build(MakeLBracket(), Symmetry{}, on).value();
  const Result<PoseEstimates> found = with->Estimate(view);
  ASSERT_TRUE(found.ok());
  ASSERT_FALSE(found->hypotheses.empty()) << found->no_result_reason;
  EXPECT_LT(SymmetricTranslationError(found->hypotheses[0].X_BO, v.X_BO, Symmetry{}), 0.005);
  EXPECT_LT(SymmetricRotationError(found->hypotheses[0].X_BO, v.X_BO, Symmetry{}), 5.0 * M_PI / 180.0);
}

TEST(Acceptance, ADetectionMostlyHiddenWhoseSupportLiesOnOnePlaneIsWithheld) {
  std::vector<Eigen::Vector3f> roi = PlatePoints(false);
  const auto plate_end = static_cast<int32_t>(roi.size());
  for (const Eigen::Vector3f& p : PlatePoints(true)) roi.push_back(p + Eigen::Vector3f(0.2f, 0.f, 0.f));
  const auto l_end = static_cast<int32_t>(roi.size());
  const auto detection = [](int class_id, double visible, std::vector<int32_t> support) {
    Detection d;
    d.class_id = class_id;
    d.visible_fraction = visible;
    d.support = std::move(support);
    return d;
  };
  std::vector<Detection> detections = {
      detection(0, 0.4, Range(0, plate_end)),      // one plane, mostly hidden: withheld
      detection(1, 0.6, Range(0, plate_end)),      // one plane, seen more than half: kept
      detection(2, 0.4, Range(plate_end, l_end)),  // two planes: kept
      detection(3, 0.4, {}),                       // no support: kept
  };
  std::vector<Detection> off = detections;
  EXPECT_EQ(WithholdOnePlane(0.0, roi, &off), 0);
  EXPECT_EQ(off.size(), 4u);
  EXPECT_EQ(WithholdOnePlane(0.5, roi, &detections), 1);
  ASSERT_EQ(detections.size(), 3u);
  EXPECT_EQ(detections[0].class_id, 1);
  EXPECT_EQ(detections[1].class_id, 2);
  EXPECT_EQ(detections[2].class_id, 3);
}

// Grid of 40 x 30 cells, 1 mm apart: segments 0 and 1 side by side (rows
// 0-9), pieces below min_segment_points under them (rows 10-14, the last two
// 10 mm higher: a depth jump), segment 2 apart (rows 20-29).
Segments ResidualRegionsGrid() {
  Segments s;
  const auto add = [&](int row, int col, float z) {
    s.points.emplace_back(0.001f * static_cast<float>(col), 0.001f * static_cast<float>(row), z);
    s.cell_of_sample.push_back(row * 40 + col);
  };
  for (const auto& [row0, col0] : {std::pair{0, 0}, std::pair{0, 20}, std::pair{20, 0}}) {
    const auto begin = static_cast<int32_t>(s.points.size());
    for (int row = row0; row < row0 + 10; ++row) {
      for (int col = col0; col < col0 + 20; ++col) add(row, col, 0.f);
    }
    s.range.emplace_back(begin, static_cast<int32_t>(s.points.size()));
  }
  for (int row = 10; row < 15; ++row) {
    for (int col = 0; col < 40; ++col) add(row, col, row < 13 ? 0.f : 0.01f);
  }
  s.roi_index = Range(0, static_cast<int32_t>(s.points.size()));
  s.grid_width = 40;
  s.grid_jump = 0.003f;
  return s;
}

TEST(ViewPasses, AResidualRegionJoinsTheUnexplainedSamplesOfSegmentsAndPiecesItTouches) {
  const SphereModel sphere(0, 0.02f);
  const std::vector<const ClassModel*> models = {&sphere};
  const Segments segments = ResidualRegionsGrid();
  std::vector<int32_t> expected = Range(0, 200);  // segment 0, then the pieces' rows 10-12
  for (int32_t k : Range(600, 720)) expected.push_back(k);
  // Segment 1 claimed by a detection far away: segment 0 and the pieces
  // beside it are one group; the pieces beyond the depth jump (80 samples)
  // are too few, and segment 2 alone repeats its own match.
  Acceptance claimed(1000, models);
  claimed.Accept({SphereAt(sphere, Vec3(1, 1, 1), 0.9, Range(200, 400))});
  const std::vector<ViewIndices> groups = ResidualRegionViews(segments, claimed, 150);
  ASSERT_EQ(groups.size(), 1u);
  EXPECT_EQ(groups[0], expected);
  // Nothing explained: segments 0 and 1 (side by side) and those pieces are one group.
  Acceptance none(1000, models);
  const std::vector<ViewIndices> all = ResidualRegionViews(segments, none, 150);
  ASSERT_EQ(all.size(), 1u);
  std::vector<int32_t> both = Range(0, 400);
  for (int32_t k : Range(600, 720)) both.push_back(k);
  EXPECT_EQ(all[0], both);
  // No grid (an unorganized cloud): no groups.
  Segments cloud = segments;
  cloud.grid_width = 0;
  EXPECT_TRUE(ResidualRegionViews(cloud, none, 150).empty());
}

// Two 10 x 10 patches of one plane, 1 mm cells, `gap` empty columns between
// them (grazing dropout along a crease): joined across up to 2 empty cells.
TEST(ViewPasses, AResidualRegionBridgesAHoleOfUpToTwoCells) {
  const SphereModel sphere(0, 0.02f);
  const std::vector<const ClassModel*> models = {&sphere};
  for (const int gap : {0, 1, 2, 3}) {
    Segments s;
    for (const int col0 : {0, 10 + gap}) {
      for (int row = 0; row < 10; ++row) {
        for (int col = col0; col < col0 + 10; ++col) {
          s.points.emplace_back(0.001f * static_cast<float>(col), 0.001f * static_cast<float>(row), 0.f);
          s.cell_of_sample.push_back(row * 40 + col);
        }
      }
    }
    s.roi_index = Range(0, 200);
    s.grid_width = 40;
    s.grid_jump = 0.006f;
    Acceptance none(200, models);
    EXPECT_EQ(ResidualRegionViews(s, none, 100).size(), gap <= 2 ? 1u : 2u) << "gap " << gap;
  }
}

// Two patches whose cells touch, the second 12 mm nearer the camera than
// the first (a part's arm in front of its own farther surface): grid
// connectivity keeps them apart; with across_jumps their union is one more
// view, after the groups'. A union one group holds 90% of adds none.
TEST(ViewPasses, ResidualGroupsTouchingAcrossADepthJumpAreAlsoMatchedJoined) {
  const SphereModel sphere(0, 0.02f);
  const std::vector<const ClassModel*> models = {&sphere};
  // Patch A: rows 0-9, columns 0-19 at z = 0; patch B: rows 0-9 from
  // column 20 on, `b_columns` wide, at z = 12 mm.
  const auto grid = [](int b_columns) {
    Segments s;
    for (int row = 0; row < 10; ++row) {
      for (int col = 0; col < 20 + b_columns; ++col) {
        s.points.emplace_back(0.001f * static_cast<float>(col), 0.001f * static_cast<float>(row),
                              col < 20 ? 0.f : 0.012f);
        s.cell_of_sample.push_back(row * 40 + col);
      }
    }
    s.roi_index = Range(0, static_cast<int32_t>(s.points.size()));
    s.grid_width = 40;
    s.grid_jump = 0.003f;
    return s;
  };
  // Sample order is row-major: A's and B's samples interleave by row.
  const Segments s = grid(10);
  std::vector<int32_t> a, b;
  for (int32_t k = 0; k < 300; ++k) (k % 30 < 20 ? a : b).push_back(k);
  Acceptance none(300, models);
  const std::vector<ViewIndices> apart = ResidualRegionViews(s, none, 150, false);
  ASSERT_EQ(apart.size(), 1u);  // B (100 samples) is below min_segment_points
  EXPECT_EQ(apart[0], a);
  const std::vector<ViewIndices> joined = ResidualRegionViews(s, none, 150, true);
  ASSERT_EQ(joined.size(), 2u);
  EXPECT_EQ(joined[0], a);
  EXPECT_EQ(joined[1], Range(0, 300));
  // B two columns wide: A holds 200 of 220 samples (91%), no union view.
  const Segments narrow = grid(2);
  Acceptance none2(220, models);
  EXPECT_EQ(ResidualRegionViews(narrow, none2, 150, true).size(), 1u);
  // B claimed by a detection: nothing to join A with.
  Acceptance claimed(300, models);
  claimed.Accept({SphereAt(sphere, Vec3(1, 1, 1), 0.9, b)});
  EXPECT_EQ(ResidualRegionViews(s, claimed, 150, true).size(), 1u);
}

// The views of a match nothing passing the bar was found in (best below it,
// -1 for no hypothesis) are taken out, in order, to be matched again with
// the estimator's own normals; the others stay.
TEST(ViewPasses, NothingFoundTakesTheViewsBelowTheBarForALookWithOwnNormals) {
  ViewSet views;
  views.views = {{0, 1}, {2, 3}, {4}, {5, 6}, {7}};
  views.first_region = 3;  // {5, 6} and {7} are region views
  MatchOutcome matched;
  matched.best = {0.9, -1.0, 0.59, 0.6, -1.0};
  const ViewSet again = NothingFound(views, matched, 0.6);
  EXPECT_TRUE(again.own_normals);
  ASSERT_EQ(again.views.size(), 3u);
  EXPECT_EQ(again.views[0], (ViewIndices{2, 3}));
  EXPECT_EQ(again.views[1], (ViewIndices{4}));
  EXPECT_EQ(again.views[2], (ViewIndices{7}));
  EXPECT_EQ(again.first_region, 2u);
  EXPECT_EQ(views.views[0], (ViewIndices{0, 1}));  // found: left in place
  EXPECT_EQ(views.views[3], (ViewIndices{5, 6}));
  // Every view found something: nothing to look at again.
  ViewSet all_found;
  all_found.views = {{0}, {1}};
  MatchOutcome good;
  good.best = {0.7, 0.95};
  EXPECT_TRUE(NothingFound(all_found, good, 0.6).views.empty());
}

TEST(FitLimit, TheMeasuredDepthNoiseOfANoisyPlaneIsItsSigma) {
  std::mt19937 rng{11};
  for (const double sigma : {0.0003, 0.001, 0.0025}) {  // 0.0025: past the fixed 4 mm edge limit
    std::normal_distribution<float> noise(0.f, static_cast<float>(sigma));
    DepthImage depth(640, 480);
    for (int v = 0; v < depth.height; ++v) {
      for (int u = 0; u < depth.width; ++u) depth.at(u, v) = 0.9f + 0.0002f * static_cast<float>(u) + noise(rng);
    }
    const auto [measured, at] = MeasureDepthNoise(depth);
    EXPECT_NEAR(measured, sigma, 0.1 * sigma);
    EXPECT_NEAR(at, 0.964, 0.01);
  }
  // Too few valid pixels: no figure.
  EXPECT_EQ(MeasureDepthNoise(DepthImage(20, 20, std::numeric_limits<float>::quiet_NaN())).first, 0.0);
}

// A frame of a tilted plane with a 20 mm step at u = 320 and a hole, axial
// noise sigma (metres), seeded.
Frame NoisyStepFrame(double sigma, uint32_t seed) {
  std::mt19937 rng{seed};
  std::normal_distribution<float> noise(0.f, static_cast<float>(sigma));
  Frame frame;
  frame.intrinsics = DefaultCamera().K;
  frame.depth = DepthImage(640, 480);
  for (int v = 0; v < 480; ++v) {
    for (int u = 0; u < 640; ++u) {
      const float clean = 0.9f + 0.0001f * static_cast<float>(v) + (u < 320 ? 0.f : 0.02f);
      frame.depth.at(u, v) = clean + noise(rng);
    }
  }
  for (int v = 100; v < 110; ++v) {
    for (int u = 100; u < 110; ++u) frame.depth.at(u, v) = std::numeric_limits<float>::quiet_NaN();
  }
  return frame;
}

// Smoothing a 1 mm noisy plane over 3 x 3 pixels (radius 1) divides its noise
// by about 3 away from the step; the pixels beside the 20 mm step keep their
// own side's depth (the gate keeps the other side out); the hole stays a
// hole and nothing else becomes one; the result does not depend on the
// number of threads.
TEST(DepthSmoothing, NoiseIsDividedByTheWindowAndAStepIsKept) {
  const double sigma = 0.001;
  const Frame frame = NoisyStepFrame(sigma, 3);
  const DepthNoise noise(CameraSpec{}, frame);  // no noise model: the measured sigma
  ASSERT_NEAR(noise.Sigma(0.9), sigma, 0.1 * sigma);
  DepthImage smoothed;
  tbb::task_arena(2).execute([&] { smoothed = SmoothDepth(frame.depth, 1, noise, 2.0); });
  DepthImage one_thread;
  tbb::task_arena(1).execute([&] { one_thread = SmoothDepth(frame.depth, 1, noise, 2.0); });
  ASSERT_EQ(smoothed.data.size(), one_thread.data.size());
  EXPECT_EQ(std::memcmp(smoothed.data.data(), one_thread.data.data(), smoothed.data.size() * sizeof(float)), 0);

  double sum_sq = 0.0;
  int n = 0;
  double worst_beside_step = 0.0;
  for (int v = 1; v + 1 < 480; ++v) {
    for (int u = 1; u + 1 < 640; ++u) {
      const float z = smoothed.at(u, v);
      const bool in_hole = u >= 100 && u < 110 && v >= 100 && v < 110;
      ASSERT_EQ(std::isfinite(z), !in_hole) << u << ", " << v;
      if (in_hole) continue;
      const float clean = 0.9f + 0.0001f * static_cast<float>(v) + (u < 320 ? 0.f : 0.02f);
      if (u == 319 || u == 320) worst_beside_step = std::max(worst_beside_step, std::abs(double(z - clean)));
      if (std::abs(u - 320) > 2 && (u < 98 || u > 111 || v < 98 || v > 111)) {
        sum_sq += double(z - clean) * double(z - clean);
        ++n;
      }
    }
  }
  const double rms = std::sqrt(sum_sq / n);
  EXPECT_LT(rms, 0.45 * sigma);
  EXPECT_GT(rms, 0.25 * sigma);
  EXPECT_LT(worst_beside_step, 3 * sigma);  // averaged across the step: a third of it, 6.7 mm
}

// The window's half width: the smallest that brings the frame's noise down
// to the target (r = ceil((sigma / target - 1) / 2)), at most max_radius;
// none for a frame already below the target or without a target.
TEST(DepthSmoothing, TheRadiusIsTheSmallestThatReachesTheTarget) {
  const auto radius = [](double sigma, double target, int max_radius) {
    return SmoothingRadius(DepthNoise(CameraSpec{}, NoisyStepFrame(sigma, 5)), target, max_radius);
  };
  EXPECT_EQ(radius(0.0003, 0.0005, 2), 0);
  EXPECT_EQ(radius(0.0013, 0.0005, 2), 1);  // 2.6 x the target
  EXPECT_EQ(radius(0.003, 0.0005, 5), 3);   // 6 x
  EXPECT_EQ(radius(0.003, 0.0005, 2), 2);
  EXPECT_EQ(radius(0.003, 0.0, 2), 0);
  EXPECT_EQ(radius(0.003, 0.0005, 0), 0);
  EXPECT_EQ(SmoothingRadius(DepthNoise(), 0.0005, 2), 0);  // no noise figure
}

// The model tables of a 60 x 40 x 20 mm block: six faces, six resting
// orientations, no holes; verification scores its true pose near 1, a pose
// 10 mm off lower, a pose sunk into the support plane below it.
// The test block turned 0.3 rad about z on the bin floor, rendered by the
// default camera, as a view (`support_plane` set: the floor) and its
// support index for Verify.
struct BlockView {
  BlockView(const PoseModel& m, bool support_plane) : scene(Render({{&block, X_BO}}, cam, 0.0002, 5)) {
    view.points_B = scene.points_B;
    view.X_BC = cam.X_BC;
    view.depth = &scene.depth;
    view.intrinsics = cam.K;
    if (support_plane) view.support_plane_B = Eigen::Vector4d(0, 0, 1, 0);
    support.Build(scene.points_B, 2.f * static_cast<float>(m.options.support_distance), view);
  }
  static inline const TriangleMesh block = testing::MakeTestBlock();
  const TestCamera cam = DefaultCamera();
  const Pose X_BO = MakePose(Mat3(Eigen::AngleAxisd(0.3, Vec3::UnitZ())), Vec3(0.01, 0.0, 0.01));
  RenderedScene scene;
  SceneView view;
  SceneSupport support;
};

TEST(PoseModelTables, ABlockHasSixFacesAndRestsOnEachAndItsTruePoseVerifiesBest) {
  auto estimator = PoseEstimator::Build(BlockView::block, Symmetry{});
  ASSERT_TRUE(estimator.ok());
  const PoseModel& m = PoseEstimatorAccess::Model(**estimator);
  EXPECT_EQ(m.faces.size(), 6u);
  EXPECT_TRUE(m.holes.empty());
  ASSERT_EQ(m.rests.size(), 6u);
  for (const RestingPose& r : m.rests) EXPECT_NEAR(r.down.cwiseAbs().maxCoeff(), 1.f, 1e-3f);

  const BlockView bv(m, /*support_plane=*/true);
  const SceneView& view = bv.view;
  const SceneSupport& support = bv.support;
  const Pose& X_BO = bv.X_BO;
  const VerifyStats at_truth = Verify(m, X_BO, view, support, SegmentDepth{});
  EXPECT_GT(at_truth.score, 0.95);
  EXPECT_GT(at_truth.visible, 50);
  const Pose off = MakePose(X_BO.linear(), X_BO.translation() + Vec3(0.0, 0.01, 0));
  EXPECT_LT(Verify(m, off, view, support, SegmentDepth{}).score, at_truth.score - 0.1);
  const Pose sunk = MakePose(X_BO.linear(), X_BO.translation() - Vec3(0, 0, 0.01));
  EXPECT_TRUE(Verify(m, sunk, view, support, SegmentDepth{}).below_support);
}

// Verify with a bar (what the pose search passes where only a pose above
// its bar is of use, pipeline/internal/pose_search.cc): over poses
// from the true one to far off, at strides 1 and 3 and bars across the
// scores, a pose it does not cut short has the figures of the full test,
// and one it cuts short scores below the bar in full, its reported score
// (the bound) at least the full one. Some of each are asserted to occur.
TEST(PoseModelTables, VerifyWithABarCutsShortOnlyPosesBelowItAndKeepsTheOthersExact) {
  auto estimator = PoseEstimator::Build(BlockView::block, Symmetry{});
  ASSERT_TRUE(estimator.ok());
  const PoseModel& m = PoseEstimatorAccess::Model(**estimator);
  const BlockView bv(m, /*support_plane=*/false);
  const SceneView& view = bv.view;
  const SceneSupport& support = bv.support;
  const Pose& X_BO = bv.X_BO;
  int cut = 0, kept = 0;
  for (int k = 0; k < 12; ++k) {
    const Mat3 turn(Eigen::AngleAxisd(0.12 * k, Vec3(0.3, 1.0, 0.2).normalized()));
    const Pose X = MakePose(turn * X_BO.linear(), X_BO.translation() + Vec3(0.0015 * k, -0.001 * k, 0.0));
    for (const int stride : {1, 3}) {
      for (const bool unmeasured : {false, true}) {
        const VerifyStats full = Verify(m, X, view, support, SegmentDepth{}, stride, unmeasured);
        ASSERT_FALSE(full.cut_short);
        for (const double bar : {0.2, 0.36, 0.6, 0.9}) {
          const VerifyStats b = Verify(m, X, view, support, SegmentDepth{}, stride, unmeasured, bar);
          if (b.cut_short) {
            ++cut;
            EXPECT_LT(full.score, bar) << "k " << k << " stride " << stride << " bar " << bar;
            EXPECT_LT(b.score, bar);
            EXPECT_GE(b.score, full.score - 1e-12);
          } else {
            ++kept;
            EXPECT_EQ(b.score, full.score);
            EXPECT_EQ(b.visible, full.visible);
            EXPECT_EQ(b.occluded, full.occluded);
            EXPECT_EQ(b.supported, full.supported);
            EXPECT_EQ(b.free_space, full.free_space);
            EXPECT_EQ(b.unmeasured, full.unmeasured);
          }
        }
      }
    }
  }
  EXPECT_GT(cut, 10);
  EXPECT_GT(kept, 10);
}

}  // namespace
}  // namespace bp::internal
