#include "web/internal/overlay.h"

#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>

namespace bp::internal {
namespace {

// Pixel of point p_B, or nullopt behind the camera.
std::optional<cv::Point> Project(const Frame& frame, const Pose& X_CB, const Vec3& p_B) {
  const Vec3 p_C = X_CB * p_B;
  if (p_C.z() <= 1e-6) return std::nullopt;
  const Intrinsics& K = frame.intrinsics;
  const double u = K.fx * p_C.x() / p_C.z() + K.cx;
  const double v = K.fy * p_C.y() / p_C.z() + K.cy;
  if (!std::isfinite(u) || !std::isfinite(v) || std::fabs(u) > 1e5 || std::fabs(v) > 1e5) {
    return std::nullopt;
  }
  return cv::Point(static_cast<int>(std::lround(u)), static_cast<int>(std::lround(v)));
}

cv::Mat DepthColour(const DepthImage& depth) {
  float lo = std::numeric_limits<float>::max(), hi = std::numeric_limits<float>::lowest();
  for (float z : depth.data) {
    if (std::isfinite(z) && z > 0) {
      lo = std::min(lo, z);
      hi = std::max(hi, z);
    }
  }
  cv::Mat grey(depth.height, depth.width, CV_8UC1, cv::Scalar(0));
  cv::Mat invalid(depth.height, depth.width, CV_8UC1, cv::Scalar(0));
  const float span = hi > lo ? hi - lo : 1.0f;
  for (int v = 0; v < depth.height; ++v) {
    auto* g = grey.ptr<uint8_t>(v);
    auto* bad = invalid.ptr<uint8_t>(v);
    for (int u = 0; u < depth.width; ++u) {
      const float z = depth.at(u, v);
      if (!(std::isfinite(z) && z > 0)) {
        bad[u] = 255;
        continue;
      }
      // Near is warm: 255 at the nearest point, 0 at the farthest.
      g[u] = static_cast<uint8_t>(std::lround(255.0f * (hi - z) / span));
    }
  }
  cv::Mat colour;
  cv::applyColorMap(grey, colour, cv::COLORMAP_JET);
  colour.setTo(cv::Scalar(0, 0, 0), invalid);
  return colour;
}

// The outer edge of the bin's rim at X_BW as a closed polyline (corners
// behind the camera dropped).
void DrawRim(cv::Mat& canvas, const Frame& frame, const Pose& X_CB, const BinOutline& bin, const Pose& X_BW,
             const cv::Scalar& colour, int thickness) {
  const double x = bin.inner_size.x() / 2 + bin.wall_thickness, y = bin.inner_size.y() / 2 + bin.wall_thickness;
  const double z = bin.inner_size.z();
  std::vector<cv::Point> corners;
  for (const Vec3& c : {Vec3(-x, -y, z), Vec3(x, -y, z), Vec3(x, y, z), Vec3(-x, y, z)}) {
    if (const auto p = Project(frame, X_CB, X_BW * c)) corners.push_back(*p);
  }
  if (corners.size() == 4) cv::polylines(canvas, corners, true, colour, thickness, cv::LINE_AA);
}

void DrawBin(cv::Mat& canvas, const Frame& frame, const Pose& X_CB, const BinOutline& bin, int scale) {
  const bool found = bin.measured && bin.measured->found;
  if (!found) {
    DrawRim(canvas, frame, X_CB, bin, bin.X_BW_nominal, cv::Scalar(160, 160, 160), scale);
    if (bin.measured) {
      cv::putText(canvas, "bin not found: nominal pose", cv::Point(4 * scale, 12 * scale), cv::FONT_HERSHEY_SIMPLEX,
                  0.4 * scale, cv::Scalar(0, 0, 255), 1, cv::LINE_AA);
    }
    return;
  }
  const BinDetection& m = *bin.measured;
  if (m.offset > 0.001 || m.offset_deg > 0.1) {
    DrawRim(canvas, frame, X_CB, bin, bin.X_BW_nominal, cv::Scalar(160, 160, 160), scale);
  }
  DrawRim(canvas, frame, X_CB, bin, m.X_BW, cv::Scalar(255, 255, 0), scale);
  char text[96];
  std::snprintf(text, sizeof(text), "bin %.1f mm / %.2f deg off%s", 1e3 * m.offset, m.offset_deg,
                m.warn ? " (warning)" : "");
  cv::putText(canvas, text, cv::Point(4 * scale, 12 * scale), cv::FONT_HERSHEY_SIMPLEX, 0.4 * scale,
              m.warn ? cv::Scalar(0, 165, 255) : cv::Scalar(255, 255, 0), 1, cv::LINE_AA);
}

}  // namespace

std::optional<std::vector<uint8_t>> RenderOverlayPng(const Frame& frame, OverlayImage image,
                                                     const std::vector<DetectedPart>& parts,
                                                     const std::vector<Grasp>& grasps,
                                                     const std::vector<GraspState>& states,
                                                     const BinOutline* bin) {
  if (!frame.organized()) return std::nullopt;
  cv::Mat canvas;
  if (image == OverlayImage::kDepth) {
    if (frame.depth.empty()) return std::nullopt;
    canvas = DepthColour(frame.depth);
  } else {
    const IntensityImage& in = frame.intensity;
    if (in.empty() || in.width <= 0 || in.height <= 0) return std::nullopt;
    const cv::Mat grey(in.height, in.width, CV_8UC1, const_cast<uint8_t*>(in.data.data()));
    cv::cvtColor(grey, canvas, cv::COLOR_GRAY2BGR);
  }
  const Pose X_CB = frame.X_BC.inverse();
  const int scale = std::max(1, canvas.cols / 320);
  if (bin != nullptr) DrawBin(canvas, frame, X_CB, *bin, scale);
  for (const DetectedPart& part : parts) {
    const auto p = Project(frame, X_CB, part.X_BO.translation());
    if (!p) continue;
    const cv::Scalar magenta(255, 0, 255);
    cv::circle(canvas, *p, 9 * scale, magenta, scale, cv::LINE_AA);
    cv::putText(canvas, "c" + std::to_string(part.class_id), *p + cv::Point(10 * scale, -6 * scale),
                cv::FONT_HERSHEY_SIMPLEX, 0.35 * scale, magenta, 1, cv::LINE_AA);
  }
  for (size_t i = 0; i < grasps.size(); ++i) {
    const Grasp& g = grasps[i];
    const auto p = Project(frame, X_CB, g.X_BT.translation());
    if (!p) continue;
    const GraspState state = i < states.size() ? states[i] : GraspState::kQueued;
    const cv::Scalar colour = state == GraspState::kServed    ? cv::Scalar(128, 128, 128)
                              : state == GraspState::kNext      ? cv::Scalar(0, 255, 0)
                              : state == GraspState::kWithdrawn ? cv::Scalar(0, 0, 200)
                                                                : cv::Scalar(0, 255, 255);
    if (const auto pre = Project(frame, X_CB, g.X_BT_pre.translation())) {
      cv::line(canvas, *pre, *p, colour, scale, cv::LINE_AA);
    }
    cv::drawMarker(canvas, *p, colour, cv::MARKER_CROSS, 10 * scale, scale, cv::LINE_AA);
    cv::putText(canvas, std::to_string(i + 1), *p + cv::Point(4 * scale, 12 * scale),
                cv::FONT_HERSHEY_SIMPLEX, 0.4 * scale, colour, 1, cv::LINE_AA);
  }
  std::vector<uint8_t> png;
  if (!cv::imencode(".png", canvas, png)) return std::nullopt;
  return png;
}

}  // namespace bp::internal
