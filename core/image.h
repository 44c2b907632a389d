// A plain row-major image, so that public headers need neither OpenCV nor PCL.
#pragma once

#include <cstddef>
#include <cstdint>
#include <vector>

namespace bp {

template <typename T>
struct Image {
  int width = 0;
  int height = 0;
  std::vector<T> data;  // row-major, size width * height

  Image() = default;
  Image(int w, int h, T fill = T{}) : width(w), height(h), data(static_cast<size_t>(w) * h, fill) {}
  bool empty() const { return data.empty(); }
  T& at(int u, int v) { return data[static_cast<size_t>(v) * width + u]; }
  const T& at(int u, int v) const { return data[static_cast<size_t>(v) * width + u]; }
};

using DepthImage = Image<float>;        // metres; NaN where there is no measurement
using IntensityImage = Image<uint8_t>;  // 8-bit grey
using LabelImage = Image<uint16_t>;     // 0 background, see GroundTruth for ids

}  // namespace bp
