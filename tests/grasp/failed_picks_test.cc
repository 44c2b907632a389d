// Failed-pick feedback (grasp/failed_picks.h): a reported failure withholds
// the grasps on that part and its near neighbours for N captures of the task,
// then releases them; K failures on one spot refuse it even when nothing else
// is left; the spots live in the bin frame.
#include "grasp/failed_picks.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <memory>
#include <set>

#include "grasp/bin_picking_planner.h"
#include "grasp/grasp_queue.h"
#include "pipeline/capture_source.h"
#include "pipeline/synthetic_source.h"
#include "pipeline/truth_perception.h"

namespace bp {
namespace {

Grasp GraspAt(int instance, int class_id, const Vec3& p_B, const std::string& name = "top") {
  Grasp g;
  g.instance_id = instance;
  g.class_id = class_id;
  g.X_BO = MakePose(Mat3::Identity(), p_B);
  g.X_BT = g.X_BO;
  g.name = name;
  return g;
}

std::vector<int> Ids(const std::deque<Grasp>& grasps) {
  std::vector<int> ids;
  for (const Grasp& g : grasps) ids.push_back(g.instance_id);
  return ids;
}

FailedPickRule Rule(double radius, int captures, int max_failures) {
  FailedPickRule r;
  r.radius = radius;
  r.captures = captures;
  r.max_failures = max_failures;
  return r;
}

TEST(FailedPicks, AFailureWithholdsThePartAndItsNearNeighboursWhileAnythingElseIsLeft) {
  FailedPicks f(Rule(0.03, 3, 3), Pose::Identity());
  // Parts 0 and 1 are 20 mm apart (neighbours), part 2 is 100 mm away; part 1
  // is of another class: a neighbour is withheld whatever its class.
  std::deque<Grasp> q = {GraspAt(0, 0, Vec3(0.5, 0, 0.1)), GraspAt(1, 1, Vec3(0.52, 0, 0.1)),
                         GraspAt(2, 0, Vec3(0.6, 0, 0.1))};
  const FailedPicks::Recorded r = f.Report(q[0], PickFailure::kSlipped);
  EXPECT_EQ(r.failures, 1);
  EXPECT_FALSE(r.refused);
  EXPECT_EQ(f.Judge(q[0]), FailedPicks::Verdict::kWithheld);
  EXPECT_EQ(f.Judge(q[1]), FailedPicks::Verdict::kWithheld);
  EXPECT_EQ(f.Judge(q[2]), FailedPicks::Verdict::kServe);
  const std::vector<Grasp> removed = f.Screen(q);
  EXPECT_EQ(Ids(q), (std::vector<int>{2}));
  ASSERT_EQ(removed.size(), 2u);
  EXPECT_EQ(removed[0].instance_id, 0);
  EXPECT_EQ(removed[1].instance_id, 1);
}

TEST(FailedPicks, WithheldGraspsStayWhenNothingElseIsLeftAndARefusedSpotLeavesEvenThen) {
  FailedPicks f(Rule(0.03, 3, 2), Pose::Identity());
  const Grasp a = GraspAt(0, 0, Vec3(0.5, 0, 0.1));
  std::deque<Grasp> q = {a};
  f.Report(a, PickFailure::kNoVacuum);
  EXPECT_TRUE(f.Screen(q).empty()) << "the only part left is tried again";
  EXPECT_EQ(Ids(q), (std::vector<int>{0}));
  // The same part re-detected 4 mm away is the same spot: its second failure reaches K = 2.
  const FailedPicks::Recorded r = f.Report(GraspAt(7, 0, Vec3(0.504, 0, 0.1)), PickFailure::kNoVacuum);
  EXPECT_EQ(r.failures, 2);
  EXPECT_TRUE(r.refused);
  EXPECT_EQ(f.Judge(a), FailedPicks::Verdict::kRefused);
  EXPECT_EQ(f.Screen(q).size(), 1u);
  EXPECT_TRUE(q.empty());
  // A part of another class on that spot is a neighbour, withheld, not refused.
  EXPECT_EQ(f.Judge(GraspAt(3, 1, Vec3(0.5, 0, 0.1))), FailedPicks::Verdict::kWithheld);
  ASSERT_EQ(f.Spots().size(), 1u);
}

// A collision is the plan's, not chance: its spot is refused at the first
// report, even when it is the only part left; a vacuum failure elsewhere
// still only withholds.
TEST(FailedPicks, ACollisionRefusesItsSpotAtOnce) {
  FailedPicks f(Rule(0.03, 3, 3), Pose::Identity());
  const Grasp a = GraspAt(0, 0, Vec3(0.5, 0, 0.1));
  const Grasp b = GraspAt(1, 0, Vec3(0.8, 0, 0.1));
  std::deque<Grasp> q = {a};
  const FailedPicks::Recorded r = f.Report(a, PickFailure::kCollision);
  EXPECT_EQ(r.failures, 3);
  EXPECT_TRUE(r.refused);
  EXPECT_EQ(f.Judge(a), FailedPicks::Verdict::kRefused);
  EXPECT_EQ(f.Screen(q).size(), 1u);
  EXPECT_TRUE(q.empty()) << "not sent into the same contact again";
  EXPECT_EQ(f.Judge(b), FailedPicks::Verdict::kServe);
  EXPECT_FALSE(f.Report(b, PickFailure::kNoVacuum).refused);
  EXPECT_EQ(f.Judge(b), FailedPicks::Verdict::kWithheld);
}

// What the tool met is still there while the part is: a collision's spot
// stays refused through any number of captures that detect a part of its
// class on it (Seen, in the bin frame), and is released `captures` captures
// after the last one that did. A slip's spot ages whatever the captures show;
// a part of another class, or one farther than the radius, does not keep it.
TEST(FailedPicks, ACollisionSpotStaysWhileItsPartIsSeenThere) {
  const Pose X_BW = MakePose(Mat3::Identity(), Vec3(0.1, 0, 0));
  FailedPicks f(Rule(0.03, 2, 3), X_BW);
  const Grasp a = GraspAt(0, 0, Vec3(0.5, 0, 0.1));
  const Grasp b = GraspAt(1, 1, Vec3(0.8, 0, 0.1));
  f.Report(a, PickFailure::kCollision);
  f.Report(b, PickFailure::kSlipped);
  // The part 4 mm from where it was, a part of the other class on the same
  // spot, and the slipped part.
  const std::vector<DetectedPart> seen = {{0, MakePose(Mat3::Identity(), Vec3(0.504, 0, 0.1)), 0.9},
                                          {1, MakePose(Mat3::Identity(), Vec3(0.5, 0, 0.1)), 0.9},
                                          {1, MakePose(Mat3::Identity(), Vec3(0.8, 0, 0.1)), 0.9}};
  for (int capture = 0; capture < 5; ++capture) {
    f.OnCapture();
    f.Seen(seen, X_BW);
  }
  EXPECT_EQ(f.Judge(a), FailedPicks::Verdict::kRefused) << "five captures showed the part on its spot";
  EXPECT_EQ(f.Judge(b), FailedPicks::Verdict::kServe) << "a slip's spot is released after 2 captures";
  // Gone: only the other class and a part of its class 40 mm away are seen.
  const std::vector<DetectedPart> gone = {{1, MakePose(Mat3::Identity(), Vec3(0.5, 0, 0.1)), 0.9},
                                          {0, MakePose(Mat3::Identity(), Vec3(0.54, 0, 0.1)), 0.9}};
  f.OnCapture();
  f.Seen(gone, X_BW);
  f.OnCapture();
  f.Seen(gone, std::nullopt);  // the nominal bin: the same here
  EXPECT_EQ(f.Judge(a), FailedPicks::Verdict::kRefused) << "2 captures after it was last seen";
  f.OnCapture();
  f.Seen(gone, X_BW);
  EXPECT_EQ(f.Judge(a), FailedPicks::Verdict::kServe);
  EXPECT_TRUE(f.Spots().empty());
}

TEST(FailedPicks, ASpotIsReleasedNCapturesAfterItsLastFailure) {
  FailedPicks f(Rule(0.03, 2, 3), Pose::Identity());
  const Grasp a = GraspAt(0, 0, Vec3(0.5, 0, 0.1));
  f.Report(a, PickFailure::kSlipped);
  f.OnCapture();
  f.OnCapture();
  EXPECT_EQ(f.Judge(a), FailedPicks::Verdict::kWithheld) << "captures 1 and 2 after the failure";
  f.Report(a, PickFailure::kSlipped);  // a second failure restarts the count
  f.OnCapture();
  f.OnCapture();
  EXPECT_EQ(f.Judge(a), FailedPicks::Verdict::kWithheld);
  f.OnCapture();
  EXPECT_EQ(f.Judge(a), FailedPicks::Verdict::kServe);
  EXPECT_TRUE(f.Spots().empty());
}

TEST(FailedPicks, SpotsAreInTheBinFrameAndCountedPerClassGraspAndReason) {
  const Pose X_BW = MakePose(Mat3(Eigen::AngleAxisd(M_PI / 2, Vec3::UnitZ())), Vec3(0.4, -0.1, 0.05));
  FailedPicks f(Rule(0.03, 3, 3), X_BW);
  // The part at (0.1, 0.02, 0.03) in the bin.
  const Vec3 p_W(0.1, 0.02, 0.03);
  f.Report(GraspAt(0, 2, X_BW * p_W, "hub_top@3~v"), PickFailure::kSlipped);
  f.Report(GraspAt(5, 2, Vec3(0.9, 0.9, 0.0), "hub_top@1"), PickFailure::kSlipped);
  f.Report(GraspAt(6, 1, Vec3(0.7, 0.9, 0.0), "side"), PickFailure::kNoVacuum);
  const std::vector<FailedPicks::Spot> spots = f.Spots();
  ASSERT_EQ(spots.size(), 3u);
  EXPECT_LT((spots[0].p_W - p_W).norm(), 1e-12);
  const std::vector<FailedPicks::Count> counts = f.Counts();
  ASSERT_EQ(counts.size(), 2u);
  EXPECT_EQ(counts[0].class_id, 1);
  EXPECT_EQ(counts[0].grasp, "side");
  EXPECT_EQ(counts[0].reason, PickFailure::kNoVacuum);
  EXPECT_EQ(counts[1].class_id, 2);
  EXPECT_EQ(counts[1].grasp, "hub_top");
  EXPECT_EQ(counts[1].failures, 2u);
}

// Bin detection measured the bin (Grasp::X_BW): a spot is kept in that bin's
// frame, not the nominal one, so it moves with the bin between captures.
TEST(FailedPicks, SpotsAreInTheMeasuredBinWhenTheGraspCarriesIt) {
  const Pose X_BW_nominal = MakePose(Mat3::Identity(), Vec3(0.5, 0.0, 0.0));
  const Pose X_BW_1 = MakePose(Mat3(Eigen::AngleAxisd(0.1, Vec3::UnitZ())), Vec3(0.53, -0.02, 0.0));
  const Pose X_BW_2 = MakePose(Mat3(Eigen::AngleAxisd(-0.05, Vec3::UnitZ())), Vec3(0.47, 0.03, 0.0));
  FailedPicks f(Rule(0.01, 3, 3), X_BW_nominal);
  const Vec3 p_W(0.1, 0.05, 0.03);  // the part in the bin
  Grasp failed = GraspAt(0, 1, X_BW_1 * p_W);
  failed.X_BW = X_BW_1;
  f.Report(failed, PickFailure::kNoVacuum);
  ASSERT_EQ(f.Spots().size(), 1u);
  EXPECT_LT((f.Spots()[0].p_W - p_W).norm(), 1e-12);
  // The next capture finds the bin moved: the same part, now elsewhere in
  // base, is still on the spot; a grasp at the old base position is not
  // (in the moved bin it lies 63 mm from the part).
  Grasp same = GraspAt(1, 1, X_BW_2 * p_W);
  same.X_BW = X_BW_2;
  Grasp old_place = GraspAt(2, 1, X_BW_1 * p_W);
  old_place.X_BW = X_BW_2;
  ASSERT_GT((X_BW_2.inverse() * (X_BW_1 * p_W) - p_W).norm(), 0.01);
  EXPECT_EQ(f.Judge(same), FailedPicks::Verdict::kWithheld);
  EXPECT_EQ(f.Judge(old_place), FailedPicks::Verdict::kServe);
  // A grasp without a measured bin is judged in the nominal bin.
  EXPECT_EQ(f.Judge(GraspAt(3, 1, X_BW_nominal * p_W)), FailedPicks::Verdict::kWithheld);
  EXPECT_EQ(f.Judge(GraspAt(4, 1, X_BW_2 * p_W)), FailedPicks::Verdict::kServe);
}

TEST(FailedPicks, OnlyTheFourReasonsDecodeFromTheWire) {
  PickFailure r = PickFailure::kUnspecified;
  EXPECT_TRUE(PickFailureFromWire(2, &r));
  EXPECT_EQ(r, PickFailure::kSlipped);
  EXPECT_TRUE(PickFailureFromWire(3, &r));
  EXPECT_EQ(r, PickFailure::kCollision);
  EXPECT_EQ(ToString(r), "collision");
  EXPECT_TRUE(PickFailureFromWire(0, &r));
  EXPECT_EQ(r, PickFailure::kUnspecified);
  EXPECT_FALSE(PickFailureFromWire(4, &r));
  EXPECT_FALSE(PickFailureFromWire(-1, &r));
}

// On a rendered pile, ground truth: the part whose pick failed and the parts
// truly within the radius of it leave the queue at once and stay out of the
// plans of the next N captures (re-captured, re-planned); capture N + 1 has
// them again.
TEST(FailedPickFeedback, AReportedFailureWithdrawsThatPartsGraspsForNCapturesThenReleasesThem) {
  Result<Cell> cell = LoadDefaultCell();
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  cell->source.kind = SourceSpec::Kind::kSynthetic;
  cell->source.num_parts = 10;
  cell->source.seed = 3;
  TaskSpec task = *cell->FindTask(0);
  task.failed_picks = Rule(0.06, 2, 3);
  auto source = MakeCaptureSource(*cell);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  BinPickingPlannerOptions options;
  options.teach_file = "-";
  auto planner = BinPickingPlanner::Create(*cell, std::make_shared<TruthPerception>(*cell), std::move(*source), options);
  ASSERT_TRUE(planner.ok()) << planner.status().ToString();
  BinPickingPlanner& p = **planner;

  FailedPicks failed(task.failed_picks, cell->bin.X_BW);
  GraspQueue queue;
  queue.SetScreen([&failed](std::deque<Grasp>& grasps) { return failed.Screen(grasps); });
  PlanRequest request;
  request.task = task;
  std::vector<PartTruth> truth;
  // One capture: its plan into the queue; @returns the true instances queued.
  auto capture = [&](bool age) {
    if (age) failed.OnCapture();
    auto scene = p.Capture(request);
    EXPECT_TRUE(scene.ok());
    truth = static_cast<const CapturedFrame&>(**scene).frame().truth->parts;
    auto plan = p.Plan(request, **scene);
    EXPECT_TRUE(plan.ok());
    queue.Replace(*plan);
    std::set<int> queued;
    for (int id : queue.contents().queued) queued.insert(p.TruthInstanceOf(task.id, id));
    return queued;
  };
  auto truth_of = [&](int instance) -> Vec3 {
    for (const PartTruth& t : truth) {
      if (t.instance_id == instance) return Vec3(t.X_BO.translation());
    }
    ADD_FAILURE() << "no true instance " << instance;
    return Vec3::Zero();
  };

  const std::set<int> before = capture(false);
  ASSERT_GE(before.size(), 4u) << "the pile must leave other parts to pick";
  // The robot fails on the first part of the queue that has a true neighbour
  // within the radius.
  const GraspQueue::Popped first = queue.PopFirst([&](const Grasp& g, int) {
    const int id = p.TruthInstanceOf(task.id, g.instance_id);
    if (id < 0) return false;
    return std::any_of(truth.begin(), truth.end(), [&](const PartTruth& t) {
      return t.instance_id != id && (t.X_BO.translation() - truth_of(id)).norm() <= task.failed_picks.radius;
    });
  });
  ASSERT_TRUE(first.grasp);
  const int failed_part = p.TruthInstanceOf(task.id, first.grasp->instance_id);
  ASSERT_GE(failed_part, 0);
  failed.Report(*first.grasp, PickFailure::kSlipped);
  // The true neighbours (the oracle's poses are exact: the same set as the screen's).
  std::set<int> near;
  for (const PartTruth& t : truth) {
    if ((t.X_BO.translation() - truth_of(failed_part)).norm() <= task.failed_picks.radius) near.insert(t.instance_id);
  }
  ASSERT_GE(near.size(), 2u) << "the test needs a neighbour within the radius";
  int queued_near = 0;
  for (int id : queue.contents().queued) queued_near += near.count(p.TruthInstanceOf(task.id, id)) > 0 ? 1 : 0;
  EXPECT_EQ(queue.Rescreen(), queued_near) << "the neighbours' grasps leave the queue at once";
  for (int id : queue.contents().queued) EXPECT_EQ(near.count(p.TruthInstanceOf(task.id, id)), 0u);

  for (int n = 1; n <= task.failed_picks.captures; ++n) {
    const std::set<int> queued = capture(true);
    for (int id : near) EXPECT_EQ(queued.count(id), 0u) << "capture " << n << " after the failure: part " << id;
    EXPECT_FALSE(queued.empty()) << "other parts are still picked";
  }
  const std::set<int> released = capture(true);
  EXPECT_EQ(released.count(failed_part), 1u) << "capture N + 1 releases the spot";
}

// Issue 41's "seed programs that never send it behave exactly as before": a
// robot that never reports a failure (no seed sends command 60) is served by
// the task's screened queue exactly what a queue without the feedback serves,
// capture after capture (each capture ages the feedback as binpickd does),
// while the pile is picked down.
TEST(FailedPickFeedback, ARobotThatNeverReportsIsServedExactlyWhatAQueueWithoutTheFeedbackServes) {
  Result<Cell> cell = LoadDefaultCell();
  ASSERT_TRUE(cell.ok()) << cell.status().ToString();
  cell->source.kind = SourceSpec::Kind::kSynthetic;
  cell->source.simulate_picks = true;
  cell->source.num_parts = 12;
  cell->source.seed = 5;
  const TaskSpec task = *cell->FindTask(0);
  auto source = MakeCaptureSource(*cell);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  auto* pile = dynamic_cast<SyntheticSource*>(source->get());
  ASSERT_NE(pile, nullptr);
  BinPickingPlannerOptions options;
  options.teach_file = "-";
  auto planner = BinPickingPlanner::Create(*cell, std::make_shared<TruthPerception>(*cell), std::move(*source), options);
  ASSERT_TRUE(planner.ok()) << planner.status().ToString();
  BinPickingPlanner& p = **planner;

  FailedPicks failed(task.failed_picks, cell->bin.X_BW);
  GraspQueue screened, plain;
  screened.SetScreen([&failed](std::deque<Grasp>& grasps) { return failed.Screen(grasps); });
  PlanRequest request;
  request.task = task;
  int served = 0;
  for (int capture = 0; capture < 4; ++capture) {
    failed.OnCapture();
    auto scene = p.Capture(request);
    ASSERT_TRUE(scene.ok()) << scene.status().ToString();
    auto plan = p.Plan(request, **scene);
    ASSERT_TRUE(plan.ok()) << plan.status().ToString();
    ASSERT_FALSE(plan->grasps.empty()) << "capture " << capture;
    ASSERT_TRUE(screened.Replace(*plan));
    ASSERT_TRUE(plain.Replace(*plan));
    EXPECT_EQ(screened.Rescreen(), 0) << "capture " << capture;
    std::optional<int> picked;
    for (;;) {
      const GraspQueue::Popped a = screened.Pop();
      const GraspQueue::Popped b = plain.Pop();
      ASSERT_EQ(a.grasp.has_value(), b.grasp.has_value()) << "capture " << capture;
      EXPECT_EQ(a.remaining, b.remaining);
      EXPECT_EQ(a.outcome, b.outcome);
      EXPECT_EQ(a.withdrawn.size(), b.withdrawn.size());
      if (!a.grasp) break;
      EXPECT_EQ(a.grasp->instance_id, b.grasp->instance_id);
      EXPECT_EQ(a.grasp->name, b.grasp->name);
      EXPECT_TRUE(a.grasp->X_BT.matrix() == b.grasp->X_BT.matrix()) << a.grasp->name;
      ++served;
      if (!picked) picked = p.TruthInstanceOf(task.id, a.grasp->instance_id);
    }
    ASSERT_TRUE(picked && *picked >= 0);
    pile->NotifyPicked(*picked);  // the robot took the first part it was given
  }
  EXPECT_GE(served, 4);
}

}  // namespace
}  // namespace bp
