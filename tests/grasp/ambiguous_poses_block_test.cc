// GraspPlanningOptions::ambiguous_poses_block against ground truth: an
// ambiguous detection is an obstacle for the other parts' grasps at each of
// its poses, not at its estimate alone. A pipe tee of the default cell lies
// on its run, its branch raised 45 deg toward a flanged bushing standing
// beside it, its end over the edge of the bushing's hub; the branch read no
// depth (dropped out), so the view is explained as well by the tee turned
// about its run with its branch straight up, which is the estimate, the
// true pose its alternative. A suction grasp on the bushing's hub top next
// to the branch passes the estimated tee but meets the true one (FCL:
// GraspPlanningModel::CheckAgainstParts, the judge's check, on the true
// poses).
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "core/mesh.h"
#include "grasp/grasp_planning.h"
#include "tests/pipeline/pose_test_util.h"
#include "tests/testing/default_cell.h"

namespace bp {
namespace {

constexpr int kBushing = 0, kTee = 2;

using testing::DefaultCell;

// The default cell without the seen-contact rule: the raised branch hides
// part of the hub's top from the camera, and the test is about the parts.
const Cell& CellWithoutSeenContact() {
  static const Cell cell = [] {
    Cell c = DefaultCell();
    for (GripperSpec& g : c.grippers) g.seen_contact.when = SeenContactRule::When::kOff;
    return c;
  }();
  return cell;
}

const TriangleMesh& PartMesh(int class_id) {
  static const std::vector<TriangleMesh> meshes = [] {
    std::vector<TriangleMesh> out;
    for (int id = 0; id <= kTee; ++id) {
      Result<TriangleMesh> m = LoadMesh(DefaultCell().FindPart(id)->mesh);
      EXPECT_TRUE(m.ok()) << m.status().ToString();
      out.push_back(m.ok() ? *m : TriangleMesh{});
    }
    return out;
  }();
  return meshes[static_cast<size_t>(class_id)];
}

std::shared_ptr<const GraspPlanningModel> Model(bool ambiguous_poses_block) {
  GraspPlanningOptions o;
  o.ambiguous_poses_block = ambiguous_poses_block;
  auto m = GraspPlanningModel::Build(CellWithoutSeenContact(), o);
  EXPECT_TRUE(m.ok()) << m.status().ToString();
  return m.ok() ? *m : nullptr;
}

// The tee (run along its x, branch along its +z: 50 mm from the run's axis,
// 40 mm across) on its run on the bin floor, run along the bin's x, turned
// about the run so that its branch points `up_deg` above the bin's -y.
Pose Tee(double up_deg) {
  return DefaultCell().bin.X_BW *
         MakePose(Mat3(Eigen::AngleAxisd((90.0 - up_deg) * M_PI / 180, Vec3::UnitX())), Vec3(0.01, 0.02, 0.020));
}

// The truth: the branch 45 deg up, its lowest point toward the bushing at
// bin y = -29.5 mm, 41.3 mm high (1.3 mm over the hub's top); below the
// hub's top the tee reaches bin y = -28 mm.
Pose TeeTruth() { return Tee(45.0); }

// The estimate: the branch straight up, over the run (bin y 0 to 40 mm).
Pose TeeEstimate() { return Tee(90.0); }

// The bushing (flange 30 mm in radius, 8 mm high; hub 18 mm, 40 mm high)
// standing on the floor, its hub 1 mm from the tee below the hub's top: its
// hub_top grasp toward the tee puts the suction tool (a 10 mm rod above the
// cup, 12 mm off the bushing's axis) 4.5 mm into the true branch's end.
Pose Bushing() { return DefaultCell().bin.X_BW * MakePose(Mat3::Identity(), Vec3(0.01, -0.047, 0.0)); }

struct Scene {
  PerceptionResult perception;
  std::vector<Detection> truth;  // the parts at their true poses, in detection order
};

// The scene seen by the cell's camera, every point of the tee's branch
// dropped (the tee's points beyond its run, tee z > 20 mm); the tee
// detected at TeeEstimate() with the truth as its alternative, the bushing
// exactly.
Scene Look() {
  const Pose& X_BW = DefaultCell().bin.X_BW;
  static const TriangleMesh floor = testing::MakeBox({-0.25f, -0.18f, -0.01f}, {0.25f, 0.18f, 0.0f});
  testing::TestCamera cam;
  cam.K = DefaultCell().camera.configs.front().intrinsics;
  cam.X_BC = DefaultCell().camera.X_BC;
  const testing::RenderedScene rendered = testing::Render(
      {{&PartMesh(kTee), TeeTruth()}, {&PartMesh(kBushing), Bushing()}, {&floor, X_BW}}, cam, 0.0002, 7);
  Scene s;
  std::vector<Detection>& d = s.perception.detections;
  d.resize(2);
  const Pose X_OB_tee = TeeTruth().inverse();
  for (size_t i = 0; i < rendered.points_B.size(); ++i) {
    const int label = rendered.point_label[i];
    const Vec3 p_B = rendered.points_B[i].cast<double>();
    if (label == 1 && (X_OB_tee * p_B).z() > 0.020) continue;  // the branch: no depth
    if (label == 1 || label == 2) {
      d[static_cast<size_t>(label - 1)].support.push_back(static_cast<int32_t>(s.perception.roi_points_B.size()));
    }
    s.perception.roi_points_B.push_back(rendered.points_B[i]);
  }
  d[0].class_id = kTee;
  d[0].X_BO = TeeEstimate();
  d[0].alternatives_X_BO = {TeeTruth()};
  d[1].class_id = kBushing;
  d[1].X_BO = Bushing();
  for (Detection& det : d) {
    det.score = 1.0;
    det.visible_fraction = 1.0;
  }
  s.truth = d;
  s.truth[0].X_BO = TeeTruth();
  s.truth[0].alternatives_X_BO.clear();
  return s;
}

GraspPlan PlanBushing(const GraspPlanningModel& model, const Scene& s) {
  TaskSpec task = *DefaultCell().FindTask(0);
  task.part_classes = {kBushing};
  return PlanGrasps(model, task, s.perception);
}

// Whether the tool of `c` meets a part of the true scene other than its own.
bool HitsTheTruePile(const GraspPlanningModel& model, const Scene& s, const GraspCandidate& c) {
  return model.CheckAgainstParts("suction", c.X_BT, s.truth, c.detection, DefaultCell().bin.X_BW,
                                 /*with_bin=*/false) == RejectReason::kPart;
}

TEST(AmbiguousPosesBlock, AToolBesideTheEstimateThatMeetsTheTruePoseIsRefusedOnlyWithTheRule) {
  const Scene s = Look();
  const auto without = Model(false), with = Model(true);
  ASSERT_TRUE(without && with);

  // Without the rule, a bushing grasp is accepted whose tool meets the true tee.
  const GraspPlan off = PlanBushing(*without, s);
  std::vector<std::string> into_the_tee;
  for (const GraspCandidate& c : off.candidates) {
    if (c.detection == 1 && !c.rejected && HitsTheTruePile(*without, s, c)) into_the_tee.push_back(c.name);
  }
  ASSERT_FALSE(into_the_tee.empty()) << "no accepted grasp meets the true tee: " << off.stats.Describe();

  // With it, each of those is refused for the tee (kPart), and every grasp
  // it still accepts is clear of the true pile.
  const GraspPlan on = PlanBushing(*with, s);
  int accepted = 0;
  for (const GraspCandidate& c : on.candidates) {
    if (c.detection != 1) continue;
    if (!c.rejected) {
      ++accepted;
      EXPECT_FALSE(HitsTheTruePile(*with, s, c)) << c.name;
    }
    if (std::find(into_the_tee.begin(), into_the_tee.end(), c.name) != into_the_tee.end()) {
      EXPECT_EQ(c.rejected, RejectReason::kPart) << c.name;
    }
  }
  EXPECT_GT(accepted, 0) << "the rule refused every grasp on the bushing: " << on.stats.Describe();
  for (const Grasp& g : on.queue) EXPECT_EQ(std::count(into_the_tee.begin(), into_the_tee.end(), g.name), 0) << g.name;
}

}  // namespace
}  // namespace bp
