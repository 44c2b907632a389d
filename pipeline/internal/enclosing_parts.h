// Perception's pass for small parts fitted into larger ones (a flanged
// bushing whose hub lies in a pipe tee's arm; docs/perception_pipeline.md,
// "enclosing"): once the other passes are done, the larger class is fitted
// on the small detection's points and the unexplained points around it, and
// replaces the small one when it explains its points and more. Private to
// bp_pipeline. Frames: B base, O part. SI units.
#pragma once

#include <cstddef>
#include <cstdint>
#include <span>
#include <vector>

#include "pipeline/internal/acceptance.h"
#include "pipeline/internal/class_model.h"
#include "pipeline/internal/segmentation.h"
#include "pipeline/internal/view_matching.h"

namespace bp::internal {

// One view to match: the samples a larger class may explain in place of a
// live detection.
struct EnclosingView {
  size_t detection = 0;  // Acceptance::detection index
  int model = 0;         // index into the models: the larger class
  ViewIndices view;      // into Segments::points
  std::vector<uint8_t> on_detection;  // per view sample: 1 on the detection's surface (2.5 mm) or in its support
};

// For each live detection and each class whose diameter is at least
// kEnclosingRatio times its own: the samples within half the larger
// diameter plus a quarter of its own of its surface centre that no other
// detection explains (those unexplained, and those on its surface or in
// its support), when at least min_unexplained of them are unexplained.
std::vector<EnclosingView> EnclosingViews(const Segments& segments, const Acceptance& acceptance,
                                          std::span<const ClassModel* const> models, int min_unexplained);

// Matches each view by its larger class (ViewMatcher::MatchClass); the
// candidate that covers most of the view's samples replaces the detection
// (Acceptance::Supersede) when it covers at least kCoveredShare of those on
// the detection's surface and kMoreExplained times as many samples as the
// detection does. @returns how many detections were replaced.
int ReplaceEnclosed(const std::vector<EnclosingView>& views, const Segments& segments,
                    std::span<const ClassModel* const> models, ViewMatcher& matcher, Acceptance& acceptance);

}  // namespace bp::internal
