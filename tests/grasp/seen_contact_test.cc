// Grasps only on surfaces the camera saw (issue 37 item 2): the seen-contact
// rule of grasp/grasp_planning.h on depth frames rendered from the default
// cell's own meshes (exact z-buffer, tests/pipeline/pose_test_util.h) by its
// own camera, with detections at true and at wrong poses.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "core/mesh.h"
#include "grasp/grasp_planning.h"
#include "grasp/internal/contact_region.h"
#include "pipeline/frame.h"
#include "tests/pipeline/pose_test_util.h"
#include "tests/testing/default_cell.h"

namespace bp {
namespace {

constexpr int kBracket = 1, kTee = 2;

using testing::DefaultCell;

std::shared_ptr<const GraspPlanningModel> ModelOf(const Cell& cell) {
  auto m = GraspPlanningModel::Build(cell);
  EXPECT_TRUE(m.ok()) << m.status().ToString();
  return m.ok() ? *m : nullptr;
}

const GraspPlanningModel& Model() {
  static const std::shared_ptr<const GraspPlanningModel> model = ModelOf(DefaultCell());
  return *model;
}

const TriangleMesh& PartMesh(int class_id) {
  static std::map<int, TriangleMesh> meshes;
  auto it = meshes.find(class_id);
  if (it == meshes.end()) {
    Result<TriangleMesh> m = LoadMesh(DefaultCell().FindPart(class_id)->mesh);
    EXPECT_TRUE(m.ok()) << m.status().ToString();
    it = meshes.emplace(class_id, m.ok() ? *m : TriangleMesh{}).first;
  }
  return it->second;
}

// The default cell's VGA camera (1.05 m above the bin floor, looking down).
testing::TestCamera CellCamera() {
  testing::TestCamera cam;
  cam.K = DefaultCell().camera.configs.front().intrinsics;
  cam.X_BC = DefaultCell().camera.X_BC;
  return cam;
}

// A part at X_WO (bin frame) on the bin floor, rendered; the frame and the
// perception result a detection at X_WO_detected would give: its support is
// every point of the part (so no point of it is an obstacle).
struct Rendered {
  Frame frame;
  PerceptionResult perception;
};
Rendered RenderPart(int class_id, const Pose& X_WO, const Pose& X_WO_detected, bool ambiguous = false) {
  const Pose& X_BW = DefaultCell().bin.X_BW;
  static const TriangleMesh floor = testing::MakeBox({-0.25f, -0.18f, -0.01f}, {0.25f, 0.18f, 0.0f});
  const testing::TestCamera cam = CellCamera();
  const testing::RenderedScene scene =
      testing::Render({{&PartMesh(class_id), X_BW * X_WO}, {&floor, X_BW}}, cam, 0.0002, 42);
  Rendered r;
  r.frame.depth = scene.depth;
  r.frame.intrinsics = cam.K;
  r.frame.X_BC = cam.X_BC;
  r.perception.roi_points_B = scene.points_B;
  Detection d;
  d.class_id = class_id;
  d.X_BO = X_BW * X_WO_detected;
  d.score = 0.95;
  // Ambiguous: an alternative pose 1 mm off, under which every grasp still
  // lands (no kAmbiguous), so that only the seen-contact rule decides.
  if (ambiguous) d.alternatives_X_BO = {d.X_BO * MakePose(Mat3::Identity(), Vec3(0.001, 0, 0))};
  for (size_t i = 0; i < scene.points_B.size(); ++i) {
    if (scene.point_label[i] == 1) d.support.push_back(static_cast<int32_t>(i));
  }
  EXPECT_GT(d.support.size(), 300u);
  r.perception.detections.push_back(d);
  return r;
}

TaskSpec Task(int id, int class_id) {
  TaskSpec t = *DefaultCell().FindTask(id);
  t.part_classes = {class_id};
  return t;
}

// Candidates whose name starts with `prefix` and whose approach the task allows.
std::vector<const GraspCandidate*> Reachable(const GraspPlan& plan, const std::string& prefix) {
  std::vector<const GraspCandidate*> out;
  for (const GraspCandidate& c : plan.candidates) {
    if (c.name.rfind(prefix, 0) == 0 && c.rejected != RejectReason::kTilt) out.push_back(&c);
  }
  return out;
}

// The pipe tee (run along its x, branch along its z) lying on its side, run
// along the bin's x, its branch along the bin's -y on the floor. Its wrong
// twin is turned 180 deg about the run: the run where it is, the branch on
// the other side, where the camera sees the floor 40 mm below.
Pose TeeOnItsSide(double turn_about_run_deg) {
  return MakePose(Mat3(Eigen::AngleAxisd((90 + turn_about_run_deg) * M_PI / 180, Vec3::UnitX())),
                  Vec3(0, 0, 0.020));
}

TEST(SeenContact, AGraspOnTheBranchOfAWronglyTurnedTeeIsRejectedAsUnseenItsRunGraspsPass) {
  const Rendered wrong = RenderPart(kTee, TeeOnItsSide(0), TeeOnItsSide(180));
  const GraspPlan plan = PlanGrasps(Model(), Task(0, kTee), wrong.perception, {}, &wrong.frame);
  const auto branch = Reachable(plan, "branch_side");
  ASSERT_FALSE(branch.empty());
  for (const GraspCandidate* c : branch) {
    EXPECT_EQ(c->rejected, RejectReason::kUnseen) << c->name << " seen " << c->seen_fraction;
    EXPECT_LT(c->seen_fraction, 0.2) << c->name;
  }
  // The run, where the camera saw it: its top grasps pass.
  int run_ok = 0;
  for (const GraspCandidate* c : Reachable(plan, "run_side")) {
    if (c->rejected) continue;
    ++run_ok;
    EXPECT_GT(c->seen_fraction, 0.9) << c->name;
  }
  EXPECT_GT(run_ok, 0);
  ASSERT_FALSE(plan.queue.empty());
  EXPECT_EQ(plan.queue[0].name.rfind("branch", 0), std::string::npos) << plan.queue[0].name;
  EXPECT_GT(plan.stats.rejected[static_cast<int>(RejectReason::kUnseen)], 0);
  EXPECT_NE(plan.stats.Describe().find("unseen"), std::string::npos) << plan.stats.Describe();
}

TEST(SeenContact, TheSameGraspOnTheTeeWhereItReallyLiesPasses) {
  const Rendered right = RenderPart(kTee, TeeOnItsSide(0), TeeOnItsSide(0));
  const GraspPlan plan = PlanGrasps(Model(), Task(0, kTee), right.perception, {}, &right.frame);
  int branch_ok = 0;
  for (const GraspCandidate* c : Reachable(plan, "branch_side")) {
    if (c->rejected) continue;
    ++branch_ok;
    EXPECT_GT(c->seen_fraction, 0.9) << c->name;
  }
  EXPECT_GT(branch_ok, 0);
  EXPECT_EQ(plan.stats.rejected[static_cast<int>(RejectReason::kUnseen)], 0) << plan.stats.Describe();
}

TEST(SeenContact, AFrameWithoutADepthImageIsJudgedOnItsRoiPoints) {
  // The same scenes as unorganized clouds (no frame): the same conclusions.
  const Rendered wrong = RenderPart(kTee, TeeOnItsSide(0), TeeOnItsSide(180));
  const GraspPlan w = PlanGrasps(Model(), Task(0, kTee), wrong.perception);
  ASSERT_FALSE(Reachable(w, "branch_side").empty());
  for (const GraspCandidate* c : Reachable(w, "branch_side")) EXPECT_EQ(c->rejected, RejectReason::kUnseen) << c->name;
  const Rendered right = RenderPart(kTee, TeeOnItsSide(0), TeeOnItsSide(0));
  const GraspPlan r = PlanGrasps(Model(), Task(0, kTee), right.perception);
  int branch_ok = 0;
  for (const GraspCandidate* c : Reachable(r, "branch_side")) branch_ok += !c->rejected;
  EXPECT_GT(branch_ok, 0);
  // Without any measured point nothing is seen.
  PerceptionResult blind = right.perception;
  blind.roi_points_B.clear();
  for (Detection& d : blind.detections) d.support.clear();
  const GraspPlan none = PlanGrasps(Model(), Task(0, kTee), blind);
  EXPECT_EQ(none.outcome, PlanResult::Outcome::kNoCollisionFree);
  EXPECT_GT(none.stats.rejected[static_cast<int>(RejectReason::kUnseen)], 0);
}

TEST(SeenContact, ADepthHoleOverTheContactRejectsTheGrasp) {
  Rendered scene = RenderPart(kTee, TeeOnItsSide(0), TeeOnItsSide(0));
  // No measurement within 15 mm of the branch's top (a specular patch).
  const Vec3 top_B = DefaultCell().bin.X_BW * Vec3(0, -0.040, 0.040);
  for (int v = 0; v < scene.frame.depth.height; ++v) {
    for (int u = 0; u < scene.frame.depth.width; ++u) {
      float& z = scene.frame.depth.at(u, v);
      if (!std::isfinite(z)) continue;
      const Vec3 p_B = scene.frame.X_BC * Deproject(scene.frame.intrinsics, static_cast<float>(u), static_cast<float>(v), z).cast<double>();
      if ((p_B - top_B).norm() < 0.015) z = std::numeric_limits<float>::quiet_NaN();
    }
  }
  const GraspPlan plan = PlanGrasps(Model(), Task(0, kTee), scene.perception, {}, &scene.frame);
  int on_top = 0;
  for (const GraspCandidate* c : Reachable(plan, "branch_side")) {
    if ((c->X_BG.translation() - top_B).norm() > 0.005) continue;
    ++on_top;
    EXPECT_EQ(c->rejected, RejectReason::kUnseen) << c->name;
  }
  EXPECT_GT(on_top, 0);
}

// The L-bracket standing on its base right under the camera: the faces the
// jaw pinches at the top of the upright are edge-on or turned away.
Pose BracketStanding() { return MakePose(Mat3::Identity(), Vec3(0, 0, 0)); }

TEST(SeenContact, AParallelJawChecksItsFingersOnlyOnAnAmbiguousPoseByDefault) {
  const TaskSpec pinch = Task(4, kBracket);
  auto verdicts = [&](const GraspPlanningModel& model, bool ambiguous) {
    const Rendered scene = RenderPart(kBracket, BracketStanding(), BracketStanding(), ambiguous);
    const GraspPlan plan = PlanGrasps(model, pinch, scene.perception, {}, &scene.frame);
    const auto top = Reachable(plan, "upright_pinch_top");
    EXPECT_EQ(top.size(), 1u);
    return top.empty() ? std::optional<RejectReason>(RejectReason::kTilt) : top[0]->rejected;
  };
  EXPECT_EQ(DefaultCell().FindGripper("parallel")->seen_contact.when, SeenContactRule::When::kIfAmbiguous);
  EXPECT_EQ(verdicts(Model(), false), std::nullopt);
  EXPECT_EQ(verdicts(Model(), true), RejectReason::kUnseen);
  Cell always = DefaultCell();
  for (GripperSpec& g : always.grippers) g.seen_contact.when = SeenContactRule::When::kAlways;
  EXPECT_EQ(verdicts(*ModelOf(always), false), RejectReason::kUnseen);
  Cell off = DefaultCell();
  for (GripperSpec& g : off.grippers) g.seen_contact.when = SeenContactRule::When::kOff;
  EXPECT_EQ(verdicts(*ModelOf(off), true), std::nullopt);
}

TEST(ContactRegion, SuctionSamplesLieOnTheFaceUnderTheCupAndJawSamplesOnThePinchedFaces) {
  const GripperSpec& cup = *DefaultCell().FindGripper("suction");
  const GripperSpec& jaw = *DefaultCell().FindGripper("parallel");
  auto mesh_of = [](const GripperSpec& g) { return LoadMesh(g.mesh).value(); };
  const internal::ContactShape cup_shape = internal::MakeContactShape(cup, mesh_of(cup)).value();
  EXPECT_NEAR(cup_shape.radius, 0.008, 1e-4);  // the cup's lip (16 mm across)
  // base_top: the middle of the bracket's base, tool down onto z = 5 mm.
  const Pose X_OG = MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), Vec3(0.045, 0, 0.005));
  const internal::ContactRegion flat = internal::SampleContactRegion(cup_shape, PartMesh(kBracket), X_OG);
  ASSERT_EQ(flat.contacts.size(), 1u);
  EXPECT_EQ(flat.contacts[0].size(), 29u);  // all on solid material (9 mm from the holes)
  for (const Eigen::Vector3f& p_G : flat.contacts[0]) {
    EXPECT_NEAR(p_G.z(), 0.0, 1e-6);
    EXPECT_LE(p_G.head<2>().norm(), 0.008 + 1e-6);
  }
  // upright_pinch_top: fingers close along x on the upright's faces x = 0
  // and x = 5 mm (the tool centre at x = 2.5 mm).
  const internal::ContactShape jaw_shape = internal::MakeContactShape(jaw, mesh_of(jaw)).value();
  const Pose X_OJ = MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), Vec3(0.0025, 0, 0.055));
  const internal::ContactRegion pinch = internal::SampleContactRegion(jaw_shape, PartMesh(kBracket), X_OJ);
  ASSERT_EQ(pinch.contacts.size(), 2u);
  for (int f = 0; f < 2; ++f) {
    EXPECT_GE(pinch.contacts[f].size(), 20u) << "finger " << f;
    for (const Eigen::Vector3f& p_G : pinch.contacts[f]) {
      EXPECT_NEAR(p_G.x(), f == 0 ? 0.0025 : -0.0025, 1e-6) << "finger " << f;
    }
  }
}

TEST(ContactRegion, ASuctionMeshWithNothingAtItsContactPlaneNeedsAnExplicitRadius) {
  GripperSpec g = *DefaultCell().FindGripper("suction");
  TriangleMesh lifted = LoadMesh(g.mesh).value();
  for (Eigen::Vector3f& v : lifted.vertices) v.z() -= 0.01f;
  const Result<internal::ContactShape> shape = internal::MakeContactShape(g, lifted);
  ASSERT_FALSE(shape.ok());
  EXPECT_NE(shape.status().message().find("seen_contact.radius"), std::string::npos) << shape.status().ToString();
  g.seen_contact.radius = 0.01;
  EXPECT_NEAR(internal::MakeContactShape(g, lifted).value().radius, 0.01, 1e-12);
}

}  // namespace
}  // namespace bp
