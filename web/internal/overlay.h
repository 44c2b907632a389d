// Draws the detected parts and the grasp queue on a frame's depth or
// intensity image and PNG-encodes it. OpenCV stays in overlay.cc.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include "grasp/grasp.h"
#include "grasp/planner.h"
#include "pipeline/frame.h"

namespace bp::internal {

enum class OverlayImage { kDepth, kIntensity };

// Where a grasp of the drawn plan stands.
enum class GraspState { kServed, kNext, kQueued, kWithdrawn };

// Parts: a magenta circle at each part origin, labelled with its class id. Grasps:
// the queue order number at each tool centre point with the approach line
// from the pre-grasp, by `states` (one per grasp): handed out in grey, the
// next one in green, the rest in yellow, withdrawn as stale in red.
// @returns nullopt when the frame is not organized or lacks the image.
// The bin's outline (issue 41): the outer edge of its rim where the plan's
// bin detection measured it (cyan) and, when that differs, where the cell
// says it is (grey), with the offset written beside it.
struct BinOutline {
  Pose X_BW_nominal = Pose::Identity();
  std::optional<BinDetection> measured;  // nullopt: the stage did not run
  Vec3 inner_size = Vec3::Zero();        // bin.inner_size
  double wall_thickness = 0.0;
};

std::optional<std::vector<uint8_t>> RenderOverlayPng(const Frame& frame, OverlayImage image,
                                                     const std::vector<DetectedPart>& parts,
                                                     const std::vector<Grasp>& grasps,
                                                     const std::vector<GraspState>& states,
                                                     const BinOutline* bin = nullptr);

}  // namespace bp::internal
