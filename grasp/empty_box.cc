#include "grasp/empty_box.h"

namespace bp {

int64_t EmptyBoxPoints(const EmptyBoxRule& rule, int64_t roi_points, int64_t largest_region_points) {
  return rule.mode == EmptyBoxRule::Mode::kLargestRegion ? largest_region_points : roi_points;
}

bool IsBoxEmpty(const EmptyBoxRule& rule, int64_t roi_points, int64_t largest_region_points, int detections,
                int64_t image_pixels) {
  return detections == 0 &&
         EmptyBoxPoints(rule, roi_points, largest_region_points) < EffectiveThreshold(rule, image_pixels);
}

}  // namespace bp
