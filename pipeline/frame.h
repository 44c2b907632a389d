// A captured frame: what every capture source produces and every pipeline
// stage consumes. Points are in the camera frame C unless a name says
// otherwise.
#pragma once

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/cell.h"
#include "core/image.h"
#include "core/pose.h"

namespace bp {

// Ground truth for one part instance of a synthetic frame.
struct PartTruth {
  int instance_id = 0;        // stable across captures of one pile; label = instance_id
  int class_id = 0;
  std::string class_name;
  Pose X_BO = Pose::Identity();  // part in robot base
  int visible_pixels = 0;        // pixels of this part in the full scene's ID render
  int unoccluded_pixels = 0;     // pixels when rendered alone from the same camera
  double visible_fraction = 0.0; // visible_pixels / unoccluded_pixels (0 if never visible)
};

struct GroundTruth {
  uint64_t seed = 0;
  std::vector<PartTruth> parts;
  // Per-pixel instance id (0 = nothing, kBinLabel = bin, else instance_id),
  // before noise and dropout.
  LabelImage labels;
  static constexpr uint16_t kBinLabel = 0xFFFF;
  // Where the bin truly stands (synthetic: bin.pose moved by
  // source.bin_offset); nullopt when not recorded (older truth files).
  std::optional<Pose> X_BW;
};

struct BinDetection;  // pipeline/bin_detection.h

struct Frame {
  // Organized frames: depth (metres, NaN = invalid) with its intrinsics.
  DepthImage depth;
  Intrinsics intrinsics;          // valid() iff the frame is organized
  IntensityImage intensity;       // optional, same size as depth
  // Unorganized frames (PCD/PLY clouds without a grid): points in C.
  std::vector<Eigen::Vector3f> points_C;
  Pose X_BC = Pose::Identity();   // camera in robot base at capture time
  int64_t timestamp_ns = 0;       // system clock, ns since epoch
  std::string source;             // e.g. "synthetic seed=3 capture=2", or a file path
  std::optional<GroundTruth> truth;
  // The bin as measured when the frame was captured (a `bin.detect:
  // required` capture checks it there); perception reports this one instead
  // of running the stage again. Null: not measured yet.
  std::shared_ptr<const BinDetection> bin;

  bool organized() const { return intrinsics.valid() && !depth.empty(); }
  // Valid 3D points in C: deprojected depth for organized frames, else points_C.
  std::vector<Eigen::Vector3f> PointsInCamera() const;
  size_t ValidPointCount() const;
};

// Deprojects pixel (u, v) with depth z (metres) through a pinhole (no distortion).
inline Eigen::Vector3f Deproject(const Intrinsics& K, float u, float v, float z) {
  return {static_cast<float>((u - K.cx) / K.fx) * z, static_cast<float>((v - K.cy) / K.fy) * z, z};
}

}  // namespace bp
