// Bin detection (issue 41): where the bin really is, measured from the
// depth of one frame, before anything crops to its ROI.
//
// The rim (the four walls' top faces, a flat frame of wall_thickness width
// at the bin's inner height) is found in a band about its nominal height:
// seen from above, the yaw and centre over a grid of the search window
// whose rim outline explains the most band points (per-axis histograms;
// a full pile's points in the band scatter, a wall's pile up), then the
// rim's plane fitted by RANSAC (PCL) to the band points near that outline,
// and the bin model's rim (the walls' centre lines) fitted to the points on
// that plane by point-to-line ICP (Gauss-Newton on x, y, yaw) from the
// consensus pose. Plane and pose are then fitted again on the rim points within
// 3 robust sigmas of the plane: points on the walls' inner faces just below
// the rim, seen along its inner edge, would tilt and shift the fit. The floor follows from the bin model: it lies inner height
// below the rim, parallel to it (the floor itself is mostly hidden under
// the parts; where it shows, it is measured and reported as a check).
//
// A bin is found when every wall's rim is seen along most of its length, the
// points fit the rim within its width, no surface continues inward at the
// rim's height (a table or a lid is not a rim), and the pose lies inside the
// search window. Otherwise the detection says why and keeps the nominal pose.
//
// Frames: B robot base, W bin (origin at the centre of the inner floor, z up),
// C camera. SI units. Thread-safety: a free function over const inputs.
#pragma once

#include <string>

#include "core/cell.h"
#include "core/pose.h"
#include "pipeline/frame.h"

namespace bp {

struct BinDetection {
  bool found = false;
  // The measured bin pose when found, else the nominal one (bin.pose).
  Pose X_BW = Pose::Identity();
  // Of the measured pose from nominal (found only): translation (m) and the
  // angle of the relative rotation (deg).
  double offset = 0.0;
  double offset_deg = 0.0;
  // The offset exceeds bin.detect_warn (found only).
  bool warn = false;
  int rim_points = 0;       // points on the fitted rim (within its width)
  double rim_rms = 0.0;     // RMS distance of the rim points of the final fit to the rim's plane, m
  double rim_seen = 0.0;    // least share of a wall's length with rim points, [0, 1]
  // Where the floor shows: points within 10 mm of the model floor of the
  // measured bin and their mean height above it (m); 0 points: not checked.
  int floor_points = 0;
  double floor_height = 0.0;
  double ms = 0.0;          // wall time of the stage
  std::string reason;       // why not found; empty when found
};

// Tuning of DetectBin beyond the cell's BinDetectSpec. Distances in metres.
struct BinDetectOptions {
  // Half height of the band about the nominal rim height where rim points
  // are looked for: the search window's tilt (3 deg over the bin's half
  // diagonal) and height offsets fit in it, a pile filling 80% of the bin
  // stays below it.
  double band = 0.03;
  // Pixels are sampled so that neighbouring samples lie about this far
  // apart on the rim (>= 1 pixel).
  double sample_spacing = 0.0015;
  // RANSAC inlier distance to the rim plane and its iterations.
  double plane_distance = 0.003;
  int plane_iterations = 100;
  int plane_max_points = 1500;  // RANSAC runs on at most this many band points
  // The rim's least-squares planes and its point-to-line ICP run on at most
  // this many points, an even subsample in scan order (a 640x480 frame has
  // about 20k rim points; every one of them still counts for the walls'
  // seen shares). The fits' noise grows as 1 / sqrt(points): at 4000, a few
  // micrometres.
  int fit_max_points = 4000;
  // Beyond its half width, a rim point may lie this far from a wall's centre
  // line (depth noise and pixel footprint at the edges).
  double rim_slack = 0.002;
  // A wall counts as seen along a share of its length with rim points, in
  // 20 equal pieces; found needs min_wall_seen on every wall.
  double min_wall_seen = 0.5;
  // Found needs fewer than this share of the rim's points on the rim plane
  // just inside the rim (6-20 mm inward): a surface continuing inward.
  double max_inward_share = 0.3;
};

// Locates the bin of `bin` (its nominal pose, sizes and detect settings) in
// an organized frame; unorganized frames and frames without a valid camera
// pose give found = false with a reason. Never throws on frame content.
BinDetection DetectBin(const Frame& frame, const BinSpec& bin, const BinDetectOptions& options = {});

// "off", "on", "required" (the cell's spelling).
const char* ToString(BinDetectSpec::Mode mode);

}  // namespace bp
