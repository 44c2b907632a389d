// Pick -> correct in hand -> place in simulation (`binpick place`), as seed
// 003's robot program runs it (docs/protocols.md "Task kinds"): pick the
// first grasp of the pick task's plan; show the part to the camera at
// adjust_det_pose and take the in_hand answer (obj_in_tool); look at the
// place area and take the place_area answer (place_in_base); move the tool
// to place_in_base * obj_in_Place * obj_in_tool^-1.
//
// The simulated world (pipeline/synthetic_source.h): the part sits in the
// gripper where the grasp really met it, then slips (source.in_hand_slip);
// the fixture stands off its taught pose (source.fixture_offset). Each cycle
// is scored against that truth: the PLACE ERROR is where the part ends up
// (the tool pose with the part as it really sits in the tool) against where
// the fixture wants it (true X_BP * X_PO), modulo the part's symmetry. The
// same place computed without the in-hand answer (the pick's own belief,
// the grasp against its detected part) is scored beside it.
#pragma once

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "core/cell.h"
#include "core/pose.h"
#include "core/status.h"
#include "pipeline/perception.h"

namespace bp {

struct PlaceCyclesOptions {
  int cycles = 100;
  uint64_t seed = 1;  // the first pile's; each new pile takes the next seed
  // The default cell's pick_to_place: its grasps are those the part can be
  // placed on the nest with (TaskSpec::place_on).
  int pick_task_id = 7;
  int in_hand_task_id = 1;
  int place_area_task_id = 3;
  // seed 003 adjust_det_pose: the tool pose at which the part is shown to
  // the camera (default: 0.5 m under the default cell's camera, the tool
  // tilted 35 deg off the line of sight: pointing straight at the camera,
  // the part hides whatever it has toward the flange, e.g. a tee's branch
  // held under its run, and the view cannot tell its turn; docs/tuning.md).
  Pose X_BT_adjust =
      MakePose(Mat3(Eigen::AngleAxisd(0.4, Vec3::UnitZ()) * Eigen::AngleAxisd(35.0 * M_PI / 180, Vec3::UnitX())),
               Vec3(0.7, 0.0, 0.55));
};

struct PlaceCycle {
  uint64_t scene_seed = 0;
  int class_id = -1;
  // placed | in_hand_missed | place_area_missed | outside_workspace
  std::string outcome;
  double slip_mm = 0, slip_deg = 0;          // the simulated slip alone
  double grasp_error_mm = 0, grasp_error_deg = 0;  // true X_TO against the pick's belief
  double in_hand_error_mm = 0, in_hand_error_deg = 0;  // the in_hand answer against the true X_TO
  double place_error_mm = 0, place_error_deg = 0;      // with the in-hand correction
  double uncorrected_mm = 0, uncorrected_deg = 0;      // without it
};

struct PlaceCyclesReport {
  std::vector<PlaceCycle> cycles;
  int placed = 0;
  int in_hand_missed = 0;     // in_hand answered NO_OBJECT_FOUND
  int place_area_missed = 0;  // place_area answered NO_OBJECT_FOUND
  int refused = 0;            // answers the workspace check refused (never sent)
  int poses_sent = 0;         // robot targets of answers sent: pick, pre-pick, place
  int sent_outside = 0;       // of which outside robot.workspace (must be 0)
  int piles = 0;
  // Over the placed cycles.
  struct Spread {
    double median = 0, p99 = 0, max = 0;
  };
  Spread place_mm, place_deg, uncorrected_mm, uncorrected_deg, in_hand_mm, in_hand_deg;
  std::string Describe() const;  // a few lines of figures
};

// Runs the cycles on synthetic piles of `cell` (source.num_parts parts,
// simulate_picks on, the cell's slip and fixture offset). A pile whose pick
// task has no grasp left is replaced by the next seed's. InvalidArgument for
// tasks of the wrong kind or a cell without fixtures; Unavailable without a
// renderer.
Result<PlaceCyclesReport> RunPlaceCycles(const Cell& cell, std::shared_ptr<const Perception> perception,
                                         const PlaceCyclesOptions& options);

}  // namespace bp
