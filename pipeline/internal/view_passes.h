// Perception's passes over the views: waves by size, the second look and the
// residual pass (docs/perception_pipeline.md). Each matches views
// (ViewMatcher) and hands the candidates to acceptance. Private to
// bp_pipeline.
#pragma once

#include <vector>

#include "pipeline/internal/acceptance.h"
#include "pipeline/internal/segmentation.h"
#include "pipeline/internal/view_matching.h"
#include "pipeline/perception.h"

namespace bp::internal {

// The views a wave matched whose best hypothesis scored below
// PerceptionOptions::second_look_below, with what their wave left.
struct WeakViews {
  ViewSet views;                   // segment views first, then region views
  std::vector<ViewTrace> traces;   // per view; empty traces when the waves kept none
};

// Views in waves by size (PerceptionOptions::view_waves): each wave's
// candidates are accepted before the next, and a view of a later wave whose
// points lie mostly (60%) on an accepted detection's surface is a piece of a
// part already found and is not matched. `views`: segment views then region
// views (views.first_region). Adds the skipped views to *views_explained.
// @returns the weak views for the second look (none when it is off or the
// run is thorough), and the time spent matching and accepting, ms.
struct WaveResult {
  WeakViews weak;
  double match_ms = 0.0;
  double accept_ms = 0.0;
  int views_explained = 0;
};
WaveResult MatchInWaves(ViewSet views, const PerceptionOptions& options, bool thorough, const Segments& segments,
                        ViewMatcher& matcher, Acceptance& acceptance);

// Second look (PerceptionOptions::second_look_below): the weak views of
// second_look_min_points or more that no confident detection explains are
// matched again with the wider search; what they find competes with the
// detections so far by score. @returns the views matched again.
int SecondLook(WeakViews weak, const PerceptionOptions& options, const Segments& segments, ViewMatcher& matcher,
               Acceptance& acceptance);

// Residual pass: the segments a detection explained only in part (touching
// parts merged into one segment), on their unclaimed samples, when at least
// min_segment_points and a quarter of the segment are left.
std::vector<ViewIndices> ResidualViews(const Segments& segments, const Acceptance& acceptance,
                                       int min_segment_points);

// Residual regions (PerceptionOptions::residual_regions): the samples no
// live detection explains (Acceptance::UnexplainedSamples), of kept segments
// and of pieces below min_segment_points alike, grouped by grid
// connectivity: samples of cells up to 3 cells apart (across holes in the
// depth) within Segments::grid_jump join. Each group of
// at least min_segment_points samples is a view, unless it is nearly one
// kept segment that the waves matched already (90% of its samples and none
// from elsewhere). Joins the pieces of a part the segmentation split or left
// unsegmented once its neighbours are found. With across_jumps
// (PerceptionOptions::residual_across_jumps), the groups whose cells touch
// (within the same reach) across a depth jump are joined too, and each such
// union of two or more groups, none holding 90% of it, is one more view
// after the groups': a part whose nearer arm hides part of its own farther
// surface (a pipe tee's branch in front of its run) leaves pieces the jump
// separates. Organized frames only (none otherwise).
std::vector<ViewIndices> ResidualRegionViews(const Segments& segments, const Acceptance& acceptance,
                                             int min_segment_points, bool across_jumps = false);

// The views of a match in which no class found a hypothesis scoring
// min_score (matched.best, -1 for none), moved out of `views` (in order,
// region views again after the segment views), to be matched once more
// with the estimator's own normals (ViewSet::own_normals;
// PerceptionOptions::residual_own_normals), with the bases the match made
// of them (ViewSet::bases: the finite points and support structure are the
// same whatever the normals).
ViewSet NothingFound(ViewSet& views, const MatchOutcome& matched, double min_score);

}  // namespace bp::internal
