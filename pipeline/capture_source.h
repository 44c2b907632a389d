// Capture sources: synthetic (OSMesa-rendered pile), files (PCD, PLY, depth
// PNG), replay of recordings (pipeline/recording.h). Not thread-safe: one owner calls Capture at a time.
#pragma once

#include <functional>
#include <memory>
#include <optional>
#include <string>

#include "core/cell.h"
#include "core/status.h"
#include "pipeline/frame.h"

namespace bp {

struct CaptureRequest {
  // What the camera is asked to look at besides the bin. A real camera sees
  // what is there; a simulated cell (the synthetic source) renders it:
  //   kBin      the bin and its pile (pick tasks);
  //   kInHand   also the robot's gripper and the part it holds, at the
  //             robot's pose X_BF, read as its tool centre point (seed 003's
  //             robot sends get_actual_tcp_pose(): docs/protocols.md "Task kinds");
  //   kFixture  also the fixture `fixture` and the table it stands on.
  enum class View { kBin, kInHand, kFixture };
  int config_id = 0;              // camera config; 0 = the cell's current default
  std::optional<Pose> X_BF;       // pose sent by the robot (eye-in-hand: its flange)
  View view = View::kBin;
  std::string gripper;            // kInHand: cell gripper name
  std::string fixture;            // kFixture: cell fixture name
};

class CaptureSource {
 public:
  virtual ~CaptureSource() = default;
  // @returns the next frame, or Unavailable / Corruption / NotFound with the reason.
  virtual Result<Frame> Capture(const CaptureRequest& request) = 0;
  // A grasp on this instance was handed to a robot, whose tool centre point
  // goes to X_BT. Sources that simulate picks remove the part from the pile
  // before the next capture (the synthetic source keeps it in the gripper,
  // where the grasp met it); others ignore it.
  virtual void NotifyPicked(int /*instance_id*/, const std::optional<Pose>& /*X_BT*/ = std::nullopt) {}
  // The robot let go of the part it holds (a place was handed out).
  virtual void NotifyReleased() {}
  // Human-readable description for logs and `binpick info`.
  virtual std::string Describe() const = 0;
};

// The hand-eye transform binpick believes in right now: X_BC for an
// eye-to-hand camera, X_FC for an eye-in-hand one. binpickd passes one
// reading its HandEyeState (calib/hand_eye_state.h), so a finished hand-eye
// calibration is used from the next capture on. Called once per capture on
// the capturing thread: it must be quick and thread-safe.
using HandEyeProvider = std::function<Pose()>;

// Builds the source the cell names (source.kind). With `hand_eye` (a live
// camera whose calibration can change while running), a synthetic source
// renders the pile from where the camera really is (calibration.true_pose
// when the cell has a calibration section) and stamps each frame with the
// pose binpick believes: X_BC = hand_eye() (eye-to-hand) or X_BF *
// hand_eye() (eye-in-hand). Without it the camera is perfectly calibrated
// (rendered from and stamped with the nominal camera pose), which is what
// perception evaluation wants. Files and replays keep the X_BC they recorded.
Result<std::unique_ptr<CaptureSource>> MakeCaptureSource(const Cell& cell, HandEyeProvider hand_eye = {});

}  // namespace bp
