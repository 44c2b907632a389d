// The space a detected part hides from the camera is an obstacle for the
// other parts' grasps (GraspPlanningOptions::hidden_behind_parts), on a
// rendered pile perceived by the ground truth (TruthPerception: the truth
// is the oracle), with a part left undetected under detected ones, as
// perception missed one in clear seed 16349.
#include <gtest/gtest.h>

#include <cmath>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include "core/cell.h"
#include "grasp/grasp_planning.h"
#include "pipeline/truth_perception.h"
#include "tests/testing/truth_piles.h"

namespace bp {
namespace {

// The default cell's synthetic piles of 20 parts (as `binpick clear`).
const Cell& PileCell() {
  static const Cell cell = testing::SyntheticDefaultCell(20);
  return cell;
}

struct Counts {
  int hits_off = 0;      // grasps accepted without the rule that hit the part on the true pile
  int refused = 0;       // of those, refused with the rule as kHiddenSpace
  int hits_rule = 0;     // grasps accepted with the rule that hit the part on the true pile
};

// Plans `scene` with and without the rule and counts the accepted grasps
// on the other parts (not on detection `own` of `scene`, -1: none) whose
// swept gripper meets true part `part` (truth.detections[part], at its true
// pose) on the true pile, and those of them the rule refuses as `reason`.
void CountHits(const GraspPlanningModel& rule, const GraspPlanningModel& off, const TaskSpec& task,
               const PerceptionResult& scene, const PerceptionResult& truth, const Frame& frame, int part, int own,
               RejectReason reason, Counts& counts) {
  const GraspPlan ruled = PlanGrasps(rule, task, scene, {}, &frame);
  const GraspPlan alone = PlanGrasps(off, task, scene, {}, &frame);
  ASSERT_EQ(ruled.candidates.size(), alone.candidates.size());
  const std::span<const Detection> hit(&truth.detections[static_cast<size_t>(part)], 1);
  const auto hits = [&](const GraspCandidate& c) {
    return off.CheckAgainstParts(task.gripper, c.X_BT, hit, -1, PileCell().bin.X_BW, /*with_bin=*/false).has_value();
  };
  for (size_t i = 0; i < alone.candidates.size(); ++i) {
    const GraspCandidate& a = alone.candidates[i];
    const GraspCandidate& r = ruled.candidates[i];
    ASSERT_EQ(a.name, r.name);
    if (a.detection == own) continue;
    if (!a.rejected && hits(a)) {
      ++counts.hits_off;
      if (r.rejected == reason) ++counts.refused;
    }
    if (!r.rejected && hits(r)) ++counts.hits_rule;
    // The rule only adds refusals (a deferred grasp may be kept when the
    // rule refuses the others: kHidden).
    if (a.rejected && a.rejected != RejectReason::kHidden) {
      EXPECT_TRUE(r.rejected.has_value()) << r.name << " on detection " << r.detection;
    }
  }
}

class HiddenSpace : public ::testing::Test {
 protected:
  void SetUp() override {
    GraspPlanningOptions off_options;
    off_options.hidden_behind_parts = false;
    auto r = GraspPlanningModel::Build(PileCell(), GraspPlanningOptions{});
    auto o = GraspPlanningModel::Build(PileCell(), off_options);
    ASSERT_TRUE(r.ok() && o.ok());
    rule_ = *r;
    off_ = *o;
    task_ = *PileCell().FindTask(0);
  }
  std::shared_ptr<const GraspPlanningModel> rule_, off_;
  TaskSpec task_;
};

// A part left undetected under detected ones (its measured points stay,
// unexplained): grasps on the other parts whose tools pass under the
// detected parts into it are accepted without the rule and hit it on the
// true pile; the rule refuses them (kHiddenSpace), and fewer accepted
// grasps hit it. Pile 15 (found among piles 1-30: the only one where a
// tool met a part so) has a bushing's hub_side grasp doing it.
TEST_F(HiddenSpace, AToolPassingUnderADetectedPartIntoAPartMissedThereIsRefused) {
  Counts counts;
  for (uint64_t seed : {15}) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    Cell cell = PileCell();
    std::optional<Frame> frame;
    std::optional<PerceptionResult> truth;
    ASSERT_NO_FATAL_FAILURE(testing::RenderTruthPile(cell, 0, seed, frame, truth));
    for (int k = 0; k < static_cast<int>(truth->detections.size()); ++k) {
      // A part mostly in view is not hidden under another.
      if (truth->detections[static_cast<size_t>(k)].visible_fraction > 0.6) continue;
      SCOPED_TRACE("detection " + std::to_string(k) + " undetected");
      ASSERT_NO_FATAL_FAILURE(CountHits(*rule_, *off_, task_, testing::Without(*truth, k), *truth, *frame, k, -1,
                                               RejectReason::kHiddenSpace, counts));
    }
  }
  EXPECT_GT(counts.hits_off, 0);
  EXPECT_GT(counts.refused, 0);
  EXPECT_LT(counts.hits_rule, counts.hits_off);
}

// The spaces built on demand (hidden_space_on_demand, only where a sweep
// that passed every other check comes near one) give each candidate the
// verdict of building every space first: on the pile of the test above,
// perceived by the truth and with each part less than 60% visible left
// undetected in turn, every candidate is refused for the same reason or
// accepted by both, and some are refused as kHiddenSpace.
TEST_F(HiddenSpace, BuiltOnDemandEachCandidateHasTheVerdictOfEverySpaceBuiltFirst) {
  GraspPlanningOptions eager_options;
  eager_options.hidden_space_on_demand = false;
  auto eager = GraspPlanningModel::Build(PileCell(), eager_options);
  ASSERT_TRUE(eager.ok());
  Cell cell = PileCell();
  std::optional<Frame> frame;
  std::optional<PerceptionResult> truth;
  ASSERT_NO_FATAL_FAILURE(testing::RenderTruthPile(cell, 0, 15, frame, truth));
  std::vector<PerceptionResult> scenes = {*truth};
  for (int k = 0; k < static_cast<int>(truth->detections.size()); ++k) {
    if (truth->detections[static_cast<size_t>(k)].visible_fraction <= 0.6) scenes.push_back(testing::Without(*truth, k));
  }
  int hidden_space = 0, accepted = 0;
  for (size_t s = 0; s < scenes.size(); ++s) {
    SCOPED_TRACE("scene " + std::to_string(s));
    const GraspPlan lazy = PlanGrasps(*rule_, task_, scenes[s], {}, &*frame);
    const GraspPlan all = PlanGrasps(**eager, task_, scenes[s], {}, &*frame);
    ASSERT_EQ(lazy.candidates.size(), all.candidates.size());
    for (size_t i = 0; i < all.candidates.size(); ++i) {
      const GraspCandidate& a = all.candidates[i];
      const GraspCandidate& l = lazy.candidates[i];
      ASSERT_EQ(a.name, l.name);
      EXPECT_EQ(a.rejected, l.rejected) << a.name << " on detection " << a.detection;
      hidden_space += a.rejected == RejectReason::kHiddenSpace ? 1 : 0;
      accepted += a.rejected ? 0 : 1;
    }
  }
  EXPECT_GT(hidden_space, 0);
  EXPECT_GT(accepted, 0);
}

}  // namespace
}  // namespace bp
