#include "pipeline/internal/depth_smoothing.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

namespace bp::internal {

namespace {

// Rows (or columns) per task.
constexpr int kGrainLines = 16;

// One pass along lines: line l has `count` samples at in[l * line_stride +
// k * step]. out gets each finite sample's gated mean over +-radius samples.
void GatedLineMeans(const std::vector<float>& in, int lines, int count, int line_stride, int step, int radius,
                    const std::vector<float>& gate_of, std::vector<float>& out) {
  tbb::parallel_for(tbb::blocked_range<int>(0, lines, kGrainLines), [&](const tbb::blocked_range<int>& r) {
    for (int l = r.begin(); l != r.end(); ++l) {
      const size_t base = static_cast<size_t>(l) * line_stride;
      for (int k = 0; k < count; ++k) {
        const size_t at = base + static_cast<size_t>(k) * step;
        const float z = in[at];
        if (!std::isfinite(z)) {
          out[at] = z;
          continue;
        }
        const float gate = gate_of[at];
        float sum = 0.f;
        int n = 0;
        const int lo = std::max(0, k - radius), hi = std::min(count - 1, k + radius);
        for (int j = lo; j <= hi; ++j) {
          const float q = in[base + static_cast<size_t>(j) * step];
          if (std::abs(q - z) <= gate) {  // false for NaN
            sum += q;
            ++n;
          }
        }
        out[at] = sum / static_cast<float>(n);  // n >= 1: the sample itself
      }
    }
  });
}

}  // namespace

int SmoothingRadius(const DepthNoise& noise, double target_sigma, int max_radius) {
  const double sigma = noise.Sigma(noise.measured_at());
  if (!(target_sigma > 0.0) || !(sigma > target_sigma) || !(noise.measured_at() > 0.0) || max_radius < 1) return 0;
  return std::clamp(static_cast<int>(std::ceil((sigma / target_sigma - 1.0) / 2.0)), 1, max_radius);
}

DepthImage SmoothDepth(const DepthImage& depth, int radius, const DepthNoise& noise, double gate_sigmas) {
  if (radius <= 0 || depth.empty()) return depth;
  const int w = depth.width, h = depth.height;
  // The gate per pixel, from the noise at its own depth.
  std::vector<float> gate(depth.data.size());
  const double k = gate_sigmas * std::sqrt(2.0);
  tbb::parallel_for(tbb::blocked_range<int>(0, h, kGrainLines), [&](const tbb::blocked_range<int>& r) {
    for (int v = r.begin(); v != r.end(); ++v) {
      for (int u = 0; u < w; ++u) {
        const size_t at = static_cast<size_t>(v) * w + u;
        const float z = depth.data[at];
        gate[at] = std::isfinite(z) ? static_cast<float>(k * noise.Sigma(z)) : 0.f;
      }
    }
  });
  std::vector<float> rows(depth.data.size());
  GatedLineMeans(depth.data, h, w, w, 1, radius, gate, rows);
  DepthImage out(w, h);
  GatedLineMeans(rows, w, h, 1, w, radius, gate, out.data);
  return out;
}

}  // namespace bp::internal
