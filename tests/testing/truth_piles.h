// Rendered piles perceived by the ground truth, and the grasp plan's
// verdicts on them: what the grasp tests that compare point-explanation
// rules (tests/grasp/grasp_planning_test.cc, own_points_test.cc,
// mixed_pixels_test.cc) share.
#pragma once

#include <gtest/gtest.h>

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <utility>

#include "core/cell.h"
#include "grasp/grasp_planning.h"
#include "pipeline/synthetic_source.h"
#include "pipeline/truth_perception.h"

namespace bp::testing {

// The default cell with a synthetic source of `num_parts` parts: the piles
// the truth-pile tests render.
inline Cell SyntheticDefaultCell(int num_parts) {
  Result<Cell> c = LoadDefaultCell();
  EXPECT_TRUE(c.ok()) << c.status().ToString();
  Cell out = *c;
  out.source.kind = SourceSpec::Kind::kSynthetic;
  out.source.num_parts = num_parts;
  return out;
}

// Renders synthetic pile `seed` of `cell` at camera config `config` and
// perceives it with the true detections (TruthPerception): the frame and
// the scene that grasp planning runs on. Sets cell.source.seed.
inline void RenderTruthPile(Cell& cell, int config, uint64_t seed, std::optional<Frame>& frame,
                            std::optional<PerceptionResult>& perception) {
  cell.source.seed = seed;
  auto source = MakeSyntheticSource(cell);
  ASSERT_TRUE(source.ok()) << source.status().ToString();
  CaptureRequest capture;
  capture.config_id = config;
  auto captured = (*source)->Capture(capture);
  ASSERT_TRUE(captured.ok()) << captured.status().ToString();
  auto perceived = TruthPerception(cell).Run(*captured);
  ASSERT_TRUE(perceived.ok());
  frame = std::move(*captured);
  perception = std::move(*perceived);
}

// Every candidate's verdict by (detection, grasp name).
using PlanVerdicts = std::map<std::pair<int, std::string>, std::optional<RejectReason>>;

// The verdicts of `plan`; `skipped` is a detection left out of its scene
// (Without): the later detections' indices are one lower there, and are
// mapped back to the full scene's.
inline PlanVerdicts VerdictMap(const GraspPlan& plan, int skipped = -1) {
  PlanVerdicts v;
  for (const GraspCandidate& c : plan.candidates) {
    const int d = skipped >= 0 && c.detection >= skipped ? c.detection + 1 : c.detection;
    v[{d, c.name}] = c.rejected;
  }
  return v;
}

// `scene` with detection `detection` left undetected (its points stay).
inline PerceptionResult Without(PerceptionResult scene, int detection) {
  scene.detections.erase(scene.detections.begin() + detection);
  return scene;
}

// With each detection k of the truth in turn left undetected (its points
// stay: another part's now), planned on `scene` (the truth's detections
// with a thinner support) less k: every grasp `rule` accepts, `off` accepts
// on the truth less k too (the true explanation), and every grasp the
// truth less k refuses by points (kPoints) that the whole truth accepts
// (`ideal`: `off` on the truth) stays refused under `rule`: the points of a
// part left undetected still block. Returns how many such refusals `rule`
// kept; stops after the first k with one when `first_only`.
inline int ExpectUndetectedPartsStillRefuse(const GraspPlanningModel& rule, const GraspPlanningModel& off,
                                            const TaskSpec& task, const PerceptionResult& scene,
                                            const PerceptionResult& truth, const Frame& frame,
                                            const PlanVerdicts& ideal, bool first_only) {
  int kept_refused = 0;
  for (int k = 0; k < static_cast<int>(truth.detections.size()); ++k) {
    if (first_only && kept_refused > 0) break;
    SCOPED_TRACE("detection " + std::to_string(k) + " undetected");
    const PlanVerdicts ruled_k = VerdictMap(PlanGrasps(rule, task, Without(scene, k), {}, &frame), k);
    const PlanVerdicts ideal_k = VerdictMap(PlanGrasps(off, task, Without(truth, k), {}, &frame), k);
    for (const auto& [key, verdict] : ruled_k) {
      if (!verdict) {
        EXPECT_FALSE(ideal_k.at(key).has_value()) << key.second << " on detection " << key.first;
      }
      if (ideal_k.at(key) == RejectReason::kPoints && !ideal.at(key)) {
        EXPECT_TRUE(verdict.has_value()) << key.second << " on detection " << key.first;
        ++kept_refused;
      }
    }
  }
  return kept_refused;
}

}  // namespace bp::testing
