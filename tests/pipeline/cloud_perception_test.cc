// Perception on unorganized clouds (issue 46): a rendered frame's points as
// a point list, organized again by ProjectCloud, give the frame's
// detections; written in another frame (no pixel lattice), they give the same
// parts within the strict tolerance (5 mm, 5 deg modulo symmetry).
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>
#include <memory>
#include <random>
#include <set>
#include <vector>

#include <gtest/gtest.h>
#include <tbb/task_arena.h>

#include "pipeline/capture_source.h"
#include "pipeline/cloud_projection.h"
#include "pipeline/evaluation.h"
#include "pipeline/file_source.h"
#include "pipeline/frame_io.h"
#include "pipeline/perception.h"
#include "pipeline/synthetic_source.h"

namespace bp {
namespace {

constexpr double kTolM = 0.005;
constexpr double kTolRad = 5.0 * M_PI / 180.0;

struct Fixture {
  Cell cell;
  std::unique_ptr<Perception> perception;
  std::vector<EvalPartModel> models;

  static Fixture& Get() {
    static Fixture* f = [] {
      auto* fx = new Fixture;
      fx->cell = *LoadDefaultCell();
      fx->cell.source.simulate_picks = false;
      fx->perception = Perception::Build(fx->cell).value();
      fx->models = LoadEvalModels(fx->cell).value();
      return fx;
    }();
    return *f;
  }

  // The default cell's pile `seed` through camera config 1 (640x480), or an
  // error when there is no renderer.
  Result<Frame> Pile(uint64_t seed) const {
    Cell c = cell;
    c.source.kind = SourceSpec::Kind::kSynthetic;
    c.source.seed = seed;
    auto source = MakeSyntheticSource(c);
    if (!source.ok()) return source.status();
    return (*source)->Capture({});
  }

  PerceptionResult Run(const Frame& frame) const {
    tbb::task_arena arena(2);
    Result<PerceptionResult> r = Status::Internal("not run");
    arena.execute([&] { r = perception->Run(frame); });
    EXPECT_TRUE(r.ok()) << r.status().ToString();
    return r.ok() ? *r : PerceptionResult{};
  }

  const EvalPartModel& Model(int class_id) const {
    return *std::find_if(models.begin(), models.end(), [&](const EvalPartModel& m) { return m.class_id == class_id; });
  }

  // Instances found strictly: a detection of the part's class within 5 mm
  // and 5 deg of its pose, modulo the part's symmetry.
  std::set<int> FoundStrictly(const PerceptionResult& r, const GroundTruth& truth) const {
    std::set<int> found;
    for (const Detection& d : r.detections) {
      for (const PartTruth& p : truth.parts) {
        if (p.class_id != d.class_id) continue;
        const Symmetry& s = Model(p.class_id).symmetry;
        if (SymmetryAwareTranslationError(d.X_BO, p.X_BO, s) <= kTolM &&
            SymmetryAwareRotationError(d.X_BO, p.X_BO, s) <= kTolRad) {
          found.insert(p.instance_id);
        }
      }
    }
    return found;
  }
};

// The frame's points as a point list in a seeded random order, in C or
// written in a frame F turned X_CF from C.
Frame AsCloud(const Frame& frame, const Pose& X_CF = Pose::Identity()) {
  Frame cloud;
  cloud.X_BC = frame.X_BC * X_CF;
  cloud.truth = frame.truth;
  cloud.source = frame.source;
  const Pose X_FC = X_CF.inverse();
  for (const Eigen::Vector3f& p : frame.PointsInCamera()) cloud.points_C.push_back((X_FC * p.cast<double>()).cast<float>());
  std::mt19937 rng{46};
  std::shuffle(cloud.points_C.begin(), cloud.points_C.end(), rng);
  return cloud;
}

TEST(CloudPerception, AnUnorganizedCopyOfARenderedFrameGivesTheSameDetections) {
  const Fixture& f = Fixture::Get();
  const Result<Frame> frame = f.Pile(21);
  if (!frame.ok()) GTEST_SKIP() << "no renderer: " << frame.status().ToString();
  Result<CloudProjection> projected = ProjectCloud(AsCloud(*frame), f.cell, /*X_BC_known=*/true);
  ASSERT_TRUE(projected.ok()) << projected.status().ToString();
  ASSERT_EQ(projected->grid, CloudGrid::kCameraConfig);
  const PerceptionResult a = f.Run(*frame), b = f.Run(projected->frame);
  ASSERT_GE(a.detections.size(), 10u);
  ASSERT_EQ(a.detections.size(), b.detections.size());
  for (size_t i = 0; i < a.detections.size(); ++i) {
    EXPECT_EQ(a.detections[i].class_id, b.detections[i].class_id) << i;
    EXPECT_TRUE(a.detections[i].X_BO.isApprox(b.detections[i].X_BO, 1e-9)) << i;
  }
}

// A vendor tool's frame 5 deg and 2 cm off the camera: the points are on no
// pixel lattice of the view, each moves up to 0.7 px sideways to its pixel.
TEST(CloudPerception, ACopyWrittenInAnotherFrameFindsTheSamePartsWithinTolerance) {
  const Fixture& f = Fixture::Get();
  int found_frame = 0, found_cloud = 0, only_frame = 0;
  for (uint64_t seed : {21u, 22u}) {
    const Result<Frame> frame = f.Pile(seed);
    if (!frame.ok()) GTEST_SKIP() << "no renderer: " << frame.status().ToString();
    const Pose X_CF = MakePose(Quat(Eigen::AngleAxisd(5 * M_PI / 180, Vec3(1, 1, 0).normalized())),
                               Vec3(0.01, -0.02, 0.005));
    Result<CloudProjection> projected = ProjectCloud(AsCloud(*frame, X_CF), f.cell, true);
    ASSERT_TRUE(projected.ok()) << projected.status().ToString();
    ASSERT_EQ(projected->grid, CloudGrid::kFromSpacing);
    const PerceptionResult a = f.Run(*frame), b = f.Run(projected->frame);
    const std::set<int> in_frame = f.FoundStrictly(a, *frame->truth), in_cloud = f.FoundStrictly(b, *frame->truth);
    found_frame += static_cast<int>(in_frame.size());
    found_cloud += static_cast<int>(in_cloud.size());
    for (int id : in_frame) only_frame += in_cloud.count(id) ? 0 : 1;
    // No more false detections than the frame's, give or take one.
    EXPECT_LE(b.detections.size() - in_cloud.size(), a.detections.size() - in_frame.size() + 1) << seed;
  }
  // Measured over seeds 1001-1020: 297 parts found against 301 (docs/tuning.md).
  EXPECT_GE(found_frame, 20);
  EXPECT_GE(found_cloud, found_frame - 2) << found_cloud << " of the frames' " << found_frame;
  EXPECT_LE(only_frame, 3) << found_cloud << " of the frames' " << found_frame;
}

// tests/pipeline/data/clouds (its README): five clouds written by Open3D,
// PCL and by hand, each against its frame's depth image. The four on a pixel
// lattice find the depth image's parts with its detections; the merged one
// the same parts, give or take one.
TEST(CloudPerception, CloudsFromOtherToolsFindWhatTheirDepthImagesFind) {
  const Fixture& f = Fixture::Get();
  const std::string dir = std::string(BINPICK_SOURCE_DIR) + "/tests/pipeline/data/clouds";
  const Result<std::vector<std::string>> files = ListFrameFiles(dir);
  ASSERT_TRUE(files.ok()) << files.status().ToString();
  ASSERT_EQ(files->size(), 5u);
  int found_depth = 0, found_cloud = 0;
  for (const std::string& path : *files) {
    const std::string name = std::filesystem::path(path).filename().string();
    const std::string stem = name.substr(0, name.find("_cloud"));
    std::string assumption;
    const Result<Frame> cloud = LoadFrameForPerception(path, f.cell, f.cell.camera.X_BC, &assumption);
    ASSERT_TRUE(cloud.ok()) << cloud.status().ToString();
    EXPECT_TRUE(assumption.empty()) << assumption;
    ASSERT_TRUE(cloud->organized() && cloud->truth.has_value()) << name;
    const Result<Frame> depth = LoadFrameFile(dir + "/depth/" + stem + "_depth.png");
    ASSERT_TRUE(depth.ok()) << depth.status().ToString();
    const PerceptionResult a = f.Run(*depth), b = f.Run(*cloud);
    const std::set<int> in_depth = f.FoundStrictly(a, *depth->truth), in_cloud = f.FoundStrictly(b, *cloud->truth);
    found_depth += static_cast<int>(in_depth.size());
    found_cloud += static_cast<int>(in_cloud.size());
    if (stem.find("merged") == std::string::npos) {
      // On the camera's own lattice: the depth image's detections.
      EXPECT_EQ(in_cloud, in_depth) << name;
      ASSERT_EQ(a.detections.size(), b.detections.size()) << name;
      // The same detections within the strict tolerance: the cloud's image
      // is the crop's window of the camera's, and its frame's figures
      // (noise, bands) move the poses by micrometres, a rare one further
      // (a millimetre cloud's: 0.3 mm, 2 deg).
      for (size_t i = 0; i < a.detections.size(); ++i) {
        const Detection &da = a.detections[i], &db = b.detections[i];
        ASSERT_EQ(da.class_id, db.class_id) << name << " " << i;
        const Symmetry& sym = f.Model(da.class_id).symmetry;
        EXPECT_LE(SymmetryAwareTranslationError(da.X_BO, db.X_BO, sym), kTolM) << name << " " << i;
        EXPECT_LE(SymmetryAwareRotationError(da.X_BO, db.X_BO, sym), kTolRad) << name << " " << i;
      }
    }
  }
  EXPECT_GE(found_depth, 20);
  // The merged cloud (no lattice) finds fewer than its depth image: 2 of its
  // 3 at the 0.7 detection bar, 2 of 4 at 0.6 (binpick eval --source
  // files:tests/pipeline/data/clouds[/depth] --min-score S: 28 / 29 and
  // 29 / 31 over the five frames). The residual groups joined across depth
  // jumps (PerceptionOptions::residual_across_jumps) find 2 parts more in
  // the depth images and 1 in the clouds (--residual-across-jumps 0 / 1:
  // 37 -> 39 and 35 -> 36 detections, none wrong more): 3 fewer. An
  // ambiguous tee turned again on its own points (RedecideTurns, organized
  // frames only: not the merged cloud) is right in the merged frame's depth
  // image (binpick eval --source files:tests/pipeline/data/clouds/depth:
  // gross 2 -> 1, the clouds' 2 both): 4 fewer.
  EXPECT_GE(found_cloud, found_depth - 4);
}

}  // namespace
}  // namespace bp
