// Perception beyond the shipped parts (issue 42): parts of 12 mm and 250 mm,
// a 3 mm sheet lying flat, a 50k-triangle mesh, a camera tilted 15 deg and
// rolled; meshes in the wrong unit refused naming it; a class whose model
// cannot be built refused unless optional. Every part here is made in the
// test (no shipped mesh); piles are rendered by the synthetic source.
#include <gtest/gtest.h>

#include <chrono>
#include <cstdio>
#include <memory>
#include <string>
#include <vector>

#include <Eigen/Geometry>
#include <tbb/task_arena.h>

#include "core/cell.h"
#include "core/mesh.h"
#include "pipeline/capture_source.h"
#include "pipeline/perception.h"
#include "pipeline/pose_estimator.h"
#include "tests/pipeline/pose_test_util.h"
#include "tests/testing/files.h"

namespace bp {
namespace {

using testing::AddQuad;

// An L profile in xz (base L x t, upright t x H at x = 0) extruded W along y,
// centred on y = 0: a bracket of any size, one closed solid.
TriangleMesh ExtrudedL(float L, float H, float t, float W) {
  TriangleMesh m;
  const float y0 = -0.5f * W, y1 = 0.5f * W;
  using V = Eigen::Vector3f;
  AddQuad(m, V(0, y0, 0), V(0, y1, 0), V(L, y1, 0), V(L, y0, 0));  // bottom
  AddQuad(m, V(L, y0, 0), V(L, y1, 0), V(L, y1, t), V(L, y0, t));  // base end
  AddQuad(m, V(t, y0, t), V(L, y0, t), V(L, y1, t), V(t, y1, t));  // base top
  AddQuad(m, V(t, y0, t), V(t, y1, t), V(t, y1, H), V(t, y0, H));  // upright inner
  AddQuad(m, V(0, y0, H), V(t, y0, H), V(t, y1, H), V(0, y1, H));  // upright top
  AddQuad(m, V(0, y0, 0), V(0, y0, H), V(0, y1, H), V(0, y1, 0));  // outer
  AddQuad(m, V(0, y0, 0), V(L, y0, 0), V(L, y0, t), V(0, y0, t));  // -y caps
  AddQuad(m, V(0, y0, t), V(t, y0, t), V(t, y0, H), V(0, y0, H));
  AddQuad(m, V(0, y1, 0), V(0, y1, t), V(L, y1, t), V(L, y1, 0));  // +y caps
  AddQuad(m, V(0, y1, t), V(0, y1, H), V(t, y1, H), V(t, y1, t));
  return m;
}

TriangleMesh Transformed(TriangleMesh m, const Eigen::Affine3f& T) {
  for (Eigen::Vector3f& v : m.vertices) v = T * v;
  return m;
}

// An L-shaped sheet in xy (arms `arm` wide, L x H outside), `thickness` thick.
TriangleMesh LSheet(float L, float H, float arm, float thickness) {
  // The profile's extrusion axis (y) turned onto z.
  return Transformed(ExtrudedL(L, H, arm, thickness), Eigen::Affine3f(Eigen::AngleAxisf(
                                                           static_cast<float>(M_PI / 2), Eigen::Vector3f::UnitX())));
}

struct Part {
  std::string name;
  TriangleMesh mesh;
  Symmetry symmetry;
};

// The default cell's camera, bin and ROI with `parts` instead of its own,
// a pile of `num_parts` rendered with `seed`. Meshes are written to scratch
// files.
Cell CellWith(const std::vector<Part>& parts, int num_parts, uint64_t seed) {
  Cell cell = LoadDefaultCell().value();
  cell.parts.clear();
  for (size_t i = 0; i < parts.size(); ++i) {
    PartSpec spec;
    spec.class_id = static_cast<int>(i);
    spec.name = parts[i].name;
    spec.mesh = testing::ScratchFile("meshes", parts[i].name + ".ply");
    EXPECT_TRUE(SaveMeshPly(parts[i].mesh, spec.mesh).ok());
    spec.symmetry = parts[i].symmetry;
    cell.parts.push_back(spec);
  }
  cell.source.kind = SourceSpec::Kind::kSynthetic;
  cell.source.num_parts = num_parts;
  cell.source.seed = seed;
  cell.source.part_classes.clear();
  return cell;
}

Frame Capture(const Cell& cell) {
  auto source = MakeCaptureSource(cell);
  EXPECT_TRUE(source.ok()) << source.status().ToString();
  CaptureRequest request;
  request.config_id = 1;
  auto frame = (*source)->Capture(request);
  EXPECT_TRUE(frame.ok()) << frame.status().ToString();
  return std::move(*frame);
}

struct Score {
  int targets = 0;         // true parts at least half visible
  int found = 0;           // of those, with a detection of their class within tolerance
  int detections = 0;
  int far_detections = 0;  // detections more than 5 mm from every true part of their class
};

// Tolerance: 2 mm and 5 deg (the eval's strict rotation tolerance) modulo
// the part's symmetry.
Score ScoreFrame(const PerceptionResult& result, const Frame& frame, const Cell& cell) {
  Score s;
  s.detections = static_cast<int>(result.detections.size());
  for (const PartTruth& t : frame.truth->parts) {
    if (t.visible_fraction < 0.5) continue;
    ++s.targets;
    const Symmetry& sym = cell.FindPart(t.class_id)->symmetry;
    for (const Detection& d : result.detections) {
      if (d.class_id == t.class_id && SymmetricTranslationError(d.X_BO, t.X_BO, sym) < 0.002 &&
          SymmetricRotationError(d.X_BO, t.X_BO, sym) < 5.0 * M_PI / 180.0) {
        ++s.found;
        break;
      }
    }
  }
  for (const Detection& d : result.detections) {
    bool near = false;
    for (const PartTruth& t : frame.truth->parts) {
      near |= t.class_id == d.class_id &&
              SymmetricTranslationError(d.X_BO, t.X_BO, cell.FindPart(t.class_id)->symmetry) < 0.005;
    }
    s.far_detections += near ? 0 : 1;
  }
  return s;
}

struct Outcome {
  Score score;
  double build_s = 0.0;
  double run_ms = 0.0;
  PerceptionOptions options;
};

// Builds perception for the cell (timed), runs it on `frames` piles (seeds
// from the cell's) on 2 threads and sums the scores.
Outcome BuildAndRun(Cell cell, int frames) {
  Outcome out;
  const auto t0 = std::chrono::steady_clock::now();
  auto perception = Perception::Build(cell);
  out.build_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  EXPECT_TRUE(perception.ok()) << perception.status().ToString();
  if (!perception.ok()) return out;
  out.options = (*perception)->options();
  tbb::task_arena arena(2);
  for (int f = 0; f < frames; ++f) {
    const Frame frame = Capture(cell);
    Result<PerceptionResult> result = Status::Internal("not run");
    const auto t1 = std::chrono::steady_clock::now();
    arena.execute([&] { result = (*perception)->Run(frame); });
    out.run_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t1).count();
    EXPECT_TRUE(result.ok());
    const Score s = ScoreFrame(*result, frame, cell);
    out.score.targets += s.targets;
    out.score.found += s.found;
    out.score.detections += s.detections;
    out.score.far_detections += s.far_detections;
    ++cell.source.seed;
  }
  std::printf("[          ] found %d of %d targets, %d detections (%d far), start-up %.2f s, %.0f ms per frame\n",
              out.score.found, out.score.targets, out.score.detections, out.score.far_detections, out.build_s,
              out.run_ms / frames);
  return out;
}

TEST(PartScale, TwelveMillimetrePartsAreSegmentedAndFound) {
  Cell cell = CellWith({{"mini_bracket", ExtrudedL(0.012f, 0.008f, 0.003f, 0.008f), {}}}, 10, 5);
  const Outcome o = BuildAndRun(cell, 2);
  EXPECT_LT(o.options.min_segment_points, 150);  // scaled to the part's views
  EXPECT_LT(o.options.floor_band, 0.003);         // below the 3 mm plate's top
  ASSERT_GT(o.score.targets, 5);
  // About half of the parts this small are found yet (each found one within
  // 0.6 mm): the other half is issue 42's open item.
  EXPECT_GE(o.score.found, 0.4 * o.score.targets);
  EXPECT_LE(o.score.far_detections, 1);
  // With the reference segment size the parts never become segments.
  cell.parts[0].perception.min_view_points = 150;
  EXPECT_EQ(BuildAndRun(cell, 1).score.found, 0);
}

TEST(PartScale, A250MillimetrePartIsFoundAndItsStartUpTimeReported) {
  const Cell cell = CellWith({{"long_bracket", ExtrudedL(0.25f, 0.08f, 0.015f, 0.06f), {}}}, 2, 7);
  const Outcome o = BuildAndRun(cell, 2);
  RecordProperty("startup_s", std::to_string(o.build_s));
  RecordProperty("frame_ms", std::to_string(o.run_ms / 2));
  ASSERT_GE(o.score.targets, 2);
  EXPECT_GE(o.score.found, o.score.targets - 1);
  EXPECT_EQ(o.score.far_detections, 0);
}

TEST(PartScale, AThreeMillimetreSheetLyingFlatIsNotErasedAsFloor) {
  const Cell cell = CellWith({{"l_sheet", LSheet(0.06f, 0.04f, 0.02f, 0.003f), {}}}, 4, 11);
  const Outcome o = BuildAndRun(cell, 2);
  EXPECT_LT(o.options.floor_band, 0.003);  // below the sheet's top
  ASSERT_GE(o.score.targets, 4);
  EXPECT_GE(o.score.found, 0.75 * o.score.targets);
  EXPECT_EQ(o.score.far_detections, 0);
}

TEST(PartScale, AFiftyThousandTriangleMeshBuildsAndIsFound) {
  std::vector<Eigen::Vector2f> profile = {{0.f, 0.f},        {0.025f, 0.f},    {0.025f, 0.008f},
                                          {0.012f, 0.008f},  {0.012f, 0.04f},  {0.f, 0.04f}};
  Part fine{"fine_flange", testing::MakeRevolved(profile, 6400), testing::RevoluteZ()};
  ASSERT_GE(fine.mesh.triangles.size(), 50000u);
  const Cell cell = CellWith({fine}, 6, 13);
  const Outcome o = BuildAndRun(cell, 1);
  RecordProperty("startup_s", std::to_string(o.build_s));
  ASSERT_GE(o.score.targets, 3);
  EXPECT_GE(o.score.found, o.score.targets - 1);
  EXPECT_EQ(o.score.far_detections, 0);
}

TEST(PartScale, PartsAreFoundWithTheCameraTilted15DegAndRolled) {
  Cell cell = CellWith({{"bracket", ExtrudedL(0.07f, 0.04f, 0.005f, 0.03f), {}},
                        {"flange", testing::MakeTestFlangedCylinder(), testing::RevoluteZ()}},
                       10, 17);
  // Turned about the point it looks at on the bin floor: 15 deg of tilt,
  // then 40 deg of roll about the optical axis.
  const Pose X_BC = cell.camera.X_BC;
  const Vec3 target = cell.bin.X_BW.translation();
  const Pose tilt = MakePose(Mat3(Eigen::AngleAxisd(15.0 * M_PI / 180.0, Vec3(0.6, 0.8, 0.0))), Vec3::Zero());
  const Pose about_target = MakePose(Mat3::Identity(), target) * tilt * MakePose(Mat3::Identity(), -target);
  cell.camera.X_BC = about_target * X_BC * MakePose(Mat3(Eigen::AngleAxisd(40.0 * M_PI / 180.0, Vec3::UnitZ())),
                                                    Vec3::Zero());
  const Outcome o = BuildAndRun(cell, 2);
  ASSERT_GT(o.score.targets, 8);
  EXPECT_GE(o.score.found, 0.75 * o.score.targets);
  EXPECT_LE(o.score.far_detections, 1);
}

TEST(PartScale, AMeshInMillimetresIsRefusedNamingTheUnit) {
  const TriangleMesh bracket = ExtrudedL(0.07f, 0.04f, 0.005f, 0.03f);
  Cell cell = CellWith({{"bracket", bracket, {}}}, 1, 1);
  // The same bracket exported in millimetres.
  ASSERT_TRUE(SaveMeshPly(Transformed(bracket, Eigen::Affine3f(Eigen::Scaling(1000.f))), cell.parts[0].mesh).ok());
  Result<std::unique_ptr<Perception>> built = Perception::Build(cell);
  ASSERT_FALSE(built.ok());
  EXPECT_EQ(built.status().code(), Status::Code::kInvalidArgument);
  EXPECT_NE(built.status().message().find("millimetres"), std::string::npos) << built.status().message();
  EXPECT_NE(built.status().message().find("bracket"), std::string::npos) << built.status().message();
  // In metres but declared in millimetres by its header: refused too.
  ASSERT_TRUE(SaveMeshPly(bracket, cell.parts[0].mesh).ok());
  std::string ply = testing::ReadBytes(cell.parts[0].mesh);
  const size_t comment = ply.find("comment");
  ASSERT_NE(comment, std::string::npos);
  ply.insert(comment, "comment units mm\n");
  testing::WriteText(cell.parts[0].mesh, ply);
  built = Perception::Build(cell);
  ASSERT_FALSE(built.ok());
  EXPECT_NE(built.status().message().find("millimetres"), std::string::npos) << built.status().message();
  // Under 2 mm: refused.
  ASSERT_TRUE(SaveMeshPly(Transformed(bracket, Eigen::Affine3f(Eigen::Scaling(0.001f))), cell.parts[0].mesh).ok());
  EXPECT_FALSE(Perception::Build(cell).ok());
}

TEST(PartScale, AClassWhoseModelFailsIsRefusedUnlessOptional) {
  Cell cell = CellWith({{"bracket", ExtrudedL(0.07f, 0.04f, 0.005f, 0.03f), {}},
                        {"flange", testing::MakeTestFlangedCylinder(), testing::RevoluteZ()}},
                       4, 3);
  const std::string good_flange = cell.parts[1].mesh;
  cell.parts[1].mesh = testing::ScratchFile("meshes", "missing.ply");
  Result<std::unique_ptr<Perception>> built = Perception::Build(cell);
  ASSERT_FALSE(built.ok());
  EXPECT_NE(built.status().message().find("missing.ply"), std::string::npos) << built.status().message();
  EXPECT_NE(built.status().message().find("optional"), std::string::npos) << built.status().message();
  // Optional: perception starts without it and says so when asked for it.
  cell.parts[1].optional = true;
  built = Perception::Build(cell);
  ASSERT_TRUE(built.ok()) << built.status().ToString();
  cell.parts[1].mesh = good_flange;  // the pile still holds flanges
  const Frame frame = Capture(cell);
  tbb::task_arena arena(2);
  Result<PerceptionResult> only_flanges = Status::Internal("not run");
  arena.execute([&] { only_flanges = (*built)->Run(frame, {1}); });
  ASSERT_TRUE(only_flanges.ok());
  EXPECT_TRUE(only_flanges->detections.empty());
  EXPECT_NE(only_flanges->reason.find("no pose model"), std::string::npos) << only_flanges->reason;
}

}  // namespace
}  // namespace bp
