// Scene variety for the synthetic source (source.variety; docs/synthetic.md,
// "Variety"): per scene, a camera tilted about the point it looks at on the
// bin floor and rolled about its optical axis, other intrinsics and
// resolution, other noise, another drop style, all drawn from the scene's
// seed (deterministic per seed, independent of the pile's own draws).
#pragma once

#include <cstdint>
#include <string>

#include "core/cell.h"
#include "core/pose.h"
#include "core/status.h"

namespace bp {

struct SceneVariety {
  double tilt_deg = 0.0;          // optical axis turned from the nominal one
  double tilt_azimuth_deg = 0.0;  // about the base frame's z, the direction of the turn
  double roll_deg = 0.0;          // about the optical axis
  double focal_scale = 1.0;
  double resolution_scale = 1.0;
  double principal_dx = 0.0, principal_dy = 0.0;  // fractions of the width, height
  double axial_noise_scale = 1.0;
  double grazing_start_deg = 72.0;
  double mixed_pixels = 0.0;
  double speckle = 0.0;
  DropStyle drop_style = DropStyle::kDefault;
  std::string Describe() const;  // one line, for frame sources and logs
};

SceneVariety DrawSceneVariety(const VarietySpec& spec, uint64_t seed);

// `base` as this scene's camera has it: resolution and focal lengths scaled,
// principal point moved, noise changed. Distortion is kept.
CameraConfig VariedConfig(const CameraConfig& base, const SceneVariety& variety);

// The camera pose of the scene: X_BC turned by the tilt about the point where
// its optical axis meets the bin floor (the bin frame's z = 0 plane), rolled
// about its optical axis, then backed off along that axis in 1 cm steps
// until the bin's inner box (floor to rim) projects inside every config of
// `configs` (already varied) with a 2% margin. @returns InvalidArgument when
// the optical axis does not meet the floor in front of the camera, or when
// the box is not in view 1 m further back.
Result<Pose> VariedCameraPose(const Pose& X_BC, const BinSpec& bin, const std::vector<CameraConfig>& configs,
                              const SceneVariety& variety);

}  // namespace bp
