// Capture sources for the bin detection tests (issue 41): a frame without a
// bin, and a source that shows the bin or not as the test says.
#pragma once

#include <atomic>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <utility>

#include "core/cell.h"
#include "pipeline/capture_source.h"

namespace bp::testing {

// The cell's default camera seeing only a horizontal plane at height z_W
// (m) of the nominal bin frame: depth along z_C, NaN where the ray misses
// the plane. No bin, so bin detection finds no rim.
inline Frame PlaneFrame(const Cell& cell, double z_W) {
  const CameraConfig& config = *cell.camera.FindConfig(cell.camera.default_config);
  Frame f;
  f.intrinsics = config.intrinsics;
  f.X_BC = cell.camera.X_BC;
  f.depth = DepthImage(f.intrinsics.width, f.intrinsics.height, std::numeric_limits<float>::quiet_NaN());
  const Pose X_WC = cell.bin.X_BW.inverse() * f.X_BC;
  for (int v = 0; v < f.depth.height; ++v) {
    for (int u = 0; u < f.depth.width; ++u) {
      const Vec3 ray_W =
          X_WC.linear() * Vec3((u - f.intrinsics.cx) / f.intrinsics.fx, (v - f.intrinsics.cy) / f.intrinsics.fy, 1);
      const double t = (z_W - X_WC.translation().z()) / ray_W.z();
      if (t > 0) f.depth.at(u, v) = static_cast<float>(t);  // depth along z_C: ray_C.z = 1
    }
  }
  return f;
}

// A bare floor at the bin's floor height: no bin.
inline Frame FloorWithoutABin(const Cell& cell) { return PlaneFrame(cell, 0.0); }

// A source whose frames show the default camera's view of a bare floor at
// the bin's floor height: no bin.
class NoBinSource final : public CaptureSource {
 public:
  explicit NoBinSource(const Cell& cell) : cell_(cell) {}
  Result<Frame> Capture(const CaptureRequest&) override { return FloorWithoutABin(cell_); }
  std::string Describe() const override { return "a floor without a bin"; }

 private:
  Cell cell_;
};

// `inner`'s frames while the bin is in view (set_bin_in_view), else the bare
// floor's (inner is not asked then, so its pile does not move). Picks and
// releases go to `inner`. Thread-safety: set_bin_in_view from any thread;
// the rest as `inner`.
class BinInViewSource final : public CaptureSource {
 public:
  BinInViewSource(const Cell& cell, std::unique_ptr<CaptureSource> inner)
      : cell_(cell), inner_(std::move(inner)) {}
  void set_bin_in_view(bool in_view) { in_view_.store(in_view); }
  Result<Frame> Capture(const CaptureRequest& request) override {
    if (in_view_.load()) return inner_->Capture(request);
    return FloorWithoutABin(cell_);
  }
  void NotifyPicked(int instance_id, const std::optional<Pose>& X_BT = std::nullopt) override {
    inner_->NotifyPicked(instance_id, X_BT);
  }
  void NotifyReleased() override { inner_->NotifyReleased(); }
  std::string Describe() const override { return inner_->Describe() + ", or a floor without a bin"; }

 private:
  Cell cell_;
  std::unique_ptr<CaptureSource> inner_;
  std::atomic<bool> in_view_{true};
};

}  // namespace bp::testing
