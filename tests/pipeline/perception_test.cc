// The perception pipeline (pipeline/perception.h) on rendered scenes of the
// default cell's parts: ROI counts, bad input, segmentation, detections, and a
// short evaluation run (pipeline/evaluation.h).
#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <functional>
#include <initializer_list>
#include <limits>
#include <map>
#include <memory>
#include <random>
#include <set>
#include <vector>

#include <tbb/task_arena.h>

#include "core/mesh.h"
#include "core/mesh_gen.h"
#include "pipeline/evaluation.h"
#include "pipeline/frame_io.h"
#include "pipeline/internal/class_model.h"
#include "pipeline/perception.h"
#include "pipeline/renderer.h"
#include "pipeline/synthetic_source.h"

namespace bp {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;

Pose PoseW(double x, double y, double z, double yaw_deg, double roll_deg = 0.0) {
  return MakePose(Mat3(Eigen::AngleAxisd(yaw_deg * kDeg, Vec3::UnitZ()) *
                       Eigen::AngleAxisd(roll_deg * kDeg, Vec3::UnitX())),
                  Vec3(x, y, z));
}

// Shared, built once: the default cell, its part meshes, a renderer and the pipeline.
struct Fixture {
  Cell cell;
  std::vector<std::shared_ptr<const TriangleMesh>> meshes;  // bin, then the parts by class id
  std::unique_ptr<DepthRenderer> renderer;
  std::unique_ptr<Perception> perception;
  std::vector<EvalPartModel> models;

  static Fixture& Get() {
    static Fixture* f = [] {
      auto* fx = new Fixture;
      fx->cell = *LoadDefaultCell();
      fx->meshes.push_back(std::make_shared<TriangleMesh>(MakeBinMesh(fx->cell.bin)));
      for (const PartSpec& p : fx->cell.parts) fx->meshes.push_back(std::make_shared<TriangleMesh>(*LoadMesh(p.mesh)));
      auto r = MakeOsMesaRenderer();
      if (r.ok()) fx->renderer = std::move(*r);
      fx->perception = Perception::Build(fx->cell).value();
      fx->models = LoadEvalModels(fx->cell).value();
      return fx;
    }();
    return *f;
  }

  // Renders the bin and parts (class id, X_WO) through camera config 1, with
  // Gaussian depth noise of sigma metres.
  Frame Render(const std::vector<std::pair<int, Pose>>& parts_W, double sigma = 0.0003, uint64_t seed = 1) const {
    RenderScene scene;
    scene.meshes = meshes;
    scene.instances.push_back({0, Pose::Identity(), GroundTruth::kBinLabel});
    Frame frame;
    frame.X_BC = cell.camera.X_BC;
    frame.truth = GroundTruth{};
    for (size_t i = 0; i < parts_W.size(); ++i) {
      scene.instances.push_back({static_cast<size_t>(parts_W[i].first) + 1, parts_W[i].second,
                                 static_cast<uint16_t>(i + 1)});
      PartTruth t;
      t.instance_id = static_cast<int>(i + 1);
      t.class_id = parts_W[i].first;
      t.X_BO = cell.bin.X_BW * parts_W[i].second;
      t.visible_fraction = 1.0;
      frame.truth->parts.push_back(t);
    }
    const Intrinsics& K = cell.camera.FindConfig(1)->intrinsics;
    auto out = renderer->Render(scene, K, cell.bin.X_BW.inverse() * cell.camera.X_BC);
    EXPECT_TRUE(out.ok()) << out.status().ToString();
    std::mt19937 rng(static_cast<uint32_t>(seed));
    std::normal_distribution<float> noise(0.f, static_cast<float>(sigma));
    for (float& z : out->depth.data) {
      if (std::isfinite(z)) z += noise(rng);
    }
    frame.depth = std::move(out->depth);
    frame.truth->labels = std::move(out->labels);
    frame.intrinsics = K;
    return frame;
  }

  // The cell's synthetic pile of seed `seed`, as the synthetic source captures it.
  Frame Pile(uint64_t seed) const {
    Cell c = cell;
    c.source.seed = seed;
    auto source = MakeSyntheticSource(c);
    EXPECT_TRUE(source.ok()) << source.status().ToString();
    auto frame = (*source)->Capture({});
    EXPECT_TRUE(frame.ok()) << frame.status().ToString();
    return std::move(*frame);
  }

  PerceptionResult Run(const Frame& frame, const std::vector<int>& classes = {},
                       PerceptionEffort effort = PerceptionEffort::kNormal) const {
    return RunWith(*perception, frame, classes, effort);
  }
  // The same with another pipeline (other options), on a 2-thread arena.
  static PerceptionResult RunWith(const Perception& p, const Frame& frame, const std::vector<int>& classes = {},
                                  PerceptionEffort effort = PerceptionEffort::kNormal) {
    tbb::task_arena arena(2);
    Result<PerceptionResult> r = Status::Internal("not run");
    arena.execute([&] { r = p.Run(frame, classes, effort); });
    EXPECT_TRUE(r.ok()) << r.status().ToString();
    return r.ok() ? *r : PerceptionResult{};
  }
};

class PerceptionTest : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!Fixture::Get().renderer) GTEST_SKIP() << "no OSMesa renderer";
  }
  Fixture& fx() { return Fixture::Get(); }
  // Renders one L-bracket at X_WO; a thorough run finds it, and only it,
  // within 2 mm / 2 deg.
  void ExpectThoroughRunFindsTheBracket(const Pose& X_WO) {
    ExpectThoroughRunFindsTheBracket(fx().Render({{1, X_WO}}), X_WO, 0.002, 2.0);
  }
  // The same on a given frame of one L-bracket at X_WO, within the given tolerances.
  void ExpectThoroughRunFindsTheBracket(const Frame& frame, const Pose& X_WO, double max_m, double max_deg) {
    const PerceptionResult r = fx().Run(frame, {}, PerceptionEffort::kThorough);
    ASSERT_EQ(r.detections.size(), 1u) << r.reason;
    EXPECT_EQ(r.detections[0].class_id, 1);
    const Pose X_BO = fx().cell.bin.X_BW * X_WO;
    EXPECT_LT((r.detections[0].X_BO.translation() - X_BO.translation()).norm(), max_m);
    EXPECT_LT(Eigen::AngleAxisd(r.detections[0].X_BO.linear().transpose() * X_BO.linear()).angle(), max_deg * kDeg);
  }
};

int32_t NearestPoint(const PerceptionResult& r, const Vec3& p_B) {
  int32_t best = -1;
  double best_d = 1e9;
  for (size_t i = 0; i < r.roi_points_B.size(); ++i) {
    const double d = (r.roi_points_B[i].cast<double>() - p_B).norm();
    if (d < best_d) {
      best_d = d;
      best = static_cast<int32_t>(i);
    }
  }
  return best;
}

TEST_F(PerceptionTest, EmptyBinGivesNoDetectionsAndASmallLargestRegion) {
  const Frame frame = fx().Render({});
  const PerceptionResult r = fx().Run(frame);
  EXPECT_TRUE(r.detections.empty());
  EXPECT_FALSE(r.reason.empty());
  EXPECT_LT(r.largest_region_points, 50);
  EXPECT_LT(r.roi_point_count, 200) << "floor noise above floor_margin";
  EXPECT_EQ(r.roi_point_count, static_cast<int64_t>(r.roi_points_B.size()));
}

TEST_F(PerceptionTest, AllNanFrameGivesNoDetectionsAndAReason) {
  Frame frame = fx().Render({});
  std::fill(frame.depth.data.begin(), frame.depth.data.end(), std::numeric_limits<float>::quiet_NaN());
  const PerceptionResult r = fx().Run(frame);
  EXPECT_TRUE(r.detections.empty());
  EXPECT_EQ(r.roi_point_count, 0);
  EXPECT_NE(r.reason.find("no valid points"), std::string::npos) << r.reason;

  Frame cloud;
  cloud.points_C.assign(1000, Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN()));
  const PerceptionResult rc = fx().Run(cloud);
  EXPECT_TRUE(rc.detections.empty());
  EXPECT_NE(rc.reason.find("no valid points"), std::string::npos) << rc.reason;
}

TEST_F(PerceptionTest, PointsOutsideTheRoiGiveAnEmptyRoiReason) {
  Frame frame;
  frame.X_BC = fx().cell.camera.X_BC;
  frame.points_C.assign(500, Eigen::Vector3f(0.f, 0.f, 0.2f));  // 0.85 m above the floor
  const PerceptionResult r = fx().Run(frame);
  EXPECT_TRUE(r.detections.empty());
  EXPECT_EQ(r.roi_point_count, 0);
  EXPECT_NE(r.reason.find("ROI is empty"), std::string::npos) << r.reason;
}

// 5000 points scattered uniformly through the ROI, organized (one pixel each)
// and unorganized: lots of ROI points, no large connected region.
TEST_F(PerceptionTest, ScatteredNoisePointsDoNotFormALargeRegion) {
  const Cell& cell = fx().cell;
  const Intrinsics K = cell.camera.FindConfig(1)->intrinsics;
  std::mt19937 rng(42);
  const Vec3 half = 0.5 * cell.bin.inner_size;
  std::uniform_real_distribution<double> ux(-half.x() + 0.01, half.x() - 0.01), uy(-half.y() + 0.01, half.y() - 0.01),
      uz(0.005, 0.2);
  Frame organized;
  organized.X_BC = cell.camera.X_BC;
  organized.intrinsics = K;
  organized.depth = DepthImage(K.width, K.height, std::numeric_limits<float>::quiet_NaN());
  Frame cloud;
  cloud.X_BC = cell.camera.X_BC;
  const Pose X_CW = cell.camera.X_BC.inverse() * cell.bin.X_BW;
  for (int i = 0; i < 5000; ++i) {
    const Vec3 p_C = X_CW * Vec3(ux(rng), uy(rng), uz(rng));
    cloud.points_C.push_back(p_C.cast<float>());
    const int u = static_cast<int>(std::lround(K.fx * p_C.x() / p_C.z() + K.cx));
    const int v = static_cast<int>(std::lround(K.fy * p_C.y() / p_C.z() + K.cy));
    if (u >= 0 && v >= 0 && u < K.width && v < K.height) organized.depth.at(u, v) = static_cast<float>(p_C.z());
  }
  for (const Frame* frame : {&organized, &cloud}) {
    const PerceptionResult r = fx().Run(*frame);
    EXPECT_GT(r.roi_point_count, 4000);
    EXPECT_LT(r.largest_region_points, 30);
    EXPECT_TRUE(r.detections.empty());
  }
}

TEST_F(PerceptionTest, StackedPartsFallIntoDifferentSegments) {
  // A bushing standing on an L bracket's base plate (5 mm thick).
  const Frame frame = fx().Render({{1, PoseW(-0.05, 0.0, 0.0, 0.0)}, {0, PoseW(0.0, 0.0, 0.005, 0.0)}});
  const PerceptionResult r = fx().Run(frame);
  const Pose& X_BW = fx().cell.bin.X_BW;
  const int32_t on_hub = NearestPoint(r, X_BW * Vec3(0.0, 0.014, 0.045));
  const int32_t on_base = NearestPoint(r, X_BW * Vec3(-0.038, 0.0, 0.005));
  ASSERT_GE(on_hub, 0);
  ASSERT_GE(on_base, 0);
  EXPECT_GE(r.segment_of_point[static_cast<size_t>(on_hub)], 0);
  EXPECT_GE(r.segment_of_point[static_cast<size_t>(on_base)], 0);
  EXPECT_NE(r.segment_of_point[static_cast<size_t>(on_hub)], r.segment_of_point[static_cast<size_t>(on_base)]);
}

TEST(PerceptionEvaluation, SymmetricPartErrorIsMeasuredModuloItsSymmetry) {
  Symmetry revolute;
  revolute.kind = Symmetry::Kind::kRevolute;
  Symmetry tee;
  tee.kind = Symmetry::Kind::kDiscrete;
  tee.order = 2;
  const Symmetry none;
  const Pose X = PoseW(0.7, 0.1, 0.05, 20.0, 10.0);
  const auto about_z = [&](double deg) { return X * PoseW(0, 0, 0, deg); };
  EXPECT_NEAR(SymmetryAwareRotationError(about_z(70), X, revolute), 0.0, 1e-9);
  EXPECT_NEAR(SymmetryAwareRotationError(about_z(180), X, tee), 0.0, 1e-9);
  EXPECT_NEAR(SymmetryAwareRotationError(about_z(90), X, tee), 90 * kDeg, 1e-9);
  EXPECT_NEAR(SymmetryAwareRotationError(about_z(180), X, none), kPi, 1e-9);
  // A tilt of the axis is an error for every symmetry.
  const Pose tilted = X * PoseW(0, 0, 0, 0, 3.0);
  EXPECT_NEAR(SymmetryAwareRotationError(tilted, X, revolute), 3 * kDeg, 1e-9);
  EXPECT_NEAR(SymmetryAwareRotationError(tilted, X, tee), 3 * kDeg, 1e-9);
  Symmetry flip = tee;  // a 180 degree flip about x with a 1 cm offset
  flip.extra.push_back(MakePose(Mat3(Eigen::AngleAxisd(kPi, Vec3::UnitX())), Vec3(0.0, 0.0, 0.01)));
  const Pose flipped = X * flip.extra[0];
  EXPECT_NEAR(SymmetryAwareRotationError(flipped, X, flip), 0.0, 1e-9);
  EXPECT_GT(SymmetryAwareRotationError(flipped, X, tee), 170 * kDeg);
}

// The default cell's evaluation models, and ground truth holding a fully
// visible bushing (instance 1) at x = 0.7 m and L-bracket (2) at x = 0.8 m.
struct EvalScene {
  std::vector<EvalPartModel> models;
  GroundTruth truth;
};
void MakeBushingAndBracket(EvalScene* scene) {
  auto cell = LoadDefaultCell();
  ASSERT_TRUE(cell.ok());
  auto models = LoadEvalModels(*cell);
  ASSERT_TRUE(models.ok()) << models.status().ToString();
  scene->models = std::move(*models);
  scene->truth.parts.push_back({1, 0, "flanged_bushing", PoseW(0.7, 0, 0.05, 0), 100, 100, 1.0});
  scene->truth.parts.push_back({2, 1, "l_bracket", PoseW(0.8, 0, 0.05, 0), 100, 100, 1.0});
}

TEST(PerceptionEvaluation, MatchesDetectionsToTruthByClassAndDistance) {
  EvalScene scene;
  ASSERT_NO_FATAL_FAILURE(MakeBushingAndBracket(&scene));
  GroundTruth& truth = scene.truth;
  const std::vector<EvalPartModel>& models = scene.models;
  truth.parts.push_back({3, 2, "pipe_tee", PoseW(0.6, 0, 0.05, 0), 10, 100, 0.1});  // not a target
  PerceptionResult result;
  result.detections.push_back({0, PoseW(0.7005, 0, 0.05, 33), 0.9, 1.0, 0.0, {}});  // revolute: yaw is free
  result.detections.push_back({2, PoseW(0.8, 0, 0.05, 0), 0.8, 1.0, 0.0, {}});      // wrong class
  result.detections.push_back({2, PoseW(0.6, 0, 0.05, 180), 0.7, 1.0, 0.0, {}});    // tee, symmetric turn
  const FrameEvaluation fe = EvaluateFrame(result, truth, models);
  ASSERT_EQ(fe.detections.size(), 3u);
  EXPECT_EQ(fe.detections[0].truth_instance, 1);
  EXPECT_NEAR(fe.detections[0].translation_error, 0.0005, 1e-9);
  EXPECT_NEAR(fe.detections[0].rotation_error, 0.0, 1e-9);
  EXPECT_TRUE(fe.detections[0].adds_ok);
  EXPECT_EQ(fe.detections[1].truth_instance, -1);
  EXPECT_EQ(fe.detections[2].truth_instance, 3);
  EXPECT_FALSE(fe.detections[2].target);
  EXPECT_NEAR(fe.detections[2].rotation_error, 0.0, 1e-9);
  const EvalReport report = Summarize({fe}, models);
  const ClassFigures& all = report.classes.back();
  EXPECT_EQ(all.name, "all");
  EXPECT_EQ(all.targets, 2);
  EXPECT_EQ(all.found, 1);
  EXPECT_DOUBLE_EQ(all.recall, 0.5);
  EXPECT_NEAR(all.precision, 2.0 / 3.0, 1e-12);
}

TEST(PerceptionEvaluation, OutcomesAreInScoreOrderAndNameTheirDetection) {
  EvalScene scene;
  ASSERT_NO_FATAL_FAILURE(MakeBushingAndBracket(&scene));
  PerceptionResult result;
  result.detections.push_back({0, PoseW(0.5, 0, 0.05, 0), 0.75, 1.0, 0.0, {}});  // nothing there
  result.detections.push_back({1, PoseW(0.8, 0, 0.05, 0), 0.95, 1.0, 0.0, {}});  // the bracket
  result.detections.push_back({0, PoseW(0.7, 0, 0.05, 0), 0.85, 1.0, 0.0, {}});  // the bushing
  const FrameEvaluation fe = EvaluateFrame(result, scene.truth, scene.models);
  ASSERT_EQ(fe.detections.size(), 3u);
  EXPECT_EQ(fe.detections[0].detection, 1u);
  EXPECT_EQ(fe.detections[0].truth_instance, 2);
  EXPECT_EQ(fe.detections[1].detection, 2u);
  EXPECT_EQ(fe.detections[1].truth_instance, 1);
  EXPECT_EQ(fe.detections[2].detection, 0u);
  EXPECT_EQ(fe.detections[2].truth_instance, -1);
}

TEST_F(PerceptionTest, ReportsTheBinMeasuredAtCaptureInsteadOfMeasuringAgain) {
  // A `required` capture measured the bin already (grasp/bin_picking_planner.cc):
  // perception reports that detection, here marked 4 mm off the true bin.
  Frame frame = fx().Render({});
  BinDetection at_capture;
  at_capture.found = true;
  at_capture.X_BW = fx().cell.bin.X_BW * MakePose(Mat3::Identity(), Vec3(0.004, 0, 0));
  at_capture.ms = 1.25;
  frame.bin = std::make_shared<const BinDetection>(at_capture);
  const PerceptionResult r = fx().Run(frame);
  ASSERT_TRUE(r.bin.has_value());
  EXPECT_EQ(r.bin->X_BW.matrix(), at_capture.X_BW.matrix());
  ASSERT_FALSE(r.timings.empty());
  EXPECT_EQ(r.timings[0].stage, "bin");
  EXPECT_EQ(r.timings[0].ms, 1.25);
  // Without it, the stage measures the bin where it truly is.
  frame.bin = nullptr;
  const PerceptionResult measured = fx().Run(frame);
  ASSERT_TRUE(measured.bin.has_value());
  ASSERT_TRUE(measured.bin->found) << measured.bin->reason;
  EXPECT_LT((measured.bin->X_BW.translation() - fx().cell.bin.X_BW.translation()).norm(), 0.0005);
}

TEST_F(PerceptionTest, FindsASinglePartWithinHalfAMillimetreAndHalfADegree) {
  // Tilted so that every face constrains the pose (a flat-lying bracket shows
  // its upright only edge-on).
  const Pose X_WO = PoseW(0.03, -0.02, 0.03, 30.0, 25.0);
  const Frame frame = fx().Render({{1, X_WO}});
  const PerceptionResult r = fx().Run(frame);
  ASSERT_EQ(r.detections.size(), 1u) << r.reason;
  const Detection& d = r.detections[0];
  EXPECT_EQ(d.class_id, 1);
  const Pose X_BO = fx().cell.bin.X_BW * X_WO;
  EXPECT_LT((d.X_BO.translation() - X_BO.translation()).norm(), 0.0005);
  EXPECT_LT(SymmetryAwareRotationError(d.X_BO, X_BO, fx().cell.parts[1].symmetry), 0.5 * kDeg);
  EXPECT_GT(d.score, 0.5);
  EXPECT_GT(d.visible_fraction, 0.8);
  EXPECT_GT(d.support.size(), 100u);
  for (int32_t i : d.support) ASSERT_LT(static_cast<size_t>(i), r.roi_points_B.size());
  std::vector<std::string> stages;
  for (const StageTiming& t : r.timings) stages.push_back(t.stage);
  EXPECT_EQ(stages,
            (std::vector<std::string>{"bin", "roi", "regions", "segment", "pose", "verify", "second_look", "residual",
                                      "residual_regions", "enclosing", "own_turns"}));
}

// A clock for PerceptionBudget that advances 1 ms at every reading: an
// estimate admitted at t finishes at t + 1 (the gate reads the clock once
// before and once after it), so on one thread the k-th admitted estimate
// (k >= 1) is admitted at 2k only while 2k + 1 <= deadline.
struct TickClock {
  std::shared_ptr<std::atomic<int>> ticks = std::make_shared<std::atomic<int>>(0);
  PerceptionBudget Budget(double deadline_ms) const {
    return {deadline_ms, [t = ticks] { return static_cast<double>((*t)++); }};
  }
};

PerceptionResult RunThoroughOnOneThread(const Frame& frame, const PerceptionBudget& budget) {
  tbb::task_arena arena(1);
  Result<PerceptionResult> r = Status::Internal("not run");
  arena.execute([&] { r = Fixture::Get().perception->RunThorough(frame, {}, budget); });
  EXPECT_TRUE(r.ok()) << r.status().ToString();
  return r.ok() ? *r : PerceptionResult{};
}

TEST_F(PerceptionTest, AThoroughRunStartsNoEstimateItsBudgetDoesNotCover) {
  const Frame frame = fx().Pile(3);
  // Deadline 9: estimates admitted at 0, 2, 4, 6, 8 (each ending 1 later, by
  // 9); every later one is skipped.
  TickClock clock;
  const PerceptionResult r = RunThoroughOnOneThread(frame, clock.Budget(9.0));
  EXPECT_EQ(r.estimator_calls, 5);
  EXPECT_GT(r.estimates_skipped, 0);
  EXPECT_TRUE(r.budget_exhausted());
  // Nothing left: no estimate at all, and the reason says why.
  TickClock none;
  const PerceptionResult empty = RunThoroughOnOneThread(frame, none.Budget(-1.0));
  EXPECT_EQ(empty.estimator_calls, 0);
  EXPECT_TRUE(empty.detections.empty());
  EXPECT_NE(empty.reason.find("budget used"), std::string::npos) << empty.reason;
}

TEST_F(PerceptionTest, AThoroughRunSpendsASmallBudgetOnTheViewsMostLikelyToHoldAPart) {
  // A pile, and a budget of the first 8 estimates: started on the largest
  // views that best fit a class, they find parts.
  TickClock clock;
  const PerceptionResult r = RunThoroughOnOneThread(fx().Pile(3), clock.Budget(15.0));
  EXPECT_EQ(r.estimator_calls, 8);
  EXPECT_FALSE(r.detections.empty()) << r.reason;
}

TEST_F(PerceptionTest, AThoroughRunWithinItsBudgetFindsWhatAnUnboundedOneFinds) {
  const Frame frame = fx().Render({{1, PoseW(0.03, -0.02, 0.0, 30.0)}, {2, PoseW(-0.05, 0.04, 0.04, 100.0, 60.0)}});
  const PerceptionResult unbounded = fx().Run(frame, {}, PerceptionEffort::kThorough);
  TickClock clock;
  const PerceptionResult bounded = RunThoroughOnOneThread(frame, clock.Budget(1e9));
  EXPECT_EQ(bounded.estimates_skipped, 0);
  EXPECT_EQ(bounded.estimator_calls, unbounded.estimator_calls);
  ASSERT_EQ(bounded.detections.size(), unbounded.detections.size());
  for (size_t i = 0; i < bounded.detections.size(); ++i) {
    EXPECT_EQ(bounded.detections[i].class_id, unbounded.detections[i].class_id);
    EXPECT_LT((bounded.detections[i].X_BO.translation() - unbounded.detections[i].X_BO.translation()).norm(), 1e-4);
  }
}

// A budget in work units (PerceptionBudget::max_estimates): the first N
// estimates in start order run, whatever the clock says (under a far
// deadline) and however many threads run them, so which parts a retry finds
// does not depend on the machine's load.
TEST_F(PerceptionTest, ACountBudgetStartsTheSameEstimatesWhateverTheClockAndTheThreads) {
  const Frame frame = fx().Pile(3);
  const PerceptionResult unbounded = fx().Run(frame, {}, PerceptionEffort::kThorough);
  auto run = [&](int threads, double ms_per_reading) {
    auto ticks = std::make_shared<std::atomic<int>>(0);
    PerceptionBudget budget{1e9, [ticks, ms_per_reading] { return ms_per_reading * (*ticks)++; }, 5};
    tbb::task_arena arena(threads);
    Result<PerceptionResult> r = Status::Internal("not run");
    arena.execute([&] { r = fx().perception->RunThorough(frame, {}, budget); });
    EXPECT_TRUE(r.ok()) << r.status().ToString();
    return r.ok() ? *r : PerceptionResult{};
  };
  const PerceptionResult fast = run(1, 1.0), slow = run(2, 1e5);
  // The first 5 ranked estimates, and the fallback classes of views all of
  // whose ranked ones were within the count; the rest is skipped.
  EXPECT_GE(fast.estimator_calls, 5);
  EXPECT_LT(fast.estimator_calls, unbounded.estimator_calls);
  EXPECT_GT(fast.estimates_skipped, 0);
  EXPECT_FALSE(fast.detections.empty()) << fast.reason;
  EXPECT_EQ(slow.estimator_calls, fast.estimator_calls);
  EXPECT_EQ(slow.estimates_skipped, fast.estimates_skipped);
  ASSERT_EQ(slow.detections.size(), fast.detections.size());
  for (size_t i = 0; i < fast.detections.size(); ++i) {
    EXPECT_EQ(slow.detections[i].class_id, fast.detections[i].class_id);
    EXPECT_LT((slow.detections[i].X_BO.translation() - fast.detections[i].X_BO.translation()).norm(), 1e-6);
  }
}

// The last part of seed 000's and seed 003's default bin (scene 1): a pipe
// tee standing on its branch, alone on the floor. From above its branch is
// hidden under its run: a half cylinder 5 cm over the floor. In the run's
// frames (grazing dropout, projector shadow) only the thorough search's
// resting seeds explained it, and the planner's retry has a budget;
// the estimate that finds the tee must be the first it starts, even when
// the budget covers only one (it was the last, classes in model order).
TEST_F(PerceptionTest, ABudgetOfOneEstimateFindsALoneTeeStandingOnItsBranch) {
  // As the synthetic pile left it (truth of the seed 003 run's capture 57):
  // 2.9 deg off upright, its branch's rim on the floor.
  Mat3 R;
  R << 0.2587891, 0.9654236, 0.0313918,  //
      0.9654503, -0.2574947, -0.0400286,  //
      -0.0305613, 0.0406662, -0.9987053;
  const Pose X_WO =
      MakePose(Eigen::Quaterniond(R).normalized().toRotationMatrix(), Vec3(0.1677247, -0.0663363, 0.0510267));
  const Frame frame = fx().Render({{2, X_WO}});
  const Pose X_BO = fx().cell.bin.X_BW * X_WO;
  const Symmetry& symmetry = fx().cell.FindPart(2)->symmetry;
  auto expect_the_tee = [&](const PerceptionResult& r, const char* run) {
    ASSERT_EQ(r.detections.size(), 1u) << run << ": " << r.reason;
    EXPECT_EQ(r.detections[0].class_id, 2) << run;
    EXPECT_LT(SymmetricTranslationError(r.detections[0].X_BO, X_BO, symmetry), 0.005) << run;
    EXPECT_LT(SymmetricRotationError(r.detections[0].X_BO, X_BO, symmetry), 5 * kDeg) << run;
  };
  expect_the_tee(fx().Run(frame, {}, PerceptionEffort::kThorough), "unbounded");
  // Admitted at tick 0, finished at 1: the next admission (tick 2 + 1) is past 0.
  TickClock clock;
  const PerceptionResult one = RunThoroughOnOneThread(frame, clock.Budget(0.0));
  EXPECT_EQ(one.estimator_calls, 1);
  EXPECT_GT(one.estimates_skipped, 0);
  expect_the_tee(one, "one estimate");
}

TEST_F(PerceptionTest, ClassesArgumentRestrictsTheSearch) {
  const Frame frame = fx().Render({{1, PoseW(0.03, -0.02, 0.0, 30.0)}});
  const PerceptionResult r = fx().Run(frame, {0, 2});
  for (const Detection& d : r.detections) EXPECT_NE(d.class_id, 1);
  tbb::task_arena arena(2);
  Result<PerceptionResult> bad = Status::Internal("not run");
  arena.execute([&] { bad = fx().perception->Run(frame, {7}); });
  EXPECT_EQ(bad.status().code(), Status::Code::kInvalidArgument);
}

TEST_F(PerceptionTest, SymmetricPartIsFoundModuloItsSymmetry) {
  // A pipe tee turned 100 degrees about z, branch tilted 60 degrees.
  const Pose X_WO = PoseW(-0.05, 0.04, 0.04, 100.0, 60.0);
  const Frame frame = fx().Render({{2, X_WO}});
  const PerceptionResult r = fx().Run(frame);
  ASSERT_EQ(r.detections.size(), 1u) << r.reason;
  const Pose X_BO = fx().cell.bin.X_BW * X_WO;
  EXPECT_EQ(r.detections[0].class_id, 2);
  EXPECT_LT(SymmetryAwareTranslationError(r.detections[0].X_BO, X_BO, fx().cell.parts[2].symmetry), 0.0005);
  EXPECT_LT(SymmetryAwareRotationError(r.detections[0].X_BO, X_BO, fx().cell.parts[2].symmetry), 0.5 * kDeg);
}

// An L-bracket standing on the outer face of its upright, the base plate
// pointing up: the camera sees mostly one plane, which many placements of the
// model's plates explain as well, and the best-voted ones sink the rest of the
// part into the floor. A normal run finds none of these; the thorough run
// (several accumulator peaks per reference point, the first that stay above
// the floor, PpfMatchOptions::accept; and the resting-pose seeds) finds these
// three. Known gap: at yaw 200 deg it finds nothing (the part falls into two
// segments), at 290 deg it finds the bracket turned 180 deg, 65 mm off (the
// upright, flat on the floor, is 5 mm thick; docs/perception.md, "Thorough
// retry").
TEST_F(PerceptionTest, ThoroughRunFindsAnLBracketStandingOnItsUpright) {
  for (const double yaw : {0.0, 35.0, 110.0}) {
    SCOPED_TRACE("yaw " + std::to_string(yaw));
    // Part +x up: the upright's outer face (x = 0) rests on the floor.
    ExpectThoroughRunFindsTheBracket(PoseW(0.02, -0.03, 0.0, yaw) *
                                     MakePose(Mat3(Eigen::AngleAxisd(-90 * kDeg, Vec3::UnitY())), Vec3::Zero()));
  }
}

// An L-bracket lying on its side (part y up): from above, only its 5 mm
// edges and, at an angle, a side face. PPF voting alone finds nothing; the
// thorough run's resting-pose seeds (PoseSearch::resting_seeds) do.
TEST_F(PerceptionTest, ThoroughRunFindsAnLBracketLyingOnItsSide) {
  for (const double yaw : {0.0, 50.0, 125.0, 240.0}) {
    for (const double roll : {-90.0, 90.0}) {
      SCOPED_TRACE("yaw " + std::to_string(yaw) + ", roll " + std::to_string(roll));
      // Roll +90: part y up, its y = -25 mm face on the floor; -90: y down.
      ExpectThoroughRunFindsTheBracket(PoseW(-0.03, 0.02, 0.025, yaw) *
                                       MakePose(Mat3(Eigen::AngleAxisd(roll * kDeg, Vec3::UnitX())), Vec3::Zero()));
    }
  }
}

// The same away from the optical axis, where the camera also sees a side
// face and the segment's centre is not the top's: 24 poses 14-17 cm off axis.
// Before the resting directions were taken from the broad faces (a hole-wall
// facet 2.9 deg off had tilted the seeds) and the thorough search kept the
// better of the coarse and fine poses, the bracket was found at none of the
// yaws tried at x = 0.14. Then 20 of 24 within 5 mm / 4 deg, 12 within 2 mm
// / 2 deg (point-to-plane ICP slides a 5 mm edge along itself); since the
// thorough search counts unmeasured grazing points as no evidence, 24 and 24.
TEST_F(PerceptionTest, ThoroughRunFindsMostLBracketsLyingOnTheirSideOffTheOpticalAxis) {
  int found = 0, within_2mm = 0, poses = 0;
  for (const double x : {0.14, -0.17}) {
    for (const double y : {0.02, -0.1}) {
      for (const double yaw : {0.0, 120.0, 239.0}) {
        for (const double roll : {-90.0, 90.0}) {
          ++poses;
          const Pose X_WO =
              PoseW(x, y, 0.025, yaw) * MakePose(Mat3(Eigen::AngleAxisd(roll * kDeg, Vec3::UnitX())), Vec3::Zero());
          const PerceptionResult r = fx().Run(fx().Render({{1, X_WO}}), {}, PerceptionEffort::kThorough);
          const Pose X_BO = fx().cell.bin.X_BW * X_WO;
          for (const Detection& d : r.detections) {
            const double t = (d.X_BO.translation() - X_BO.translation()).norm();
            const double a = Eigen::AngleAxisd(d.X_BO.linear().transpose() * X_BO.linear()).angle();
            EXPECT_EQ(d.class_id, 1);
            if (d.class_id != 1 || t > 0.005 || a > 4 * kDeg) continue;
            ++found;
            within_2mm += t < 0.002 && a < 2 * kDeg;
          }
        }
      }
    }
  }
  std::printf("[          ] %d of %d found within 5 mm / 4 deg, %d within 2 mm / 2 deg\n", found, poses, within_2mm);
  EXPECT_GE(found, 22);
  EXPECT_GE(within_2mm, 20);
}

// An L-bracket alone on the floor, on its side and tilted 15 deg about its
// long axis (as a cleared bin left one): the normal condition cuts its 5 mm
// edges and side faces into pieces each below min_segment_points, though the
// part as a whole has several hundred points. The connected region is then
// matched as one segment.
TEST_F(PerceptionTest, AFragmentedLonePartIsMatchedAsOneSegment) {
  const TriangleMesh& bracket = *fx().meshes[2];
  // Measured in `binpick clear --seed 13`: z axis (-0.91, 0.32, 0.25), +y up.
  const Vec3 z = Vec3(-0.91, 0.32, 0.25).normalized();
  const Vec3 y = (Vec3::UnitZ() - z.z() * z).normalized();
  Mat3 R;
  R << y.cross(z), y, z;
  Pose X_WO = MakePose(R, Vec3(-0.138, 0.029, 0.0));
  double min_z = 1e9;
  for (const auto& v : bracket.vertices) min_z = std::min(min_z, (X_WO * v.cast<double>()).z());
  X_WO.translation().z() -= min_z;
  // A noisier sensor than the other tests' (0.8 mm): the normals of the
  // 5 mm edges scatter, and no piece reaches 150 points.
  const Frame frame = fx().Render({{1, X_WO}}, 0.0008);

  PerceptionOptions options;
  options.match_fragmented_regions = false;
  auto split = Perception::Build(fx().cell, options);
  ASSERT_TRUE(split.ok()) << split.status().ToString();
  const PerceptionResult without = Fixture::RunWith(**split, frame, {}, PerceptionEffort::kThorough);
  EXPECT_TRUE(without.detections.empty());
  EXPECT_NE(without.reason.find("no segment of at least"), std::string::npos) << without.reason;
  ASSERT_GT(without.largest_region_points, options.min_segment_points);

  ExpectThoroughRunFindsTheBracket(frame, X_WO, 0.005, 4.0);
}

// L-brackets lying alone on their side, tilted 11-13 deg, in the last frames
// of two scenes that `binpick clear --scenes 100 --seed 1 --fallback-task 4
// --save-left DIR` left unfinished (tests/pipeline/data: depth PNG at 0.1 mm,
// intrinsics, truth; the cell's sensor model with its projector shadow and
// grazing-angle dropout). Seed 80: the normal condition cuts the part into
// one piece above min_segment_points (226 grid points, about a quarter of
// the part) and smaller ones; only the connected region, pieces included,
// matches (PerceptionOptions::match_regions). Seed 36: 28% of the visible
// model surface falls on pixels without depth; the thorough search counts
// them as no evidence (PoseSearch::unmeasured_is_no_evidence), else the true
// pose scores about 0.7, at min_detection_score.
TEST_F(PerceptionTest, LoneLBracketsOnTheirSideInFramesAClearLeftAreFound) {
  const auto load = [](int seed) {
    const std::string path =
        std::string(BINPICK_SOURCE_DIR) + "/tests/pipeline/data/clear_seed" + std::to_string(seed) + "_depth.png";
    auto frame = LoadFrameFile(path);
    EXPECT_TRUE(frame.ok()) << frame.status().ToString();
    EXPECT_TRUE(frame->truth && frame->truth->parts.size() == 1u);
    return *frame;
  };
  const Frame f80 = load(80), f36 = load(36);
  for (const Frame* f : {&f80, &f36}) {
    const Pose X_WO = fx().cell.bin.X_BW.inverse() * f->truth->parts[0].X_BO;
    ExpectThoroughRunFindsTheBracket(*f, X_WO, 0.002, 2.0);
  }

  PerceptionOptions no_pieces;
  no_pieces.match_regions = false;
  auto without_pieces = Perception::Build(fx().cell, no_pieces);
  ASSERT_TRUE(without_pieces.ok()) << without_pieces.status().ToString();
  EXPECT_TRUE(Fixture::RunWith(**without_pieces, f80, {}, PerceptionEffort::kThorough).detections.empty());

  PerceptionOptions unmeasured_counts;
  unmeasured_counts.thorough_search.unmeasured_is_no_evidence = false;
  auto strict = Perception::Build(fx().cell, unmeasured_counts);
  ASSERT_TRUE(strict.ok()) << strict.status().ToString();
  // Without it the same frame gives the bracket a score near
  // min_detection_score (0.704 measured) instead of above 0.9.
  const PerceptionResult strict_run = Fixture::RunWith(**strict, f36, {}, PerceptionEffort::kThorough);
  const PerceptionResult run = fx().Run(f36, {}, PerceptionEffort::kThorough);
  ASSERT_EQ(run.detections.size(), 1u);
  EXPECT_GT(run.detections[0].score, 0.9);
  for (const Detection& d : strict_run.detections) EXPECT_LT(d.score, 0.75);
}

// L-brackets lying alone on their side in the last frames of two `--variety`
// scenes `binpick clear --scenes 90 --seed 2001 --variety --fallback-task 4
// --thorough-retry-ms 100000 --save-left DIR` answered EMPTY with the part
// left (tests/pipeline/data, seeds 2005 and 2024: 530 x 398 and 563 x 422
// pixels, 168 and 150 of the part's pixels measured). Their grid, a whole
// pixel apart, is coarser than the cell camera's (2.0-2.2 mm against
// 1.9 mm), so the part covers fewer grid points than a VGA frame gives it:
// counted at the same 150 points, no segment is left (largest connected
// region 145 and 133); counted as the same surface area
// (PerceptionOptions::min_segment_spacing) the thorough run finds them.
TEST_F(PerceptionTest, LBracketsOnTheirSideInCoarseVarietyFramesAreSegmentedAndFound) {
  for (const int seed : {2005, 2024}) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    const std::string path =
        std::string(BINPICK_SOURCE_DIR) + "/tests/pipeline/data/clear_seed" + std::to_string(seed) + "_depth.png";
    auto frame = LoadFrameFile(path);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    ASSERT_TRUE(frame->truth && frame->truth->parts.size() == 1u);
    ASSERT_EQ(frame->truth->parts[0].class_id, 1);

    PerceptionOptions fixed;
    fixed.min_segment_spacing = 0.0;
    auto same_count = Perception::Build(fx().cell, fixed);
    ASSERT_TRUE(same_count.ok()) << same_count.status().ToString();
    const PerceptionResult without = Fixture::RunWith(**same_count, *frame, {}, PerceptionEffort::kThorough);
    EXPECT_TRUE(without.detections.empty());
    EXPECT_NE(without.reason.find("no segment of at least 150 "), std::string::npos) << without.reason;

    const Pose X_WO = fx().cell.bin.X_BW.inverse() * frame->truth->parts[0].X_BO;
    ExpectThoroughRunFindsTheBracket(*frame, X_WO, 0.005, 5.0);
  }
}

// Two L-brackets lying flat back to back, their uprights (at the corners,
// the part origins) 20 mm apart: two parts, though their origins are closer than the
// duplicate distance (0.3 diameters, 35 mm). Duplicates are judged by the
// centres of the parts' surfaces, 90 mm apart here.
TEST_F(PerceptionTest, FindsTwoLBracketsWhoseCornersAreCloseButWhoseBodiesAreApart) {
  const Pose X_W1 = PoseW(0.01, 0.0, 0.0, 0.0), X_W2 = PoseW(-0.01, 0.01, 0.0, 180.0);
  const PerceptionResult r = fx().Run(fx().Render({{1, X_W1}, {1, X_W2}}));
  ASSERT_EQ(r.detections.size(), 2u) << r.reason;
  for (const Pose& X_WO : {X_W1, X_W2}) {
    const Vec3 t_B = (fx().cell.bin.X_BW * X_WO).translation();
    double best = 1e9;
    for (const Detection& d : r.detections) best = std::min(best, (d.X_BO.translation() - t_B).norm());
    EXPECT_LT(best, 0.001);
  }
}

TEST_F(PerceptionTest, SeparatesTwoTouchingParts) {
  // Two bushings standing side by side, flanges touching (60 mm flanges).
  const Pose X_W1 = PoseW(0.0, 0.0, 0.0, 0.0), X_W2 = PoseW(0.0601, 0.0, 0.0, 0.0);
  const Frame frame = fx().Render({{0, X_W1}, {0, X_W2}});
  const PerceptionResult r = fx().Run(frame);
  ASSERT_EQ(r.detections.size(), 2u) << r.reason;
  // Each detection explains its own part: the supports may share only the
  // points along the line where the flanges touch (within the support
  // distance of both models), a few percent of either.
  std::set<int32_t> first(r.detections[0].support.begin(), r.detections[0].support.end());
  size_t shared = 0;
  for (int32_t i : r.detections[1].support) shared += first.count(i);
  const size_t smaller = std::min(r.detections[0].support.size(), r.detections[1].support.size());
  EXPECT_GT(smaller, 500u);
  EXPECT_LE(shared, smaller / 20) << shared << " shared support points";
  for (const Pose& X_WO : {X_W1, X_W2}) {
    const Vec3 t = (fx().cell.bin.X_BW * X_WO).translation();
    const double best = std::min((r.detections[0].X_BO.translation() - t).norm(),
                                 (r.detections[1].X_BO.translation() - t).norm());
    EXPECT_LT(best, 0.001);
  }
}

// A short evaluation run on synthetic piles of the default cell (20 parts,
// default noise, 640x480). Measured on seeds 11-12: recall 1.000 (30
// targets), precision 1.000 (34 detections), median 0.041 mm / 0.065 deg
// (0.833 / 0.935 before the face seeds and view waves); the thresholds leave
// about two parts of margin. Over 70 piles the issue's targets (0.95 / 0.99)
// are not met yet (docs/perception_pipeline.md), so these pin the current
// level against regressions.
TEST(PerceptionEval, ShortSyntheticRunMeetsThresholds) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  std::vector<FrameEvaluation> frames;
  tbb::task_arena arena(2);
  for (uint64_t seed : {11u, 12u}) {
    const Frame frame = f.Pile(seed);
    ASSERT_TRUE(frame.truth.has_value());
    Result<PerceptionResult> r = Status::Internal("not run");
    arena.execute([&] { r = f.perception->Run(frame); });
    ASSERT_TRUE(r.ok()) << r.status().ToString();
    frames.push_back(EvaluateFrame(*r, *frame.truth, f.models));
  }
  const EvalReport report = Summarize(frames, f.models);
  const ClassFigures& all = report.classes.back();
  EXPECT_GE(all.targets, 20);
  EXPECT_GE(all.recall, 0.90);
  EXPECT_GE(all.precision, 0.94);
  EXPECT_LE(all.t_median_mm, 1.0);
  EXPECT_LE(all.r_median_deg, 1.0);
}

// The second look (PerceptionOptions::second_look_below, on by default)
// matches the weak views no detection explains again with 12 coarse poses
// instead of 4. On piles 10 and 24 of the default cell it finds a part each
// that a run without it misses (measured over piles 1-60 since the looser
// ICP convergence of 2026-12-03: 15 parts more in 15 piles, none fewer; 9 in
// piles 1-40, as before it, when piles 3 and 6 were the examples).
TEST(PerceptionEval, TheSecondLookFindsPartsTheNormalRunMisses) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  // Both without the residual regions' pass, which finds some of the same
  // parts after the second look.
  PerceptionOptions options;
  options.residual_regions = false;
  auto with = Perception::Build(f.cell, options);
  ASSERT_TRUE(with.ok()) << with.status().ToString();
  options.second_look_below = 0.0;
  auto without = Perception::Build(f.cell, options);
  ASSERT_TRUE(without.ok()) << without.status().ToString();
  std::vector<FrameEvaluation> normal, with_second_look;
  int second_looks = 0, coarse_skipped = 0;
  for (uint64_t seed : {10u, 24u}) {
    const Frame frame = f.Pile(seed);
    ASSERT_TRUE(frame.truth.has_value());
    const PerceptionResult off = Fixture::RunWith(**without, frame);
    const PerceptionResult on = Fixture::RunWith(**with, frame);
    EXPECT_EQ(off.second_looks, 0);
    EXPECT_EQ(off.coarse_skipped, 0);
    second_looks += on.second_looks;
    coarse_skipped += on.coarse_skipped;
    normal.push_back(EvaluateFrame(off, *frame.truth, f.models));
    with_second_look.push_back(EvaluateFrame(on, *frame.truth, f.models));
  }
  EXPECT_GT(second_looks, 0);
  // The second look leaves out the coarse poses the waves refined.
  EXPECT_GT(coarse_skipped, 0);
  const ClassFigures a = Summarize(normal, f.models).classes.back();
  const ClassFigures b = Summarize(with_second_look, f.models).classes.back();
  // 33 -> 35 parts found.
  EXPECT_GE(b.found, a.found + 1) << a.found << " -> " << b.found;
  EXPECT_LE(b.t_median_mm, 1.0);

  PerceptionOptions bad;
  bad.second_look_search.max_coarse_poses = 0;
  EXPECT_EQ(Perception::Build(f.cell, bad).status().code(), Status::Code::kInvalidArgument);
}

// Face seeds (PoseSearch::face_seeds): an L-bracket standing on its base,
// seen from above, shows its base plate's top face whole and its upright at
// a grazing angle; the plate is a segment of coplanar points, on which point
// pair features tie between every placement of the bracket's flat faces.
// With the face seeds the bracket is found from that segment alone (within
// 2 mm / 1.5 deg: the grazing upright leaves the pose weakly constrained;
// measured 0.1-1.4 mm); without them PPF voting turned it end for end at 2
// of the 7 headings (score 0.83). Turning it end for end about its base
// plate is one of the bracket's near symmetries (PoseSearch::near_symmetries):
// without face seeds but with those, it is found at 6 of the 7 headings (at
// every one with 150 PPF partners per reference point or more;
// PoseEstimatorOptions::ppf_max_partners is 100), 5 since the coarse ICP
// pass runs 5 iterations instead of 7 (icp_coarse_iterations, 2026-12-03;
// with face seeds, the default, still all 7).
TEST_F(PerceptionTest, FaceSeedsFindAnLBracketFromItsBasePlateAlone) {
  auto model = internal::BuildClassModel(fx().cell.parts[1]);
  ASSERT_TRUE(model.ok()) << model.status().ToString();
  const Eigen::Vector3f z_W = fx().cell.bin.X_BW.linear().col(2).cast<float>();
  const Eigen::Vector4d floor(z_W.x(), z_W.y(), z_W.z(),
                              -fx().cell.bin.X_BW.translation().dot(fx().cell.bin.X_BW.linear().col(2)));
  int with = 0, without = 0, turned = 0, cases = 0;
  for (const double yaw : {0.0, 35.0, 70.0, 115.0, 160.0, 220.0, 290.0}) {
    const Pose X_WO = PoseW(-0.1 + 0.0005 * yaw, 0.06, 0.0, yaw);
    const Frame frame = fx().Render({{1, X_WO}});
    const PerceptionResult r = fx().Run(frame);
    // The largest segment: the base plate's top face.
    std::map<int32_t, int> size;
    for (int32_t s : r.segment_of_point) {
      if (s >= 0) ++size[s];
    }
    ASSERT_FALSE(size.empty());
    const int32_t largest = std::max_element(size.begin(), size.end(), [](const auto& a, const auto& b) {
                              return a.second < b.second;
                            })->first;
    std::vector<Eigen::Vector3f> plate;
    for (size_t i = 0; i < r.roi_points_B.size(); ++i) {
      if (r.segment_of_point[i] == largest) plate.push_back(r.roi_points_B[i]);
    }
    ++cases;
    const Pose X_BO = fx().cell.bin.X_BW * X_WO;
    // (face seeds, near symmetries): both, neither, near symmetries alone.
    for (const auto& [seeds, near] : {std::pair{2, true}, std::pair{0, false}, std::pair{0, true}}) {
      internal::SegmentView view;
      view.points_B = plate;
      view.frame = &frame;
      view.floor_plane_B = floor;
      view.search = PoseSearch{};
      view.search->face_seeds = seeds;
      view.search->near_symmetries = near;
      const internal::ClassEstimate e = (*model)->Estimate(view);
      const bool found =
          !e.hypotheses.empty() && e.hypotheses[0].score >= 0.7 &&
          (e.hypotheses[0].X_BO.translation() - X_BO.translation()).norm() < 0.002 &&
          Eigen::AngleAxisd(e.hypotheses[0].X_BO.linear().transpose() * X_BO.linear()).angle() < 1.5 * kDeg;
      (seeds > 0 ? with : near ? turned : without) += found ? 1 : 0;
    }
  }
  std::printf("[          ] face seeds: %d of %d found within 2 mm / 1.5 deg, without: %d, near symmetries alone: %d\n",
              with, cases, without, turned);
  EXPECT_EQ(with, cases);
  EXPECT_LT(without, with);
  EXPECT_GT(turned, without);
  EXPECT_GE(turned, cases - 2);
}

// Class ranking by planar share (PerceptionOptions::rank_planar_share_weight):
// a view of a pipe no longer runs the L-bracket first, nor a plate the tee.
// On piles 13, 14 and 20 it saves estimator calls (65 / 39 / 49 -> 61 / 35 /
// 43 in `binpick --log-level debug eval`) and finds the same parts with the
// same true and false detections.
TEST(PerceptionEval, PlanarShareRanksTheRightClassFirst) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  PerceptionOptions options;
  options.rank_planar_share_weight = 0.0;
  auto extents_only = Perception::Build(f.cell, options);
  ASSERT_TRUE(extents_only.ok()) << extents_only.status().ToString();
  int calls_extents = 0, calls_planar = 0;
  std::vector<FrameEvaluation> a, b;
  for (uint64_t seed : {13u, 14u, 20u}) {
    const Frame frame = f.Pile(seed);
    ASSERT_TRUE(frame.truth.has_value());
    const PerceptionResult old_rank = Fixture::RunWith(**extents_only, frame);
    const PerceptionResult new_rank = Fixture::RunWith(*f.perception, frame);
    calls_extents += old_rank.estimator_calls;
    calls_planar += new_rank.estimator_calls;
    a.push_back(EvaluateFrame(old_rank, *frame.truth, f.models));
    b.push_back(EvaluateFrame(new_rank, *frame.truth, f.models));
  }
  EXPECT_LT(calls_planar, calls_extents);
  const ClassFigures fa = Summarize(a, f.models).classes.back();
  const ClassFigures fb = Summarize(b, f.models).classes.back();
  EXPECT_EQ(fb.found, fa.found);
  EXPECT_EQ(fb.true_positives, fa.true_positives);
  EXPECT_EQ(fb.detections, fa.detections);

  PerceptionOptions bad;
  bad.rank_planar_share_weight = -1.0;
  EXPECT_EQ(Perception::Build(f.cell, bad).status().code(), Status::Code::kInvalidArgument);
}

// The second look tries first the class whose hypothesis in the view's wave
// scored best (PerceptionOptions::second_look_rank_by_wave): on piles 23, 25
// and 28 fewer estimator calls (`binpick --log-level debug eval`: 37 / 41 /
// 71 -> 35 / 39 / 69), the same parts found, the same true and false
// detections.
TEST(PerceptionEval, TheSecondLookTriesTheWavesClosestClassFirst) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  PerceptionOptions options;
  options.second_look_rank_by_wave = false;
  auto by_extents = Perception::Build(f.cell, options);
  ASSERT_TRUE(by_extents.ok()) << by_extents.status().ToString();
  int calls_extents = 0, calls_wave = 0;
  std::vector<FrameEvaluation> a, b;
  for (uint64_t seed : {23u, 25u, 28u}) {
    const Frame frame = f.Pile(seed);
    ASSERT_TRUE(frame.truth.has_value());
    const PerceptionResult old_rank = Fixture::RunWith(**by_extents, frame);
    const PerceptionResult new_rank = Fixture::RunWith(*f.perception, frame);
    EXPECT_GT(new_rank.second_looks, 0) << "pile " << seed;
    calls_extents += old_rank.estimator_calls;
    calls_wave += new_rank.estimator_calls;
    a.push_back(EvaluateFrame(old_rank, *frame.truth, f.models));
    b.push_back(EvaluateFrame(new_rank, *frame.truth, f.models));
  }
  EXPECT_LT(calls_wave, calls_extents);
  const ClassFigures fa = Summarize(a, f.models).classes.back();
  const ClassFigures fb = Summarize(b, f.models).classes.back();
  EXPECT_EQ(fb.found, fa.found);
  EXPECT_EQ(fb.true_positives, fa.true_positives);
  EXPECT_EQ(fb.detections, fa.detections);
}

// The segment stage's passes over the grid cells run in one range of cells
// per thread and merge their counts in range order: on one thread and on
// two, the same segments (every ROI point's label), views and detections
// (the per-region counts' merge has a test of its own in roi_cloud_test).
TEST(PerceptionEval, OneThreadAndTwoGiveTheSameSegmentsAndDetections) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  for (uint64_t seed : {3u, 13u}) {
    const Frame frame = f.Pile(seed);
    const PerceptionResult two = Fixture::RunWith(*f.perception, frame);
    tbb::task_arena arena(1);
    Result<PerceptionResult> one = Status::Internal("not run");
    arena.execute([&] { one = f.perception->Run(frame, {}); });
    ASSERT_TRUE(one.ok()) << one.status().ToString();
    ASSERT_FALSE(two.segment_of_point.empty());
    EXPECT_GT(*std::max_element(two.segment_of_point.begin(), two.segment_of_point.end()), 5) << "pile " << seed;
    EXPECT_EQ(one->views, two.views);
    EXPECT_EQ(one->largest_region_points, two.largest_region_points);
    EXPECT_TRUE(one->segment_of_point == two.segment_of_point) << "pile " << seed;
    ASSERT_EQ(one->detections.size(), two.detections.size()) << "pile " << seed;
    for (size_t i = 0; i < two.detections.size(); ++i) {
      EXPECT_EQ(one->detections[i].class_id, two.detections[i].class_id);
      EXPECT_TRUE(one->detections[i].X_BO.isApprox(two.detections[i].X_BO, 1e-12)) << "pile " << seed << " #" << i;
    }
  }
}

// View waves (PerceptionOptions::view_waves): the views of later waves that
// lie mostly on a part already found are not matched. On pile 3 this skips
// views and estimator calls, and finds the same parts (the same recall
// targets, no extra false detection) as one wave of every view.
TEST(PerceptionEval, ViewWavesSkipPiecesOfPartsAlreadyFound) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  PerceptionOptions options;
  options.view_waves = {};
  auto one_wave = Perception::Build(f.cell, options);
  ASSERT_TRUE(one_wave.ok()) << one_wave.status().ToString();
  const Frame frame = f.Pile(3);
  ASSERT_TRUE(frame.truth.has_value());
  const PerceptionResult all = Fixture::RunWith(**one_wave, frame);
  const PerceptionResult waves = Fixture::RunWith(*f.perception, frame);
  EXPECT_EQ(all.views_explained, 0);
  EXPECT_GT(waves.views_explained, 0);
  EXPECT_LT(waves.estimator_calls, all.estimator_calls);
  const ClassFigures a = Summarize({EvaluateFrame(all, *frame.truth, f.models)}, f.models).classes.back();
  const ClassFigures b = Summarize({EvaluateFrame(waves, *frame.truth, f.models)}, f.models).classes.back();
  EXPECT_EQ(b.found, a.found);
  EXPECT_LE(b.detections - b.true_positives, a.detections - a.true_positives);

  PerceptionOptions bad;
  bad.view_waves = {300, 2000};
  EXPECT_EQ(Perception::Build(f.cell, bad).status().code(), Status::Code::kInvalidArgument);
}

// Parts of a pile never interpenetrate, so neither do the detections: a
// hypothesis that sinks into an accepted detection's material loses to it or,
// scoring higher, replaces it. On pile 13 a bushing was fitted into an
// L-bracket's plate (0.90) before the bracket (0.97) was found.
TEST(PerceptionEval, DetectionsNeverInterpenetrate) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  std::map<int, std::unique_ptr<internal::ClassModel>> models;
  for (const PartSpec& p : f.cell.parts) models[p.class_id] = std::move(internal::BuildClassModel(p)).value();
  for (uint64_t seed : {13u, 38u}) {
    const Frame frame = f.Pile(seed);
    const PerceptionResult r = f.Run(frame);
    ASSERT_GE(r.detections.size(), 10u) << "pile " << seed;
    std::vector<std::vector<Eigen::Vector3f>> surfaces;
    for (const Detection& d : r.detections) {
      std::vector<Eigen::Vector3f> s;
      for (const Eigen::Vector3f& p : models.at(d.class_id)->surface_points_O()) {
        s.push_back((d.X_BO * p.cast<double>()).cast<float>());
      }
      surfaces.push_back(std::move(s));
    }
    for (size_t a = 0; a < r.detections.size(); ++a) {
      for (size_t b = 0; b < r.detections.size(); ++b) {
        if (a == b) continue;
        const size_t inside =
            models.at(r.detections[b].class_id)->CountInside(r.detections[b].X_BO, surfaces[a], 0.001f);
        EXPECT_LE(static_cast<double>(inside), 0.03 * static_cast<double>(surfaces[a].size()))
            << "pile " << seed << ": detection " << a << " (class " << r.detections[a].class_id << ", score "
            << r.detections[a].score << ") inside detection " << b << " (class " << r.detections[b].class_id
            << ", score " << r.detections[b].score << ")";
      }
    }
  }
}

// The frame's own depth noise, measured (it scales the fit residual limit up
// for cameras noisier than their cell says: the 0.8 mm frame of
// AFragmentedLonePartIsMatchedAsOneSegment keeps its bracket), before
// smoothing; a frame above smoothing_target_sigma (0.5 mm) is smoothed
// (stage "smooth") and its part still found, one below is not; bad smoothing
// options are refused.
TEST_F(PerceptionTest, MeasuresTheDepthNoiseOfTheFrame) {
  for (double sigma : {0.0003, 0.0008}) {
    const PerceptionResult r = fx().Run(fx().Render({{0, PoseW(0.0, 0.0, 0.0, 0.0)}}, sigma));
    EXPECT_NEAR(r.depth_noise_sigma, sigma, 0.1 * sigma);
    EXPECT_NEAR(r.depth_noise_at, 1.05, 0.01);  // the bin floor fills most of the frame
    EXPECT_EQ(r.detections.size(), 1u) << r.reason;
    const bool smoothed =
        std::any_of(r.timings.begin(), r.timings.end(), [](const auto& t) { return t.stage == "smooth"; });
    EXPECT_EQ(smoothed, sigma > PerceptionOptions{}.smoothing_target_sigma) << sigma;
  }
  const PerceptionResult none = fx().Run(fx().Render({}, 0.0));
  EXPECT_LT(none.depth_noise_sigma, 0.00002);  // rendered depth: float rounding only

  for (const auto& spoil : std::vector<std::function<void(PerceptionOptions&)>>{
           [](PerceptionOptions& o) { o.smoothing_gate_sigmas = 0.0; },
           [](PerceptionOptions& o) { o.smoothing_target_sigma = std::numeric_limits<double>::quiet_NaN(); },
           [](PerceptionOptions& o) { o.smoothing_max_radius = -1; }}) {
    PerceptionOptions bad;
    spoil(bad);
    EXPECT_EQ(Perception::Build(fx().cell, bad).status().code(), Status::Code::kInvalidArgument);
  }
}

// A bushing fitted onto a pipe tee whose run shows only in part (a 36 mm hub
// on a 40 mm pipe) supports most of its samples within the support distance
// but leaves residuals above the depth noise (PerceptionOptions::
// max_fit_rms_sigmas). Measured in piles 15, 27 and 65: with the limit off,
// each has such a false positive; with it, none, and no true detection is lost
// (piles 1-120: 5 such false bushings, 1.31-1.86 sigma_z; piles 1-60 since
// the looser ICP convergence of 2026-12-03: 5 false positives above the
// limit, in piles 13, 15, 27, 36 and 42, where pile 54 was one before;
// piles 1-100 since the 3-iteration ICP gate schedule of the same day: 8,
// in piles 13, 15, 27, 36, 54, 65, 72 and 95, where 42 and 94 were before;
// since the 0.6 detection bar and the 1.5 mm floor penetration of
// 2026-12-05, 36 no longer is, 54 keeps another false positive below the
// limit, the other six are).
TEST(PerceptionEval, FitsWorseThanTheDepthNoiseAreRejected) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  // The fit limit alone: the free-space rule refuses some of the same fits.
  // Unmeasured samples count against, as when the piles were chosen (as no
  // evidence, pile 27's badly fitted false positive loses to another pose).
  PerceptionOptions on;
  on.max_free_space_fraction = 1.0;
  on.unmeasured_is_no_evidence = false;
  on.second_look_search.unmeasured_is_no_evidence = false;
  PerceptionOptions off = on;
  off.max_fit_rms_sigmas = 0.0;
  const std::unique_ptr<Perception> loose = Perception::Build(f.cell, off).value();
  const std::unique_ptr<Perception> strict = Perception::Build(f.cell, on).value();
  const NoiseModel& noise = f.cell.camera.FindConfig(1)->noise;
  const double limit_sigmas = PerceptionOptions{}.max_fit_rms_sigmas;
  for (uint64_t seed : {15u, 27u, 65u}) {
    const Frame frame = f.Pile(seed);
    // Detections (index, rms in sigma_z) that match no part.
    const auto judge = [&](const PerceptionResult& r, int* true_positives) {
      std::vector<std::pair<size_t, double>> false_positives;
      *true_positives = 0;
      for (const DetectionOutcome& o : EvaluateFrame(r, *frame.truth, f.models).detections) {
        const Detection& d = r.detections[o.detection];
        const double z = (frame.X_BC.inverse() * d.X_BO).translation().z();
        const double sigma = noise.axial_sigma_base + noise.axial_sigma_quadratic * z * z;
        if (o.truth_instance >= 0) {
          ++*true_positives;
        } else {
          false_positives.emplace_back(o.detection, d.rms_residual / sigma);
        }
      }
      return false_positives;
    };
    int tp_off = 0, tp_on = 0;
    const auto fp_off = judge(Fixture::RunWith(*loose, frame), &tp_off);
    const PerceptionResult limited = Fixture::RunWith(*strict, frame);
    const auto fp_on = judge(limited, &tp_on);
    EXPECT_TRUE(std::any_of(fp_off.begin(), fp_off.end(), [&](const auto& fp) { return fp.second > limit_sigmas; }))
        << "pile " << seed << ": no false positive above the limit to reject";
    // (sigma_z here at the part's origin, the pipeline's at its surface
    // centroid: a few percent apart.)
    for (const auto& [k, rms] : fp_on) EXPECT_LE(rms, 1.1 * limit_sigmas) << "pile " << seed << ", detection " << k;
    EXPECT_LT(fp_on.size(), fp_off.size()) << "pile " << seed;
    EXPECT_GE(tp_on, tp_off) << "pile " << seed;
    for (const Detection& d : limited.detections) {
      EXPECT_GT(d.rms_residual, 0.0);
      EXPECT_LT(d.rms_residual, 0.001);
    }
  }
}

// A flanged bushing fits coaxially into a pipe tee's run (its hub is 2 mm
// inside the run's surface): on a tee mostly hidden by its neighbours, such
// a fit explains what is seen of the tee, its flange sticking out where the
// camera sees the tee's surface behind it. max_free_space_fraction refuses
// those fits. Piles of the tuning range (--variety) where that happened
// (fits hidden by the tee and its neighbours leave no free space: not
// refused by this rule).
// Pile `seed` of `cell` with scene variety on (binpick eval --variety),
// rendered with its truth.
Result<Frame> VariedPile(Cell cell, uint64_t seed) {
  cell.source.variety = VarietySpec{};
  cell.source.seed = seed;
  Result<std::unique_ptr<CaptureSource>> source = MakeSyntheticSource(cell);
  if (!source.ok()) return source.status();
  return (*source)->Capture({});
}

TEST(PerceptionEval, ABushingFittedIntoATeeIsRefusedByTheFreeSpaceItLeaves) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  PerceptionOptions off;
  off.max_free_space_fraction = 1.0;
  const std::unique_ptr<Perception> loose = Perception::Build(f.cell, off).value();
  int in_a_tee_off = 0;
  for (uint64_t seed : {1015u, 1021u, 1062u}) {
    Result<Frame> frame = VariedPile(f.cell, seed);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    // Bushings that match no bushing but lie within 15 mm of a tee's origin
    // (on its run axis); and the true positives.
    const auto judge = [&](const PerceptionResult& r, int* true_positives) {
      int in_a_tee = 0;
      *true_positives = 0;
      for (const DetectionOutcome& o : EvaluateFrame(r, *frame->truth, f.models).detections) {
        if (o.verdict == DetectionVerdict::kTrue) ++*true_positives;
        if (o.verdict != DetectionVerdict::kFalse || o.class_id != 0) continue;
        const Vec3 p = r.detections[o.detection].X_BO.translation();
        for (const PartTruth& t : frame->truth->parts) {
          if (t.class_id == 2 && (t.X_BO.translation() - p).norm() < 0.015) ++in_a_tee;
        }
      }
      return in_a_tee;
    };
    int tp_off = 0, tp_on = 0;
    in_a_tee_off += judge(Fixture::RunWith(*loose, *frame), &tp_off);
    EXPECT_EQ(judge(f.Run(*frame), &tp_on), 0) << "pile " << seed;
    EXPECT_GE(tp_on, tp_off - 1) << "pile " << seed;
  }
  EXPECT_GT(in_a_tee_off, 0) << "no bushing fitted into a tee without the rule: nothing to refuse";
}


// A pipe tee standing on its branch, or lying with the branch hidden under
// its run, fits the seen run at any turn about the run; a turn of 5-30 deg
// pushes the branch's rim 1-3 mm into the bin floor, which true poses of
// parts resting on it never do (at most about 1.1 mm: the fit's error).
// PerceptionOptions::max_support_penetration (1.5 mm; the estimator's own
// default is 3 mm) refuses those turns. Piles of the tuning range (--variety)
// where a tee was detected so turned: 1004 (refused, left for the next
// capture) and 1034 (the right pose found instead; also 1046, not run here:
// each pile costs two perception runs, several seconds under ASan).
TEST(PerceptionEval, ATeeTurnedIntoTheFloorIsRefused) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  // Both without the own-point turns (which turn some of these tees right
  // whatever the limit) and with unmeasured samples counting against, as when
  // the limit was chosen (as no evidence, pile 1004's search path moves and
  // the loose run finds one part more) and without the residual regions'
  // look with the estimator's own normals (with it, too, the loose run finds
  // one part more in pile 1004): the limit's effect alone.
  PerceptionOptions no_own_turns;
  no_own_turns.own_turn_gain = -1.0;
  no_own_turns.residual_own_normals = false;
  no_own_turns.unmeasured_is_no_evidence = false;
  no_own_turns.second_look_search.unmeasured_is_no_evidence = false;
  const std::unique_ptr<Perception> limited = Perception::Build(f.cell, no_own_turns).value();
  PerceptionOptions old_limit = no_own_turns;
  old_limit.max_support_penetration = 0.003;
  const std::unique_ptr<Perception> loose = Perception::Build(f.cell, old_limit).value();
  const Pose& X_BW = f.cell.bin.X_BW;
  const Eigen::Vector3d up_B = X_BW.linear().col(2);
  // How far the detection's mesh reaches below the floor (metres, >= 0).
  const auto sink = [&](const Detection& d) {
    double lowest = 0.0;
    for (const Eigen::Vector3f& v : f.meshes[static_cast<size_t>(d.class_id) + 1]->vertices) {
      lowest = std::min(lowest, up_B.dot(d.X_BO * v.cast<double>() - X_BW.translation()));
    }
    return -lowest;
  };
  int sunk_gross_tees_loose = 0;
  for (uint64_t seed : {1004u, 1034u}) {
    Result<Frame> frame = VariedPile(f.cell, seed);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    // True positives, gross tees, and gross tees sunk below the new limit.
    struct Counts {
      int true_positives = 0, gross_tees = 0, sunk_gross_tees = 0;
    };
    const auto judge = [&](const PerceptionResult& r) {
      Counts c;
      for (const DetectionOutcome& o : EvaluateFrame(r, *frame->truth, f.models).detections) {
        if (o.verdict == DetectionVerdict::kTrue) ++c.true_positives;
        if (o.verdict != DetectionVerdict::kGross || o.class_id != 2) continue;
        ++c.gross_tees;
        if (sink(r.detections[o.detection]) > 0.0015) ++c.sunk_gross_tees;
      }
      return c;
    };
    const Counts before = judge(Fixture::RunWith(*loose, *frame));
    const PerceptionResult result = Fixture::RunWith(*limited, *frame);
    const Counts after = judge(result);
    sunk_gross_tees_loose += before.sunk_gross_tees;
    EXPECT_EQ(after.sunk_gross_tees, 0) << "pile " << seed;
    EXPECT_LE(after.gross_tees, before.gross_tees - before.sunk_gross_tees) << "pile " << seed;
    EXPECT_GE(after.true_positives, before.true_positives) << "pile " << seed;
    for (const Detection& d : result.detections) EXPECT_LE(sink(d), 0.0015 + 1e-4) << "pile " << seed;
  }
  EXPECT_GE(sunk_gross_tees_loose, 2) << "no tee turned into the floor with the old limit: nothing to refuse";
}

// The pipe tees (class 2) of a result, judged strictly against the truth:
// right ones, gross ones (near a true tee, outside the pose tolerance), and
// right ones that carry an alternative pose.
struct TeeCounts {
  int true_tees = 0, gross_tees = 0, true_tees_with_alternatives = 0;
};
TeeCounts JudgeTees(const PerceptionResult& r, const GroundTruth& truth, const std::vector<EvalPartModel>& models) {
  TeeCounts c;
  for (const DetectionOutcome& o : EvaluateFrame(r, truth, models).detections) {
    if (o.class_id != 2) continue;
    c.gross_tees += o.verdict == DetectionVerdict::kGross;
    if (o.verdict != DetectionVerdict::kTrue) continue;
    ++c.true_tees;
    c.true_tees_with_alternatives += !r.detections[o.detection].alternatives_X_BO.empty();
  }
  return c;
}

// A pipe tee's turns about its run that hide its branch behind the run
// score higher (fewer of its samples in view) while explaining less of what
// the camera saw; the turn that explains more was carried as an alternative
// and is now the pose when it explains more than 6% more of the view
// (PoseEstimatorOptions::ambiguity_net_gain). Piles of the tuning range
// (--variety) where a tee was detected 8 deg (1010) and 57 deg (1068) off
// about its run with the true pose among its alternatives.
TEST(PerceptionEval, ATurnThatExplainsMoreOfTheViewIsPreferred) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  // Both without the own-point turns (which turn the tee of 1068 right by
  // themselves) and without withholding ambiguous parts mostly hidden (the
  // tee of 1068 is seen 47-48%): the gain's effect alone.
  PerceptionOptions no_own_turns;
  no_own_turns.own_turn_gain = -1.0;
  no_own_turns.ambiguous_min_visible = 0.0;
  const std::unique_ptr<Perception> by_gain = Perception::Build(f.cell, no_own_turns).value();
  PerceptionOptions off = no_own_turns;
  off.ambiguity_net_gain = 0.0;
  const std::unique_ptr<Perception> by_score = Perception::Build(f.cell, off).value();
  for (uint64_t seed : {1010u, 1068u}) {
    Result<Frame> frame = VariedPile(f.cell, seed);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    const auto judge = [&](const PerceptionResult& r) { return JudgeTees(r, *frame->truth, f.models); };
    const TeeCounts before = judge(Fixture::RunWith(*by_score, *frame));
    const TeeCounts after = judge(Fixture::RunWith(*by_gain, *frame));
    EXPECT_GE(before.gross_tees, 1) << "pile " << seed << ": no tee off its pose by score alone";
    EXPECT_LE(after.gross_tees, before.gross_tees - 1) << "pile " << seed;
    EXPECT_GE(after.true_tees, before.true_tees + 1) << "pile " << seed;
    // The pose the score chose is kept as the right one's alternative.
    EXPECT_GE(after.true_tees_with_alternatives, before.true_tees_with_alternatives + 1) << "pile " << seed;
  }
}

// A pipe tee seen as an L (one of its three alike arms hidden) fits with its
// branch on either seen arm: 90 deg off about the part's y. The arm swap
// (PoseEstimatorOptions::arm_swaps) is tried as a near symmetry and the
// truth replaces the pose or is carried as its alternative. Piles of the
// tuning range (--variety): 1003 and 1068, a tee detected 90 deg off about
// y without the swap and right with it; 1016, one still off whose true pose
// is now among its alternatives.
TEST(PerceptionEval, ATeeSeenAsAnLIsTriedWithItsArmsSwapped) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  // Both without withholding ambiguous parts mostly hidden (the tee of 1068
  // is seen 48%): the swaps' effect alone.
  PerceptionOptions on;
  on.ambiguous_min_visible = 0.0;
  const std::unique_ptr<Perception> swaps = Perception::Build(f.cell, on).value();
  PerceptionOptions off = on;
  off.arm_swaps = false;
  const std::unique_ptr<Perception> no_swaps = Perception::Build(f.cell, off).value();
  for (uint64_t seed : {1003u, 1068u, 1016u}) {
    Result<Frame> frame = VariedPile(f.cell, seed);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    struct Counts {
      int true_tees = 0, gross_tees = 0, carried = 0;
    };
    const auto judge = [&](const PerceptionResult& r) {
      Counts c;
      for (const DetectionOutcome& o : EvaluateFrame(r, *frame->truth, f.models).detections) {
        if (o.class_id != 2) continue;
        c.true_tees += o.verdict == DetectionVerdict::kTrue;
        c.gross_tees += o.verdict == DetectionVerdict::kGross;
        c.carried += o.verdict == DetectionVerdict::kGross && o.carried;
      }
      return c;
    };
    const Counts before = judge(Fixture::RunWith(*no_swaps, *frame));
    const Counts after = judge(Fixture::RunWith(*swaps, *frame));
    EXPECT_GE(before.gross_tees, 1) << "pile " << seed << ": no tee off without the swap";
    if (seed == 1016u) {
      EXPECT_GE(after.carried, before.carried + 1) << "pile " << seed;
      EXPECT_LE(after.gross_tees, before.gross_tees) << "pile " << seed;
    } else {
      EXPECT_LE(after.gross_tees, before.gross_tees - 1) << "pile " << seed;
      EXPECT_GE(after.true_tees, before.true_tees + 1) << "pile " << seed;
    }
  }
}

// A pipe tee fully in view is fitted turned about its run when its branch's
// turned pose claims points of its neighbours: judged on the segment, the
// wrong turn explains more. Once every detection is accepted, the tee's turns
// are judged again on its own points (those the neighbours explain left out
// of the view and of the depth image; PerceptionOptions::own_turn_gain) and
// the true turn, refined on them, explains more. Piles of the tuning range
// (--variety): 1013 and 1082, a tee fully in view detected 24 and 25 deg
// off about its run without the stage and right with it (at the default
// own_turn_min_foreign: the stage still judges them); the wrong pose is
// kept as the right one's alternative. A share of the reach on neighbours
// outside [0, 1] is refused.
TEST(PerceptionEval, ATeeIsTurnedAgainOnItsOwnPointsOnceItsNeighboursAreFound) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  PerceptionOptions off;
  off.own_turn_gain = -1.0;
  const std::unique_ptr<Perception> on_segments = Perception::Build(f.cell, off).value();
  for (uint64_t seed : {1013u, 1082u}) {
    Result<Frame> frame = VariedPile(f.cell, seed);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    const auto judge = [&](const PerceptionResult& r) { return JudgeTees(r, *frame->truth, f.models); };
    const TeeCounts before = judge(Fixture::RunWith(*on_segments, *frame));
    const PerceptionResult result = f.Run(*frame);
    const TeeCounts after = judge(result);
    EXPECT_GE(before.gross_tees, 1) << "pile " << seed << ": no tee off about its run without the stage";
    EXPECT_LE(after.gross_tees, before.gross_tees - 1) << "pile " << seed;
    EXPECT_GE(after.true_tees, before.true_tees + 1) << "pile " << seed;
    EXPECT_GE(after.true_tees_with_alternatives, before.true_tees_with_alternatives + 1) << "pile " << seed;
    EXPECT_TRUE(std::any_of(result.timings.begin(), result.timings.end(),
                            [](const StageTiming& t) { return t.stage == "own_turns"; }));
  }
  for (double share : {-0.1, 1.5, std::numeric_limits<double>::quiet_NaN()}) {
    PerceptionOptions bad;
    bad.own_turn_min_foreign = share;
    EXPECT_EQ(Perception::Build(f.cell, bad).status().code(), Status::Code::kInvalidArgument) << share;
  }
}

// Two poses of a part are alternatives of each other only beyond the strict
// tolerance (5 mm, 5 deg) modulo its symmetry: a pipe tee turned half a turn
// about its branch (its declared symmetry) or a few degrees about its run is
// the same pose; 6 deg about its run or 6 mm along it is another.
TEST(PerceptionEval, PosesAreDistinctBeyondTheToleranceModuloTheSymmetry) {
  Fixture& f = Fixture::Get();
  const std::unique_ptr<internal::ClassModel> tee = internal::BuildClassModel(f.cell.parts[2]).value();
  const Pose X = MakePose(Mat3(Eigen::AngleAxisd(0.7, Vec3(1, 2, 3).normalized())), Vec3(0.6, 0.05, 0.08));
  const auto turned = [&](const Vec3& axis, double deg) {
    return X * MakePose(Mat3(Eigen::AngleAxisd(deg * kDeg, axis)), Vec3::Zero());
  };
  EXPECT_FALSE(tee->DistinctPoses(X, X));
  EXPECT_FALSE(tee->DistinctPoses(X, turned(Vec3::UnitZ(), 180.0)));
  EXPECT_FALSE(tee->DistinctPoses(X, turned(Vec3::UnitX(), 4.0)));
  EXPECT_FALSE(tee->DistinctPoses(turned(Vec3::UnitZ(), 180.0), turned(Vec3::UnitX(), -4.0)));
  EXPECT_TRUE(tee->DistinctPoses(X, turned(Vec3::UnitX(), 6.0)));
  EXPECT_TRUE(tee->DistinctPoses(X, turned(Vec3::UnitZ(), 90.0)));
  EXPECT_TRUE(tee->DistinctPoses(X, X * MakePose(Mat3::Identity(), Vec3(0.006, 0, 0))));
}

// The own-point turn of a tee that moves it by less than the tolerance
// refines its pose; it does not make it ambiguous (the old pose is no
// alternative of the new one). Piles of the tuning range (--variety): in
// 1002 tees 7, 10 and 11 (56-93% seen) were each turned 1-4 deg and carried
// their old pose as their one alternative; in 1017 tee 5 (seen 49%), so
// marked, was withheld as ambiguous and mostly hidden. Each is found
// strictly and unambiguous, and no detection carries an alternative within
// the tolerance of its pose.
TEST(PerceptionEval, ATeeTurnedWithinTheToleranceOnItsOwnPointsIsNotAmbiguous) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  const std::vector<std::pair<unsigned, std::vector<int>>> piles = {{1002u, {7, 10, 11}}, {1017u, {5}}};
  for (const auto& pile : piles) {
    const unsigned seed = pile.first;
    Result<Frame> frame = VariedPile(f.cell, seed);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    const PerceptionResult result = f.Run(*frame);
    for (const Detection& d : result.detections) {
      const Symmetry& symmetry = f.cell.parts[static_cast<size_t>(d.class_id)].symmetry;
      for (const Pose& X : d.alternatives_X_BO) {
        EXPECT_TRUE(SymmetricTranslationError(X, d.X_BO, symmetry) > 0.005 ||
                    SymmetricRotationError(X, d.X_BO, symmetry) > 5.0 * kDeg)
            << "pile " << seed << ": class " << d.class_id << " carries its own pose as an alternative";
      }
    }
    for (const int instance : pile.second) {
      bool found_unambiguous = false;
      for (const DetectionOutcome& o : EvaluateFrame(result, *frame->truth, f.models).detections) {
        if (o.verdict == DetectionVerdict::kTrue && o.truth_instance == instance) {
          found_unambiguous = !result.detections[o.detection].pose_ambiguous();
        }
      }
      EXPECT_TRUE(found_unambiguous) << "pile " << seed << ": tee " << instance;
    }
  }
}

// A frame's result judged strictly against its truth (EvaluateFrame): how
// many detections are right (true) and wrong (gross or false), whether truth
// instance `instance` is found (-1: none asked), and how many detections
// `mark` picks out (the mechanism a test is about; given each outcome and its
// detection, and free to assert on them; none: 0).
struct VerdictCounts {
  int right = 0, wrong = 0, marked = 0;
  bool found = false;
};
using VerdictMark = std::function<bool(const DetectionOutcome&, const Detection&)>;
VerdictCounts CountVerdicts(const PerceptionResult& result, const Frame& frame,
                            const std::vector<EvalPartModel>& models, int instance = -1,
                            const VerdictMark& mark = nullptr) {
  VerdictCounts c;
  for (const DetectionOutcome& o : EvaluateFrame(result, *frame.truth, models).detections) {
    if (o.verdict == DetectionVerdict::kTrue) ++c.right;
    if (o.verdict == DetectionVerdict::kGross || o.verdict == DetectionVerdict::kFalse) ++c.wrong;
    c.found |= o.verdict == DetectionVerdict::kTrue && o.truth_instance == instance;
    if (mark && mark(o, result.detections[o.detection])) ++c.marked;
  }
  return c;
}

// Parts the segmentation split over segments, left in pieces below
// min_segment_points or merged with a neighbour: once the neighbours are
// found, the samples no detection explains, grouped by grid connectivity,
// hold the part alone (PerceptionOptions::residual_regions). Piles of the
// tuning range (--variety): 1001, a pipe tee 61% visible whose 696 points
// lie mostly in pieces (its neighbour tees are found); 1026, an L-bracket
// fully in view sharing its one segment with a neighbour (44% of it its
// own). Each part is matched only with the pass, and the pass adds no wrong
// detection to these piles. The enclosing pass, after it, is left out of
// both runs: in 1001 without the regions a bushing fitted into the tee is
// replaced by the tee there. planar_view_min_share is off in both: with it,
// 1026's bracket is found by its face seeds without the pass. Both count
// the segment minimum the same on every frame (min_segment_spacing 0): 1001's
// frame is coarser than the cell camera's, and counted as an area its tee's
// pieces are segments, found without the pass.
TEST(PerceptionEval, TheSamplesNoDetectionExplainsAreMatchedAsRegions) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  PerceptionOptions on;
  on.enclosing_parts = false;
  on.planar_view_min_share = 0.0;
  on.min_segment_spacing = 0.0;
  PerceptionOptions off = on;
  off.residual_regions = false;
  const std::unique_ptr<Perception> with = Perception::Build(f.cell, on).value();
  const std::unique_ptr<Perception> without = Perception::Build(f.cell, off).value();
  for (const std::pair<unsigned, int>& pile : {std::pair{1001u, 13}, std::pair{1026u, 13}}) {
    // Named copies, not structured bindings: clang 14 (the sanitizer trees)
    // does not let the lambda below capture a structured binding.
    const unsigned seed = pile.first;
    const int instance = pile.second;
    Result<Frame> frame = VariedPile(f.cell, seed);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    const VerdictCounts before = CountVerdicts(Fixture::RunWith(*without, *frame), *frame, f.models, instance);
    const VerdictCounts after = CountVerdicts(Fixture::RunWith(*with, *frame), *frame, f.models, instance);
    EXPECT_FALSE(before.found) << "pile " << seed << ": part " << instance << " found without the pass";
    EXPECT_TRUE(after.found) << "pile " << seed << ": part " << instance;
    EXPECT_GE(after.right, before.right + 1) << "pile " << seed;
    EXPECT_LE(after.wrong, before.wrong) << "pile " << seed;
  }
}

// The truth of instance `instance` in a frame with truth, or nullptr.
const PartTruth* TruthInstance(const Frame& frame, int instance) {
  for (const PartTruth& p : frame.truth->parts) {
    if (p.instance_id == instance) return &p;
  }
  return nullptr;
}

// A rule that finds a missed part: on each pile of the tuning range
// (--variety; seed, true instance) the part is missed by `without` and
// found strictly by `with`, and `with` answers no more wrong detections.
// check_truth, if given, first checks that the pile's part shows the
// mechanism the rule is for.
void ExpectFoundOnlyWith(const Perception& without, const Perception& with,
                         std::initializer_list<std::pair<unsigned, int>> piles,
                         const std::function<void(const PartTruth&, unsigned)>& check_truth = {}) {
  const Fixture& f = Fixture::Get();
  for (const auto& [seed, instance] : piles) {
    Result<Frame> frame = VariedPile(f.cell, seed);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    if (check_truth) {
      const PartTruth* part = TruthInstance(*frame, instance);
      ASSERT_NE(part, nullptr) << "pile " << seed;
      check_truth(*part, seed);
    }
    const VerdictCounts before = CountVerdicts(Fixture::RunWith(without, *frame), *frame, f.models, instance);
    const VerdictCounts after = CountVerdicts(Fixture::RunWith(with, *frame), *frame, f.models, instance);
    EXPECT_FALSE(before.found) << "pile " << seed << ": instance " << instance << " found without the rule";
    EXPECT_TRUE(after.found) << "pile " << seed << ": instance " << instance;
    EXPECT_LE(after.wrong, before.wrong) << "pile " << seed;
  }
}

// A tee whose neighbours hold few of the points within its reach is judged
// again on its own points when its pose is ambiguous: the fine pass's 30
// deg turn grid steps over a true turn whose peak is about 8 deg wide.
// Piles of the tuning range (--variety): 1043 (tee 14, fully visible,
// detected 13 deg off about its run, its true turn explaining 61 samples
// more) and 1133 (tee 2, seen 51%, 13 deg off), each found strictly.
TEST(PerceptionEval, AnAmbiguousTeeWithFewNeighboursIsTurnedAgainOnItsOwnPoints) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  for (const std::pair<unsigned, int>& pile : {std::pair{1043u, 14}, std::pair{1133u, 2}}) {
    Result<Frame> frame = VariedPile(f.cell, pile.first);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    const PerceptionResult result = f.Run(*frame);
    EXPECT_TRUE(CountVerdicts(result, *frame, f.models, pile.second).found)
        << "pile " << pile.first << ": tee " << pile.second;
  }
}

// A pipe tee whose nearer arm hides part of its own run: the depth jump at
// the arm's outline splits its samples into pieces no grid connectivity
// joins, each too little of the tee for a hypothesis. The residual groups
// touching across a depth jump, matched joined
// (PerceptionOptions::residual_across_jumps), hold the tee. Piles of the
// tuning range (--variety): 1034 (tee 18, fully visible: groups of 1017 and
// 453 samples 29 mm apart in depth across one cell) and 1072 (tee 12, fully
// visible: four pieces 16-27 mm apart in depth across 1-3 cells). Each tee is
// found only with the joined views, and they add no wrong detection.
TEST(PerceptionEval, ATeeSplitByItsOwnDepthJumpIsMatchedJoined) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  // Without the residual regions' look with the estimator's own normals too
  // (it finds the tee of pile 1034 in one of its pieces): the joined views'
  // effect alone.
  PerceptionOptions off;
  off.residual_across_jumps = false;
  off.residual_own_normals = false;
  PerceptionOptions on = off;
  on.residual_across_jumps = true;
  const std::unique_ptr<Perception> without = Perception::Build(f.cell, off).value();
  const std::unique_ptr<Perception> with = Perception::Build(f.cell, on).value();
  ExpectFoundOnlyWith(*without, *with, {{1034u, 18}, {1072u, 12}});
}

// A part whose residual region (its unexplained samples, once its
// neighbours are found) holds nearly only its own points, yet no class finds
// it there: the grid's normals (central differences about 2.5 mm away, on
// noisy, smoothed depth with grazing dropout) are too rough for the
// point-pair voting. Matched once more with the estimator's own normals
// (PerceptionOptions::residual_own_normals), it is found. Piles of the
// tuning range (--variety): 1034 (pipe tee 4, fully visible, a residual
// view of 1169 samples, all its own) and 1030 (L-bracket 17, fully visible,
// 835 samples, all its own). Each is found only with the rule, and it adds
// no wrong detection.
TEST(PerceptionEval, AResidualRegionNothingWasFoundInIsMatchedWithTheEstimatorsOwnNormals) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  PerceptionOptions off;
  off.residual_own_normals = false;
  const std::unique_ptr<Perception> without = Perception::Build(f.cell, off).value();
  ExpectFoundOnlyWith(*without, *f.perception, {{1034u, 4}, {1030u, 17}});
}

// A pipe tee standing on its branch, seen from above, shows only its run:
// a cylinder every turn about the run fits, and a coarse pose turned the
// wrong way puts the branch where the camera saw nothing and scores below
// the bar. Such a pose is turned about the run before it is rejected
// (PerceptionOptions::turns_below_bar, off by default). Piles of the tuning
// range (--variety): 1011 (tee 8, 92% visible) and 1033 (tee 3, 95%
// visible), both with the branch pointing down: missed without the turns
// (the default), found in the true pose with them, and no wrong detection
// more.
TEST(PerceptionEval, ATeeStandingOnItsBranchIsTurnedBeforeItIsRejected) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  PerceptionOptions on;
  on.turns_below_bar = true;
  on.second_look_search.turns_below_bar = true;
  const std::unique_ptr<Perception> with = Perception::Build(f.cell, on).value();
  ExpectFoundOnlyWith(*f.perception, *with, {{1011u, 8}, {1033u, 3}}, [](const PartTruth& tee, unsigned seed) {
    ASSERT_EQ(tee.class_id, 2) << "pile " << seed;
    // The branch (the tee's z) points down, away from the camera.
    EXPECT_LT(tee.X_BO.rotation().col(2).z(), -0.9) << "pile " << seed;
  });
}

// A flanged bushing fitted into a pipe tee's arm (its hub in the arm, the
// tee otherwise unexplained) is replaced by the tee fitted over its samples
// and the unexplained ones around it, once every other pass is done
// (PerceptionOptions::enclosing_parts). Piles of the tuning range
// (--variety): 1061 (tee 11, 57% visible) and 1090 (tee 13, 46%): without
// the pass a bushing is detected within 15 mm of the tee's origin and the
// tee not at all; with it the tee is found in its true pose and no bushing
// is left there.
TEST(PerceptionEval, ABushingInsideATeeIsReplacedByTheTee) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  PerceptionOptions off;
  off.enclosing_parts = false;
  const std::unique_ptr<Perception> without = Perception::Build(f.cell, off).value();
  for (const std::pair<unsigned, int>& pile : {std::pair{1061u, 11}, std::pair{1090u, 13}}) {
    const unsigned seed = pile.first;
    const int instance = pile.second;
    Result<Frame> frame = VariedPile(f.cell, seed);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    const PartTruth* tee = TruthInstance(*frame, instance);
    ASSERT_NE(tee, nullptr) << "pile " << seed;
    ASSERT_EQ(tee->class_id, 2) << "pile " << seed;
    // Marked: the bushings detected within 15 mm of the tee's origin.
    const VerdictMark bushing_in_tee = [tee](const DetectionOutcome&, const Detection& d) {
      return d.class_id == 0 && (d.X_BO.translation() - tee->X_BO.translation()).norm() < 0.015;
    };
    const VerdictCounts before =
        CountVerdicts(Fixture::RunWith(*without, *frame), *frame, f.models, instance, bushing_in_tee);
    const PerceptionResult result = f.Run(*frame);
    const VerdictCounts after = CountVerdicts(result, *frame, f.models, instance, bushing_in_tee);
    EXPECT_EQ(before.marked, 1) << "pile " << seed << ": no bushing in the tee without the pass";
    EXPECT_FALSE(before.found) << "pile " << seed;
    EXPECT_EQ(after.marked, 0) << "pile " << seed;
    EXPECT_TRUE(after.found) << "pile " << seed;
    EXPECT_LE(after.wrong, before.wrong - 1) << "pile " << seed;
    EXPECT_TRUE(std::any_of(result.timings.begin(), result.timings.end(),
                            [](const StageTiming& t) { return t.stage == "enclosing"; }));
  }
}

// A part mostly hidden whose pose is ambiguous is withheld, not answered
// in a guessed pose (PerceptionOptions::ambiguous_min_visible). Piles of
// the tuning range (--variety): 1002 (tee 6, 34% visible) and 1065 (tee
// 13, 34%), each tee's branch hidden: without the rule it is detected
// turned 82 and 159 deg about its run, carrying other turns as
// alternatives; with it that detection is withheld, and no other part
// loses its detection.
TEST(PerceptionEval, AnAmbiguousTeeMostlyHiddenIsWithheld) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  PerceptionOptions off;
  off.ambiguous_min_visible = 0.0;
  const std::unique_ptr<Perception> without = Perception::Build(f.cell, off).value();
  for (const std::pair<unsigned, int>& pile : {std::pair{1002u, 6}, std::pair{1065u, 13}}) {
    const unsigned seed = pile.first;
    const int instance = pile.second;
    Result<Frame> frame = VariedPile(f.cell, seed);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    // Marked: the gross detections nearest the tee, each with an ambiguous pose.
    const VerdictMark gross_on_tee = [instance, seed](const DetectionOutcome& o, const Detection& d) {
      if (o.verdict != DetectionVerdict::kGross || o.near_instance != instance) return false;
      EXPECT_TRUE(d.pose_ambiguous()) << "pile " << seed;
      return true;
    };
    const PerceptionResult before_result = Fixture::RunWith(*without, *frame);
    const VerdictCounts before = CountVerdicts(before_result, *frame, f.models, -1, gross_on_tee);
    const PerceptionResult result = f.Run(*frame);
    const VerdictCounts after = CountVerdicts(result, *frame, f.models, -1, gross_on_tee);
    EXPECT_EQ(before.marked, 1) << "pile " << seed << ": the tee not answered wrong without the rule";
    EXPECT_EQ(before_result.withheld_ambiguous, 0) << "pile " << seed;
    EXPECT_EQ(after.marked, 0) << "pile " << seed;
    EXPECT_GE(result.withheld_ambiguous, 1) << "pile " << seed;
    EXPECT_LE(after.wrong, before.wrong - 1) << "pile " << seed;
    EXPECT_EQ(after.right, before.right) << "pile " << seed;
    for (const Detection& d : result.detections) {
      EXPECT_FALSE(d.pose_ambiguous() && d.visible_fraction < f.perception->options().ambiguous_min_visible)
          << "pile " << seed;
    }
  }
}

// A part mostly hidden whose seen surface is one flat face is withheld
// (PerceptionOptions::one_plane_min_visible): the face fixes the plane, but
// not which of the part's flat faces it is or where on it the part lies.
// Piles of the tuning range (--variety, 640x480) where, without the rule,
// an L-bracket is detected where none lies (the nearest bracket 43 and 45
// mm away), its support on one plane, 0.17 and 0.23 of it seen (1110,
// 1193): the false detection is withheld and no right one is lost.
TEST(PerceptionEval, ADetectionSeenOnOnePlaneAndMostlyHiddenIsWithheld) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  PerceptionOptions off;
  off.one_plane_min_visible = 0.0;
  const std::unique_ptr<Perception> without = Perception::Build(f.cell, off).value();
  for (const unsigned seed : {1110u, 1193u}) {
    Result<Frame> frame = VariedPile(f.cell, seed);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    // Marked: the false L-bracket detections.
    const VerdictMark false_bracket = [](const DetectionOutcome& o, const Detection&) {
      return o.verdict == DetectionVerdict::kFalse && o.class_id == 1;
    };
    const PerceptionResult before_result = Fixture::RunWith(*without, *frame);
    const VerdictCounts before = CountVerdicts(before_result, *frame, f.models, -1, false_bracket);
    const PerceptionResult result = f.Run(*frame);
    const VerdictCounts after = CountVerdicts(result, *frame, f.models, -1, false_bracket);
    EXPECT_GE(before.marked, 1) << "pile " << seed << ": no false bracket without the rule";
    EXPECT_EQ(before_result.withheld_one_plane, 0) << "pile " << seed;
    EXPECT_EQ(after.marked, before.marked - 1) << "pile " << seed;
    EXPECT_GE(result.withheld_one_plane, 1) << "pile " << seed;
    EXPECT_LE(after.wrong, before.wrong - 1) << "pile " << seed;
    EXPECT_EQ(after.right, before.right) << "pile " << seed;
  }
}

// Grazing dropout (--variety) leaves an L-bracket seen nearly edge-on with
// half the model samples in view over pixels without depth; counted against
// the pose, its true pose scored 0.43-0.45 on its own points (below the 0.6
// bar) and the bracket was never found. As no evidence
// (PerceptionOptions::unmeasured_is_no_evidence) it is. Piles of the tuning
// range: 1012 (bracket 13, fully visible) and 1020 (bracket 15, fully
// visible).
TEST(PerceptionEval, ABracketWhoseGrazingFacesDroppedOutIsFound) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  PerceptionOptions off;
  off.unmeasured_is_no_evidence = false;
  off.second_look_search.unmeasured_is_no_evidence = false;
  const std::unique_ptr<Perception> without = Perception::Build(f.cell, off).value();
  ExpectFoundOnlyWith(*without, *f.perception, {{1012u, 13}, {1020u, 15}});
}

// PoseEstimator::Score gives the score Estimate would: with the options'
// unmeasured_is_no_evidence (what perception hands every class), a grazing
// face over pixels without depth is left out of the denominator. The eval's
// causes score a missed part's truth with it: counted against, 26 of the 28
// L-brackets "below the bar" on the tuning range scored 0.81-0.98 by the
// pipeline's rule. Pile 1012 of the tuning range (--variety): bracket 13,
// fully visible, its grazing faces dropped out.
TEST(PerceptionEval, ScoreVerifiesByTheEstimatorsUnmeasuredRule) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  Result<Frame> frame = VariedPile(f.cell, 1012u);
  ASSERT_TRUE(frame.ok()) << frame.status().ToString();
  const PartTruth* bracket = TruthInstance(*frame, 13);
  ASSERT_NE(bracket, nullptr);
  ASSERT_EQ(bracket->class_id, 1);
  const PerceptionResult r = f.Run(*frame);
  SceneView view;
  view.points_B = r.roi_points_B;
  view.X_BC = frame->X_BC;
  view.depth = &frame->depth;
  view.intrinsics = frame->intrinsics;
  const TriangleMesh& mesh = *f.meshes[2];  // the bin, then the parts by class id
  PoseEstimatorOptions counted;
  PoseEstimatorOptions no_evidence;
  no_evidence.unmeasured_is_no_evidence = true;
  const auto against = PoseEstimator::Build(mesh, f.cell.parts[1].symmetry, counted).value()->Score(view, bracket->X_BO);
  const auto left_out = PoseEstimator::Build(mesh, f.cell.parts[1].symmetry, no_evidence).value()->Score(view, bracket->X_BO);
  ASSERT_TRUE(against.ok() && left_out.ok());
  EXPECT_EQ(against->visible_points, left_out->visible_points);
  EXPECT_EQ(against->supported_points, left_out->supported_points);
  ASSERT_GT(left_out->unmeasured_points, 0) << "no grazing face without depth: nothing to leave out";
  const double net = left_out->supported_points - left_out->free_space_points;
  const int seen = left_out->visible_points - left_out->occluded_points;
  EXPECT_NEAR(against->score, net / seen, 1e-9);
  EXPECT_NEAR(left_out->score, net / (seen - left_out->unmeasured_points), 1e-9);
  EXPECT_GE(left_out->score, 0.6);
  EXPECT_LT(against->score, 0.6);
}

// Two true neighbours whose surface centres lie within 0.3 of the larger
// diameter (NMS in acceptance) were one part to acceptance: the lower
// score lost though the two share no point and do not interpenetrate. A
// candidate near an accepted detection's centre now conflicts with it only
// when a share of its support lies on that detection's surface
// (PerceptionOptions::near_centre_min_shared). Piles of the tuning range
// (--variety): 1053 (L-bracket 17, fully visible, score 0.981, replaced by
// flanged bushing 19 at 0.982, surface centres 33 mm apart) and 1037
// (L-bracket 20, fully visible, 0.910, lost to L-bracket 17 at 0.937, 29 mm
// apart). Each bracket is found only with the rule, its neighbour stays
// found, and no wrong detection is added.
TEST(PerceptionEval, NeighboursWithCloseSurfaceCentresAreBothKept) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  PerceptionOptions off;
  off.near_centre_min_shared = 0.0;
  const std::unique_ptr<Perception> without = Perception::Build(f.cell, off).value();
  ExpectFoundOnlyWith(*without, *f.perception, {{1053u, 17}, {1037u, 20}});
  for (const auto& [seed, neighbour] : {std::pair{1053u, 19}, std::pair{1037u, 17}}) {
    Result<Frame> frame = VariedPile(f.cell, seed);
    ASSERT_TRUE(frame.ok()) << frame.status().ToString();
    EXPECT_TRUE(CountVerdicts(Fixture::RunWith(*f.perception, *frame), *frame, f.models, neighbour).found)
        << "pile " << seed << ": neighbour " << neighbour;
  }
}

// An L-bracket lying on its side, seen edge-on: the camera sees its side
// face, the L of its two plates 5 mm wide, 2-4 pixels at 640x480, with
// mixed pixels behind its outline. The view's least-squares plane leans to
// them (RMS past 1 mm), so it was not planar, got no face seeds, and point
// pair voting on one plane found nothing. With the share test
// (PerceptionOptions::planar_view_min_share) the view is planar and the
// face seeds, fitted to the plane's points, lay the side face on it. Piles
// of the tuning range (--variety): 1072 (bracket 1, 96% visible) and 1085
// (bracket 14, fully visible), each seen within 25 deg of its y axis.
TEST(PerceptionEval, ABracketSeenEdgeOnThroughMixedPixelsIsFoundByItsFaceSeeds) {
  Fixture& f = Fixture::Get();
  if (!f.renderer) GTEST_SKIP() << "no OSMesa renderer";
  PerceptionOptions off;
  off.planar_view_min_share = 0.0;
  const std::unique_ptr<Perception> without = Perception::Build(f.cell, off).value();
  ExpectFoundOnlyWith(*without, *f.perception, {{1072u, 1}, {1085u, 14}}, [&](const PartTruth& bracket, unsigned seed) {
    Result<Frame> frame = VariedPile(f.cell, seed);
    ASSERT_TRUE(frame.ok());
    const Vec3 to_camera = (bracket.X_BO.inverse() * frame->X_BC.translation()).normalized();
    EXPECT_EQ(bracket.class_id, 1) << "pile " << seed;
    EXPECT_GT(std::abs(to_camera.y()), std::cos(25.0 * kDeg)) << "pile " << seed << ": not seen edge-on";
  });
}

}  // namespace
}  // namespace bp
