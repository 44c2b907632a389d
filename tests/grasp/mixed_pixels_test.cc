// The mixed pixels on a detected part's rays (behind its edge, or in front
// of it beside a nearer neighbour) no longer refuse grasps that hit nothing
// on the true pile (GraspPlanningOptions::mixed_on_part_rays), on rendered
// piles whose every edge pixel is mixed, with the true detections
// (TruthPerception: the ground truth is the oracle).
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
#include "pipeline/truth_perception.h"
#include "tests/testing/truth_piles.h"

namespace bp {
namespace {

// The default cell's synthetic piles of 12 parts, each camera config's
// edge pixels mixed with the depth behind them (NoiseModel::mixed_pixels 1:
// every pixel whose clean depth differs from a 4-neighbour's by more than
// 1 cm measures a depth between the two).
const Cell& MixedCell() {
  static const Cell cell = [] {
    Cell out = testing::SyntheticDefaultCell(12);
    for (CameraConfig& config : out.camera.configs) config.noise.mixed_pixels = 1.0;
    return out;
  }();
  return cell;
}

// A fit's support: each true detection's pixels (TruthPerception labels a
// mixed pixel with the part in front) less those farther than 1 mm from
// its surface, as a pose fit leaves them out: a mixed pixel's depth lies
// between the part's edge and what is behind it.
PerceptionResult FitSupportOnly(const PerceptionResult& truth) {
  std::map<int, CollisionGeometryPtr> parts;
  for (const PartSpec& p : MixedCell().parts) {
    parts[p.class_id] = CollisionGeometry::FromMesh(LoadMesh(p.mesh).value()).value();
  }
  PerceptionResult out = truth;
  for (Detection& d : out.detections) {
    std::vector<int32_t> kept;
    for (int32_t i : d.support) {
      const Vec3 p = truth.roi_points_B[static_cast<size_t>(i)].cast<double>();
      if (NearestSurfacePoint(*parts.at(d.class_id), d.X_BO, p).distance <= 0.001) kept.push_back(i);
    }
    d.support = std::move(kept);
  }
  return out;
}

// The candidates the rule frees (refused by points with it off, accepted
// with it), each checked by the judge against the true pile (every true
// part, the one left out of `scene` included, and the bin where it stands).
int ExpectFreedGraspsHitNothing(const GraspPlanningModel& rule, const GraspPlanningModel& off, const TaskSpec& task,
                                const PerceptionResult& scene, const PerceptionResult& truth, const Frame& frame,
                                int skipped) {
  const GraspPlan ruled = PlanGrasps(rule, task, scene, {}, &frame);
  const GraspPlan alone = PlanGrasps(off, task, scene, {}, &frame);
  EXPECT_EQ(ruled.candidates.size(), alone.candidates.size());
  int freed = 0;
  for (size_t i = 0; i < ruled.candidates.size() && i < alone.candidates.size(); ++i) {
    const GraspCandidate& c = ruled.candidates[i];
    if (c.rejected || alone.candidates[i].rejected != RejectReason::kPoints) continue;
    ++freed;
    const int target = skipped >= 0 && c.detection >= skipped ? c.detection + 1 : c.detection;
    EXPECT_EQ(rule.CheckAgainstParts(task.gripper, c.X_BT, truth.detections, target, MixedCell().bin.X_BW),
              std::nullopt)
        << c.name << " on detection " << target;
  }
  return freed;
}

// Without the rule, grasps beside a part's edge are refused by the mixed
// points floating behind or in front of it (and the occluded columns and
// dropout rays under them), though they hit nothing on the true pile; with
// it they are accepted. Every grasp it frees passes the judge on the true
// pile, also with each detection in turn left undetected (its points then
// another part's, on no detected part's ray: they stay).
TEST(MixedPixels, PointsOnADetectedPartsRaysNoLongerRefuseGraspsThatHitNothing) {
  GraspPlanningOptions rule_options;
  GraspPlanningOptions off_options;
  off_options.mixed_on_part_rays = 0;
  auto rule = GraspPlanningModel::Build(MixedCell(), rule_options);
  auto off = GraspPlanningModel::Build(MixedCell(), off_options);
  ASSERT_TRUE(rule.ok() && off.ok());
  EXPECT_GT((*rule)->options().mixed_on_part_rays, 0.0);
  const TaskSpec task = *MixedCell().FindTask(0);
  int freed = 0, freed_with_one_undetected = 0;
  for (const auto& [config, seed] : std::vector<std::pair<int, uint64_t>>{{1, 13}, {2, 12}}) {
    SCOPED_TRACE("config " + std::to_string(config) + " seed " + std::to_string(seed));
    Cell cell = MixedCell();
    std::optional<Frame> frame;
    std::optional<PerceptionResult> truth;
    ASSERT_NO_FATAL_FAILURE(testing::RenderTruthPile(cell, config, seed, frame, truth));
    const PerceptionResult fit = FitSupportOnly(*truth);
    freed += ExpectFreedGraspsHitNothing(**rule, **off, task, fit, *truth, *frame, -1);
    for (int k = 0; k < static_cast<int>(truth->detections.size()); ++k) {
      SCOPED_TRACE("detection " + std::to_string(k) + " undetected");
      freed_with_one_undetected +=
          ExpectFreedGraspsHitNothing(**rule, **off, task, testing::Without(fit, k), *truth, *frame, k);
    }
  }
  EXPECT_GT(freed, 0);
  EXPECT_GT(freed_with_one_undetected, 0);
}

}  // namespace
}  // namespace bp
