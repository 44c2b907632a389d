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

// Parts: a magenta circle at each part origin, labelled with its class id. Grasps:
// the queue order number at each tool centre point with the approach line
// from the pre-grasp; the first `served` grasps (already handed out) in grey,
// the next one in green, the rest in yellow.
// @returns nullopt when the frame is not organized or lacks the image.
std::optional<std::vector<uint8_t>> RenderOverlayPng(const Frame& frame, OverlayImage image,
                                                     const std::vector<DetectedPart>& parts,
                                                     const std::vector<Grasp>& grasps, int served);

}  // namespace bp::internal
