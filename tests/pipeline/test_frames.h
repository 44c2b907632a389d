// Small synthetic frames for file IO tests: a floor plane with a box on it,
// built in code (no renderer).
#pragma once

#include <unistd.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <string>

#include <gtest/gtest.h>

#include "pipeline/frame.h"
#include "tests/testing/files.h"

namespace bp::testing {

inline Intrinsics SmallIntrinsics() {
  Intrinsics K;
  K.width = 64;
  K.height = 48;
  K.fx = 80.3;
  K.fy = 79.7;
  K.cx = 31.5;
  K.cy = 23.25;
  K.distortion = {0.01, -0.002, 0.0001, 0.0, 0.0003};
  return K;
}

inline Pose SomeCameraPose() {
  return MakePose(Quat(0.1, 0.98, -0.05, 0.02), Vec3(0.7, -0.01, 1.05));
}

// Floor at 1.0 m with a 0.1 m box in the middle, a few invalid pixels, seeded noise.
inline Frame PlaneWithBox(uint32_t seed = 42) {
  std::mt19937 rng{seed};
  std::normal_distribution<float> noise(0.f, 0.0003f);
  Frame f;
  f.intrinsics = SmallIntrinsics();
  f.depth = DepthImage(f.intrinsics.width, f.intrinsics.height);
  f.intensity = IntensityImage(f.intrinsics.width, f.intrinsics.height);
  for (int v = 0; v < f.depth.height; ++v) {
    for (int u = 0; u < f.depth.width; ++u) {
      const bool box = u >= 24 && u < 40 && v >= 16 && v < 32;
      float z = (box ? 0.9f : 1.0f) + noise(rng);
      if ((u * 7 + v * 13) % 41 == 0) z = std::numeric_limits<float>::quiet_NaN();
      f.depth.at(u, v) = z;
      f.intensity.at(u, v) = static_cast<uint8_t>((u * 4 + v * 3) % 256);
    }
  }
  f.X_BC = SomeCameraPose();
  f.timestamp_ns = 1'700'000'000'123'456'789;
  f.source = "test plane_with_box";
  GroundTruth truth;
  truth.seed = 18'446'744'073'709'551'557ull;  // needs all 64 bits
  PartTruth a;
  a.instance_id = 1;
  a.class_id = 2;
  a.class_name = "pipe_tee";
  a.X_BO = MakePose(Quat(0.3, -0.2, 0.9, 0.1), Vec3(0.71, 0.012345678901234, 0.0456));
  a.visible_pixels = 256;
  a.unoccluded_pixels = 300;
  a.visible_fraction = 256.0 / 300.0;
  PartTruth b;
  b.instance_id = 7;
  b.class_id = 0;
  b.class_name = "flanged_bushing";
  b.X_BO = MakePose(Quat(1, 0, 0, 0), Vec3(0.6, -0.1, 0.02));
  truth.parts = {a, b};
  f.truth = truth;
  return f;
}

// Keeps the first `fraction` of a file's bytes.
inline void Truncate(const std::string& path, double fraction) {
  const std::string bytes = ReadBytes(path);
  WriteText(path, bytes.substr(0, static_cast<size_t>(bytes.size() * fraction)));
}

}  // namespace bp::testing
