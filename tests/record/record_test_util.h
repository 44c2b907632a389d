// Shared by the record / replay tests: a small version of the default cell
// (320 x 240 camera, a few parts) written as a file, so that the session's
// cell.yaml is exactly what was planned with.
#pragma once

#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>

#include <gtest/gtest.h>

#include "core/cell.h"
#include "tests/testing/files.h"

namespace bp::testing {

inline void ReplaceOnce(std::string& text, const std::string& from, const std::string& to) {
  const size_t at = text.find(from);
  ASSERT_NE(at, std::string::npos) << from;
  text.replace(at, from.size(), to);
}

// The default cell at a quarter of the pixels, `parts` parts of class 0
// (suction-graspable bushings), seed `seed`; relative paths made absolute.
inline std::string WriteSmallCell(const std::string& dir, int parts, uint64_t seed, const std::string& extra = "") {
  std::ifstream in(std::string(BINPICK_SOURCE_DIR) + "/assets/cells/default.yaml");
  std::string text((std::istreambuf_iterator<char>(in)), {});
  ReplaceOnce(text, "resolution: [640, 480]\n      intrinsics: {fx: 800.0, fy: 800.0, cx: 319.5, cy: 239.5}",
              "resolution: [320, 240]\n      intrinsics: {fx: 400.0, fy: 400.0, cx: 159.5, cy: 119.5}");
  ReplaceOnce(text, "num_parts: 20\n  seed: 1", "num_parts: " + std::to_string(parts) +
                                                  "\n  seed: " + std::to_string(seed) + "\n  part_classes: [0]");
  const std::string assets = std::string(BINPICK_SOURCE_DIR) + "/assets/";
  for (size_t at = text.find("../"); at != std::string::npos; at = text.find("../", at)) text.replace(at, 3, assets);
  text += extra;
  const std::string path = dir + "/small_cell.yaml";
  WriteText(path, text);
  return path;
}

}  // namespace bp::testing
