// A part's own points never block its own grasps, a neighbour's still do
// (GraspPlanningOptions::surface_explain_distance), on rendered piles with
// the true detections (TruthPerception: the ground truth is the oracle).
#include <gtest/gtest.h>

#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "collision/mesh_collider.h"
#include "core/cell.h"
#include "core/mesh.h"
#include "grasp/grasp_planning.h"
#include "pipeline/synthetic_source.h"
#include "pipeline/truth_perception.h"
#include "tests/testing/truth_piles.h"

namespace bp {
namespace {

const Cell& PileCell() {
  static const Cell cell = testing::SyntheticDefaultCell(12);
  return cell;
}

using ModelResult = Result<std::shared_ptr<const GraspPlanningModel>>;

// PileCell's planning models with the rule (surface_explain_distance at its
// default) and with it off (0), both with part_margin 0: the exact
// neighbours, so that a refusal by points is not hidden by the margin.
std::pair<ModelResult, ModelResult> RuleAndOffModels() {
  GraspPlanningOptions rule;
  rule.part_margin = 0;
  GraspPlanningOptions off = rule;
  off.surface_explain_distance = 0;
  return {GraspPlanningModel::Build(PileCell(), rule), GraspPlanningModel::Build(PileCell(), off)};
}

// Pile `seed` of PileCell at camera config `config`, perceived by the truth.
void RenderPile(int config, uint64_t seed, std::optional<Frame>& frame, std::optional<PerceptionResult>& truth) {
  Cell cell = PileCell();
  testing::RenderTruthPile(cell, config, seed, frame, truth);
}

// A view's support: the true detections' every-pixel support (TruthPerception)
// less the points on faces seen more obliquely than 60 deg (a part's grazing
// faces and the edges round them, which the view perception matches in
// leaves out, as does a segment that ends at a depth edge).
PerceptionResult ViewSupportOnly(const PerceptionResult& truth, const Frame& frame) {
  std::map<int, CollisionGeometryPtr> parts;
  for (const PartSpec& p : PileCell().parts) {
    parts[p.class_id] = CollisionGeometry::FromMesh(LoadMesh(p.mesh).value()).value();
  }
  const Vec3 eye = frame.X_BC.translation();
  PerceptionResult out = truth;
  for (Detection& d : out.detections) {
    std::vector<int32_t> kept;
    for (int32_t i : d.support) {
      const Vec3 p = truth.roi_points_B[static_cast<size_t>(i)].cast<double>();
      const SurfacePoint s = NearestSurfacePoint(*parts.at(d.class_id), d.X_BO, p);
      if (s.normal_W.dot((eye - p).normalized()) >= 0.5) kept.push_back(i);
    }
    d.support = std::move(kept);
  }
  return out;
}

using testing::PlanVerdicts;
using testing::VerdictMap;

// On piles whose detections are true but supported by one view each (their
// grazing and edge points unexplained): without the rule some candidates
// are refused by their own part's points, with it they are accepted, land
// on nothing but their part on the true pile, and nothing is accepted that
// the true explanation (every pixel of each detected part, the rule off)
// refuses. With each detection in turn left undetected, its points are
// another part's: the grasps they refuse under the true explanation stay
// refused under the rule.
TEST(OwnPoints, APartsOwnUnsupportedPointsNoLongerBlockItsGraspsButAnUndetectedNeighboursStillDo) {
  const auto models = RuleAndOffModels();
  const ModelResult& with_rule = models.first;
  const ModelResult& without = models.second;
  ASSERT_TRUE(with_rule.ok() && without.ok());
  const TaskSpec task = *PileCell().FindTask(0);
  int recovered = 0, kept_refused = 0;
  for (const auto& [config, seed] : std::vector<std::pair<int, uint64_t>>{{1, 5}, {2, 6}}) {
    SCOPED_TRACE("config " + std::to_string(config) + " seed " + std::to_string(seed));
    std::optional<Frame> frame;
    std::optional<PerceptionResult> truth;
    ASSERT_NO_FATAL_FAILURE(RenderPile(config, seed, frame, truth));
    const PerceptionResult view = ViewSupportOnly(*truth, *frame);
    const GraspPlan ruled_plan = PlanGrasps(**with_rule, task, view, {}, &*frame);
    const PlanVerdicts alone = VerdictMap(PlanGrasps(**without, task, view, {}, &*frame));
    const PlanVerdicts ruled = VerdictMap(ruled_plan);
    const PlanVerdicts ideal = VerdictMap(PlanGrasps(**without, task, *truth, {}, &*frame));
    for (const GraspCandidate& c : ruled_plan.candidates) {
      if (c.rejected) continue;
      const std::pair<int, std::string> key{c.detection, c.name};
      EXPECT_FALSE(ideal.at(key).has_value()) << c.name << " on detection " << c.detection;
      if (alone.at(key) != RejectReason::kPoints) continue;
      ++recovered;
      // The judge's check on the true pile (every part detected exactly here).
      EXPECT_EQ((*with_rule)->CheckAgainstParts(task.gripper, c.X_BT, truth->detections, c.detection,
                                                PileCell().bin.X_BW),
                std::nullopt)
          << c.name << " on detection " << c.detection;
    }
    kept_refused += testing::ExpectUndetectedPartsStillRefuse(**with_rule, **without, task, view, *truth, *frame,
                                                              ideal, /*first_only=*/false);
  }
  EXPECT_GT(recovered, 0);
  EXPECT_GT(kept_refused, 0);
}

// The grasp the rule frees, with a neighbour's surface 5 mm off its part
// (a patch of points over the grasp point, across the approach): refused by
// those points, which lie beyond the surface distance.
// The patch is added to the ROI points only, not to the depth image, and
// some of it lies behind the part's near face at its pixels, where no
// camera could have measured it: mixed_on_part_rays (which reads the depth
// image) rightly drops those points, so it is off in both models here; this
// test is about surface_explain_distance alone.
TEST(OwnPoints, ANeighboursPointsFiveMillimetresFromThePartStillBlockTheGraspTheRuleFrees) {
  GraspPlanningOptions rule;
  rule.mixed_on_part_rays = 0;
  auto with_rule = GraspPlanningModel::Build(PileCell(), rule);
  GraspPlanningOptions off = rule;
  off.surface_explain_distance = 0;
  auto without = GraspPlanningModel::Build(PileCell(), off);
  ASSERT_TRUE(with_rule.ok() && without.ok());
  EXPECT_LT((*with_rule)->options().surface_explain_distance, 0.003);
  const TaskSpec task = *PileCell().FindTask(0);
  std::optional<Frame> frame;
  std::optional<PerceptionResult> truth;
  ASSERT_NO_FATAL_FAILURE(RenderPile(1, 5, frame, truth));
  PerceptionResult view = ViewSupportOnly(*truth, *frame);
  const GraspPlan before = PlanGrasps(**without, task, view, {}, &*frame);
  const GraspPlan after = PlanGrasps(**with_rule, task, view, {}, &*frame);
  ASSERT_EQ(before.candidates.size(), after.candidates.size());
  size_t freed = before.candidates.size();
  for (size_t i = 0; i < before.candidates.size() && freed == before.candidates.size(); ++i) {
    if (before.candidates[i].rejected == RejectReason::kPoints && !after.candidates[i].rejected) freed = i;
  }
  ASSERT_LT(freed, before.candidates.size()) << "no grasp refused by its own points";
  const GraspCandidate& c = after.candidates[freed];
  // The neighbour: points every mm within 8 mm of the grasp's axis, 5 mm
  // from the grasp point against the approach (X_BG: the contact frame).
  const Vec3 x = c.X_BG.linear().col(0), y = c.X_BG.linear().col(1), z = c.X_BG.linear().col(2);
  const Vec3 centre = c.X_BG.translation() - 0.005 * z;
  for (int i = -8; i <= 8; ++i) {
    for (int j = -8; j <= 8; ++j) {
      if (i * i + j * j > 64) continue;
      const Vec3 p = centre + 0.001 * (i * x + j * y);
      // A neighbour 5 mm off: none of its points nearer the part (a concave part's other faces).
      const Detection& d = view.detections[static_cast<size_t>(c.detection)];
      if (*(*with_rule)->SurfaceDistance(d.class_id, d.X_BO, p) < 0.0045) continue;
      view.roi_points_B.push_back(p.cast<float>());
    }
  }
  const GraspPlan blocked = PlanGrasps(**with_rule, task, view, {}, &*frame);
  ASSERT_EQ(blocked.candidates.size(), after.candidates.size());
  EXPECT_EQ(blocked.candidates[freed].name, c.name);
  EXPECT_EQ(blocked.candidates[freed].rejected, RejectReason::kPoints);
}

// Piles with every detection's pose a degree off its truth (turned about
// one of its axes through its origin; the strict eval passes 5 deg), its
// support still one view: the points the rule explains are the part's true
// surface, where the estimated mesh is not. A grasp the rule frees (refused
// by points with it off) whose lifted sweep meets the true part (the
// judge's self check) is refused with it too, by those points (kSelf),
// and there is one on these piles (a tee's run_top turned vertical, as
// traced in docs/tuning.md "Own points"). No grasp the rule accepts cuts
// into its true part unless the rule off accepts it too.
TEST(OwnPoints, APartsOwnPointsStillRefuseItsGraspWhereItsPoseIsADegreeOff) {
  const auto models = RuleAndOffModels();
  const ModelResult& with_rule = models.first;
  const ModelResult& without = models.second;
  ASSERT_TRUE(with_rule.ok() && without.ok());
  const TaskSpec task = *PileCell().FindTask(0);
  int freed_into_the_part = 0;
  for (const auto& [config, seed] : std::vector<std::pair<int, uint64_t>>{{1, 5}, {1, 11}}) {
    std::optional<Frame> frame;
    std::optional<PerceptionResult> truth;
    ASSERT_NO_FATAL_FAILURE(RenderPile(config, seed, frame, truth));
    for (int axis = 0; axis < 3; ++axis) {
      for (const double deg : {-1.0, 1.0}) {
        SCOPED_TRACE("config " + std::to_string(config) + " seed " + std::to_string(seed) + " axis " +
                     std::to_string(axis) + " " + std::to_string(deg) + " deg");
        PerceptionResult view = ViewSupportOnly(*truth, *frame);
        for (Detection& d : view.detections) {
          d.X_BO = d.X_BO * Pose(Eigen::AngleAxisd(deg * M_PI / 180.0, Vec3::Unit(axis)));
        }
        const GraspPlan ruled = PlanGrasps(**with_rule, task, view, {}, &*frame);
        const GraspPlan alone = PlanGrasps(**without, task, view, {}, &*frame);
        ASSERT_EQ(ruled.candidates.size(), alone.candidates.size());
        for (size_t i = 0; i < ruled.candidates.size(); ++i) {
          const GraspCandidate& c = ruled.candidates[i];
          // The judge's self check: the lifted sweep against the true part alone.
          const Detection part[] = {truth->detections[static_cast<size_t>(c.detection)]};
          if ((*with_rule)->CheckAgainstParts(task.gripper, c.X_BT, part, 0, PileCell().bin.X_BW, false) !=
              RejectReason::kSelf) {
            continue;
          }
          if (!c.rejected) {
            EXPECT_FALSE(alone.candidates[i].rejected.has_value()) << c.name << " on detection " << c.detection;
          }
          if (alone.candidates[i].rejected == RejectReason::kPoints && c.rejected != RejectReason::kPoints) {
            ++freed_into_the_part;
            EXPECT_EQ(c.rejected, RejectReason::kSelf) << c.name << " on detection " << c.detection;
          }
        }
      }
    }
  }
  EXPECT_GT(freed_into_the_part, 0);
}

}  // namespace
}  // namespace bp
