// Capture sources: synthetic (OSMesa-rendered pile), files (PCD, PLY, depth
// PNG), replay of recordings (pipeline/recording.h). Not thread-safe: one owner calls Capture at a time.
#pragma once

#include <memory>
#include <optional>
#include <string>

#include "core/cell.h"
#include "core/status.h"
#include "pipeline/frame.h"

namespace bp {

struct CaptureRequest {
  int config_id = 0;              // camera config; 0 = the cell's current default
  std::optional<Pose> X_BF;       // flange pose sent by the robot (eye-in-hand)
};

class CaptureSource {
 public:
  virtual ~CaptureSource() = default;
  // @returns the next frame, or Unavailable / Corruption / NotFound with the reason.
  virtual Result<Frame> Capture(const CaptureRequest& request) = 0;
  // A grasp on this instance was handed to a robot. Sources that simulate
  // picks remove the part from the pile before the next capture; others ignore it.
  virtual void NotifyPicked(int /*instance_id*/) {}
  // Human-readable description for logs and `binpick info`.
  virtual std::string Describe() const = 0;
};

// Builds the source the cell names (source.kind).
Result<std::unique_ptr<CaptureSource>> MakeCaptureSource(const Cell& cell);

}  // namespace bp
