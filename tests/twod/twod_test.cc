// 2D tasks: plane calibration against the synthetic camera's true geometry,
// detection against ground truth, footprint collisions, cell keys.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <random>

#include "core/atomic_file.h"
#include "tests/testing/files.h"
#include "tests/testing/twod.h"
#include "twod/detector_2d.h"
#include "twod/plane_calibration.h"
#include "twod/plane_camera.h"
#include "twod/planner_2d.h"

namespace bp {
namespace {

using testing::CalibrateWithMarker;
using testing::LoadTwodCell;

double AngleDiffDeg(double a, double b) { return std::abs(WrapAngle(a - b)) * 180.0 / M_PI; }

TEST(PlaneCalibration, MarkerGridFitMapsHeldOutPointsWithinATenthOfAMillimetre) {
  const Cell cell = LoadTwodCell();
  auto camera = std::move(SyntheticPlaneCamera::Create(cell).value());
  Result<PlaneCalibration> c = CalibrateWithMarker(*camera);
  ASSERT_TRUE(c.ok()) << c.status().ToString();
  EXPECT_EQ(c->points, 20);
  EXPECT_LE(c->residual_rms_mm, 0.2);
  std::printf("2D calibration: %d points, residual %.4f mm rms, %.4f mm max\n", c->points, c->residual_rms_mm,
              c->residual_max_mm);
  // Held-out points (not on the grid), at the plane and 4 mm above it: the
  // true projection mapped back through the calibration.
  std::mt19937 rng{42};
  std::uniform_real_distribution<double> ux(-0.2, 0.2), uy(-0.14, 0.14);
  double worst = 0;
  for (int i = 0; i < 50; ++i) {
    for (double h : {0.0, 0.004}) {
      const Vec3 p(ux(rng), uy(rng), h);
      const Vec3 q = camera->X_CP() * p;
      // The true pixel: OpenCV's distorted pinhole (k1, k2, p1, p2, k3).
      const Intrinsics& K = cell.camera.configs[0].intrinsics;
      const double x = q.x() / q.z(), y = q.y() / q.z();
      const double r2 = x * x + y * y;
      const auto& d = K.distortion;
      const double radial = 1 + d[0] * r2 + d[1] * r2 * r2 + d[4] * r2 * r2 * r2;
      const double xd = x * radial + 2 * d[2] * x * y + d[3] * (r2 + 2 * x * x);
      const double yd = y * radial + d[2] * (r2 + 2 * y * y) + 2 * d[3] * x * y;
      const Eigen::Vector2d uv(K.fx * xd + K.cx, K.fy * yd + K.cy);
      const Eigen::Vector2d back = c->PixelToPlane(uv, h);
      worst = std::max(worst, (back - p.head<2>()).norm() * 1000);
    }
  }
  std::printf("2D calibration: held-out points worst error %.4f mm\n", worst);
  EXPECT_LE(worst, 0.1);
}

TEST(PlaneCalibration, SurvivesASaveLoadRoundTripAndRejectsACorruptFile) {
  const Cell cell = LoadTwodCell();
  auto camera = std::move(SyntheticPlaneCamera::Create(cell).value());
  const PlaneCalibration c = CalibrateWithMarker(*camera, 3, 3).value();
  const std::string dir = testing::FreshDir("calib");
  const std::string path = dir + "/plane.yaml";
  ASSERT_TRUE(SavePlaneCalibration(c, path).ok());
  ASSERT_TRUE(SavePlaneCalibration(c, path).ok());
  EXPECT_TRUE(std::filesystem::exists(AtomicBackupPath(path)));
  Result<PlaneCalibration> back = LoadPlaneCalibration(path);
  ASSERT_TRUE(back.ok()) << back.status().ToString();
  EXPECT_LT((back->PixelToPlane({100, 200}) - c.PixelToPlane({100, 200})).norm(), 1e-9);
  EXPECT_EQ(back->points, 9);

  std::string text = testing::ReadBytes(path);
  text.replace(text.find("homography: ["), 13, "homography: [x, ");
  testing::WriteText(path, text);
  Result<PlaneCalibration> bad = LoadPlaneCalibration(path);
  ASSERT_FALSE(bad.ok());
  EXPECT_NE(bad.status().message().find(path), std::string::npos) << bad.status().ToString();
  EXPECT_EQ(LoadPlaneCalibration(dir + "/missing.yaml").status().code(), Status::Code::kNotFound);
}

TEST(PlaneCalibration, RejectsCollinearPoints) {
  Intrinsics K;
  K.width = 640, K.height = 480, K.fx = K.fy = 500, K.cx = 320, K.cy = 240;
  std::vector<Eigen::Vector2d> px, xy;
  for (int i = 0; i < 6; ++i) {
    px.emplace_back(100 + 50 * i, 240);
    xy.emplace_back(0.01 * i, 0.0);
  }
  EXPECT_EQ(FitPlaneCalibration(K, px, xy).status().code(), Status::Code::kInvalidArgument);
}

// Scenes per method: 4 in the suite; BINPICK_TWOD_SCENES=N measures more.
int Scenes() {
  const char* n = std::getenv("BINPICK_TWOD_SCENES");
  return n ? std::max(1, std::atoi(n)) : 4;
}

struct Errors {
  int truths = 0, matched = 0, wrong_class = 0;
  double max_mm = 0, max_deg = 0, sum_mm = 0, sum_deg = 0;
};

// Each true part against its nearest detection: the grasp point of the
// part's first 2D grasp (position) and the part's rotation.
Errors Measure(const Cell& cell, Match2DMethod method, int scenes) {
  auto camera = std::move(SyntheticPlaneCamera::Create(cell).value());
  const PlaneCalibration c = CalibrateWithMarker(*camera).value();
  Detector2DOptions options;
  options.method = method;
  const Detector2D detector(cell, options);
  Errors e;
  for (int seed = 1; seed <= scenes; ++seed) {
    EXPECT_TRUE(camera->Scatter(8, static_cast<uint64_t>(seed)).ok());
    const PlaneImage image = camera->Capture({}).value();
    const Detect2DResult r = detector.Detect(image.image, c).value();
    for (const FlatPartTruth& t : image.truth) {
      ++e.truths;
      const Detection2D* best = nullptr;
      for (const Detection2D& d : r.parts) {
        if ((d.X_PO.xy() - t.X_PO.xy()).norm() < 0.01) best = &d;
      }
      if (!best) continue;
      if (best->class_id != t.class_id) {
        ++e.wrong_class;
        continue;
      }
      ++e.matched;
      const Grasp2DSpec& g = cell.FindPart(t.class_id)->flat_2d->grasps.front();
      const double mm = (best->X_PO.Apply(g.xy) - t.X_PO.Apply(g.xy)).norm() * 1000;
      const double deg = AngleDiffDeg(best->X_PO.theta, t.X_PO.theta);
      e.max_mm = std::max(e.max_mm, mm);
      e.max_deg = std::max(e.max_deg, deg);
      e.sum_mm += mm;
      e.sum_deg += deg;
    }
  }
  std::printf("2D detection (%s): %d/%d parts, %d wrong class, grasp point max %.3f mm mean %.3f mm, "
              "rotation max %.3f deg mean %.3f deg\n",
              method == Match2DMethod::kMoments ? "contours+moments" : "rotated template", e.matched, e.truths,
              e.wrong_class, e.max_mm, e.sum_mm / std::max(1, e.matched), e.max_deg,
              e.sum_deg / std::max(1, e.matched));
  return e;
}

TEST(Detector2D, RotatedTemplateFindsEveryPartWithinHalfAMillimetreAndHalfADegree) {
  const Cell cell = LoadTwodCell();
  const Errors e = Measure(cell, Match2DMethod::kRotatedTemplate, Scenes());
  EXPECT_EQ(e.matched, e.truths);
  EXPECT_EQ(e.wrong_class, 0);
  EXPECT_LE(e.max_mm, 0.5);
  EXPECT_LE(e.max_deg, 0.5);
}

TEST(Detector2D, ContoursAndMomentsFindEveryPartWithinHalfAMillimetreAndHalfADegree) {
  const Cell cell = LoadTwodCell();
  const Errors e = Measure(cell, Match2DMethod::kMoments, Scenes());
  EXPECT_EQ(e.matched, e.truths);
  EXPECT_EQ(e.wrong_class, 0);
  EXPECT_LE(e.max_mm, 0.5);
  EXPECT_LE(e.max_deg, 0.5);
}

TEST(Detector2D, FindsTheMarkerCentreToATenthOfAPixel) {
  const Cell cell = LoadTwodCell();
  auto camera = std::move(SyntheticPlaneCamera::Create(cell).value());
  PlaneCaptureRequest request;
  request.marker_X_PT = MakePose(Mat3::Identity(), Vec3(0.05, -0.03, 0.0));
  const PlaneImage image = camera->Capture(request).value();
  const Eigen::Vector2d found = FindMarker(image.image).value();
  // Truth: the calibration-free projection of the marker centre.
  const Vec3 q = camera->X_CP() * Vec3(0.05, -0.03, 0.0);
  const Intrinsics K = camera->intrinsics();
  const double x = q.x() / q.z(), y = q.y() / q.z(), r2 = x * x + y * y;
  const auto& d = K.distortion;
  const double radial = 1 + d[0] * r2 + d[1] * r2 * r2 + d[4] * r2 * r2 * r2;
  const Eigen::Vector2d truth(K.fx * (x * radial + 2 * d[2] * x * y + d[3] * (r2 + 2 * x * x)) + K.cx,
                              K.fy * (y * radial + d[2] * (r2 + 2 * y * y) + 2 * d[3] * x * y) + K.cy);
  EXPECT_LT((found - truth).norm(), 0.1) << found.transpose() << " vs " << truth.transpose();
  // An empty plane has no marker.
  EXPECT_EQ(FindMarker(camera->Capture({}).value().image).status().code(), Status::Code::kNotFound);
}

TEST(PolygonsOverlap, DetectsVertexInsideAndCrossingEdges) {
  const std::vector<Eigen::Vector2d> square = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  const std::vector<Eigen::Vector2d> inside_vertex = {{0.5, 0.5}, {2, 0.5}, {2, 2}};
  const std::vector<Eigen::Vector2d> cross = {{-0.5, 0.4}, {1.5, 0.4}, {1.5, 0.6}, {-0.5, 0.6}};
  const std::vector<Eigen::Vector2d> apart = {{2, 2}, {3, 2}, {3, 3}};
  EXPECT_TRUE(PolygonsOverlap(square, inside_vertex));
  EXPECT_TRUE(PolygonsOverlap(square, cross));
  EXPECT_FALSE(PolygonsOverlap(square, apart));
}

// A gripper with a 120 mm square footprint: two parts 20 cm apart are both
// pickable; 2 cm apart, every grasp's footprint overlaps the other part.
TEST(Plane2DPlanner, FootprintOverlappingANeighbourIsNoCollisionFree) {
  Cell cell = LoadTwodCell();
  cell.grippers[0].footprint = {{-0.06, -0.06}, {0.06, -0.06}, {0.06, 0.06}, {-0.06, 0.06}};
  std::shared_ptr<SyntheticPlaneCamera> camera = std::move(SyntheticPlaneCamera::Create(cell).value());
  auto store = std::make_shared<PlaneCalibrationStore>();
  store->Set(CalibrateWithMarker(*camera).value());
  Plane2DPlanner planner(cell, camera, store);
  PlanRequest request;
  request.task = *cell.FindTask(0);
  auto plan = [&](double dy) {
    camera->SetParts({{1, 0, {-0.05, 0.0, 0.0}}, {2, 1, {-0.05, dy, 0.3}}});
    const CaptureHandle scene = planner.Capture(request).value();
    return planner.Plan(request, *scene).value();
  };
  const PlanResult apart = plan(-0.2);
  EXPECT_EQ(apart.outcome, PlanResult::Outcome::kGrasps) << apart.message;
  EXPECT_EQ(apart.detections, 2);
  EXPECT_EQ(apart.grasps.size(), 2u);

  const PlanResult close = plan(-0.045);
  EXPECT_EQ(close.detections, 2) << close.message;
  EXPECT_EQ(close.outcome, PlanResult::Outcome::kNoCollisionFree) << close.message;
  EXPECT_TRUE(close.grasps.empty());

  // With the cell's own 40 x 28 mm footprint the same close pair is pickable.
  Cell small = LoadTwodCell();
  Plane2DPlanner small_planner(small, camera, store);
  const CaptureHandle scene = small_planner.Capture(request).value();
  const PlanResult fine = small_planner.Plan(request, *scene).value();
  EXPECT_EQ(fine.outcome, PlanResult::Outcome::kGrasps) << fine.message;
}

TEST(Plane2DPlanner, WithoutCalibrationThePlannerReportsUnavailable) {
  const Cell cell = LoadTwodCell();
  std::shared_ptr<SyntheticPlaneCamera> camera = std::move(SyntheticPlaneCamera::Create(cell).value());
  Plane2DPlanner planner(cell, camera, std::make_shared<PlaneCalibrationStore>());
  PlanRequest request;
  request.task = *cell.FindTask(0);
  const CaptureHandle scene = planner.Capture(request).value();
  EXPECT_EQ(planner.Plan(request, *scene).status().code(), Status::Code::kUnavailable);
}

// A 3D planner double that counts its calls and captures nothing.
class Counting3DPlanner final : public GraspPlanner {
 public:
  struct Scene final : CapturedScene {
    std::string Describe() const override { return "3d"; }
  };
  Result<CaptureHandle> Capture(const PlanRequest&) override {
    ++captures;
    return CaptureHandle(std::make_shared<const Scene>());
  }
  Result<PlanResult> Plan(const PlanRequest&, const CapturedScene& scene) override {
    ++plans;
    EXPECT_NE(dynamic_cast<const Scene*>(&scene), nullptr);
    return PlanResult{};
  }
  int captures = 0, plans = 0;
};

TEST(TaskKindPlanner, RoutesPick2DTasksToThe2DPlannerAndTheRestTo3D) {
  Cell cell = LoadTwodCell();
  TaskSpec pick3d;
  pick3d.id = 7;
  pick3d.kind = TaskSpec::Kind::kPick;
  pick3d.gripper = "suction";
  cell.tasks.push_back(pick3d);
  std::shared_ptr<SyntheticPlaneCamera> camera = std::move(SyntheticPlaneCamera::Create(cell).value());
  ASSERT_TRUE(camera->Scatter(3, 2).ok());
  auto store = std::make_shared<PlaneCalibrationStore>();
  store->Set(CalibrateWithMarker(*camera, 3, 3).value());
  auto counting = std::make_unique<Counting3DPlanner>();
  Counting3DPlanner* three_d = counting.get();
  TaskKindPlanner planner(std::move(counting), std::make_unique<Plane2DPlanner>(cell, camera, store));

  PlanRequest r2;
  r2.task = *cell.FindTask(0);
  const CaptureHandle s2 = planner.Capture(r2).value();
  const PlanResult p2 = planner.Plan(r2, *s2).value();
  EXPECT_EQ(p2.detections, 3);
  EXPECT_EQ(three_d->captures, 0);

  PlanRequest r3;
  r3.task = *cell.FindTask(7);
  const CaptureHandle s3 = planner.Capture(r3).value();
  EXPECT_TRUE(planner.Plan(r3, *s3).ok());
  EXPECT_EQ(three_d->captures, 1);
  EXPECT_EQ(three_d->plans, 1);
  // Without a 3D planner, 3D tasks are Unavailable.
  TaskKindPlanner only_2d(nullptr, std::make_unique<Plane2DPlanner>(cell, camera, store));
  EXPECT_EQ(only_2d.Capture(r3).status().code(), Status::Code::kUnavailable);
}

TEST(PlanePose, IsATurnAboutThePlaneNormalWithTheToolPointingDown) {
  const Pose X = PlanePose({0.1, -0.2, 0.7}, 0.004);
  EXPECT_NEAR((X.linear().col(2) - Vec3(0, 0, -1)).norm(), 0, 1e-12);
  const Pose2D back = ToPose2D(X);
  EXPECT_NEAR(back.x, 0.1, 1e-12);
  EXPECT_NEAR(back.y, -0.2, 1e-12);
  EXPECT_NEAR(back.theta, 0.7, 1e-12);
}

TEST(Cell2D, RejectsAGraspOutsideTheOutlineAndAPick2DTaskWithoutFootprint) {
  std::string text = testing::ReadBytes(AssetsDir() + "/cells/twod.yaml");
  const std::string base = AssetsDir() + "/cells/x.yaml";
  std::string outside = text;
  outside.replace(outside.find("xy: [0.05, 0.01]"), 16, "xy: [0.05, 0.04]");
  Result<Cell> a = ParseCell(outside, base);
  ASSERT_FALSE(a.ok());
  EXPECT_NE(a.status().message().find("parts[0].flat_2d.grasps[0].xy: grasp point is outside the outline"),
            std::string::npos)
      << a.status().ToString();
  std::string no_footprint = text;
  const size_t f = no_footprint.find("    footprint:");
  no_footprint.erase(f, no_footprint.find('\n', f) - f + 1);
  Result<Cell> b = ParseCell(no_footprint, base);
  ASSERT_FALSE(b.ok());
  EXPECT_NE(b.status().message().find("tasks[0].gripper: a pick_2d task's gripper needs a footprint"),
            std::string::npos)
      << b.status().ToString();
  std::string crossing = text;
  crossing.replace(crossing.find("[[-0.02, -0.014], [0.02, -0.014], [0.02, 0.014], [-0.02, 0.014]]"), 64,
                   "[[-0.02, -0.014], [0.02, 0.014], [0.02, -0.014], [-0.02, 0.014]]");
  Result<Cell> c = ParseCell(crossing, base);
  ASSERT_FALSE(c.ok());
  EXPECT_NE(c.status().message().find("grippers[0].footprint: edges 0 and 2 cross"), std::string::npos)
      << c.status().ToString();
}

}  // namespace
}  // namespace bp
