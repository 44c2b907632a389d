// The empty-box rule (seed 000, RC_CHECK_EMPTY_BOX), in one place: the request
// handler and `binpick clear` both ask this function.
//
// EMPTY when no part was detected and the ROI holds fewer points than the
// rule's threshold scaled to the image (EffectiveThreshold, core/cell.h),
// counted in the largest connected region (kLargestRegion: stray noise points
// cannot make a bin look full) or in total (kTotal). NOT_EMPTY otherwise: any
// detection makes the bin not empty.
#pragma once

#include <cstdint>

#include "core/cell.h"
#include "grasp/planner.h"

namespace bp {

// `image_pixels` 0: the threshold as stated (no scaling).
bool IsBoxEmpty(const EmptyBoxRule& rule, int64_t roi_points, int64_t largest_region_points, int detections,
                int64_t image_pixels = 0);

inline bool IsBoxEmpty(const EmptyBoxRule& rule, const PlanResult& plan) {
  return IsBoxEmpty(rule, plan.roi_points, plan.largest_region_points, plan.detections, plan.image_pixels);
}

// The count the rule compares with the threshold.
int64_t EmptyBoxPoints(const EmptyBoxRule& rule, int64_t roi_points, int64_t largest_region_points);

}  // namespace bp
