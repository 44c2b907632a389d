// Unorganized clouds made organized for perception (docs/file_formats.md,
// "Unorganized clouds"): the points are seen through a virtual pinhole camera
// V and each pixel keeps the nearest point along its ray as its depth.
// Perception's organized path (normals and region growing on the pixel grid,
// verification against the depth image) then runs on the result unchanged.
//
// V is the cloud's own camera (X_BV = X_BC) when X_BC is known and looks
// down into the bin; otherwise a camera above the bin looking down -z of the
// bin frame W ("a view from +z of the bin"), which callers report as an
// assumption. The pixel grid, in order of preference:
//   1. a camera config of the cell whose pixel grid holds every point
//      (a cloud deprojected from that camera's depth image);
//   2. a pinhole lattice recovered from the points (x/z and y/z of every
//      point on one regular grid: a cloud deprojected from any pinhole);
//   3. otherwise square pixels as wide as nearly every point's spacing to
//      its nearest neighbour (holes in a surface would split the organized
//      path's regions), coarser while a pixel grid that fine leaves holes.
// On 1 and 2 every point is on its pixel's ray, so the frame reproduces the
// cloud (to float rounding); on 3 a point moves to its pixel's ray, by at
// most half a pixel sideways, its depth kept.
#pragma once

#include <cstdint>
#include <string>

#include "core/cell.h"
#include "core/status.h"
#include "pipeline/frame.h"

namespace bp {

enum class CloudGrid {
  kCameraConfig,  // the grid of one of the cell's camera configs
  kRecovered,     // a pinhole lattice recovered from the points
  kFromSpacing,   // no lattice: pitch from the point spacing
};

enum class CloudViewSource {
  kCamera,          // V = the cloud's camera (X_BC known)
  kAboveBinNoPose,  // X_BC unknown: seen from +z of the bin frame
  kAboveBinTilted,  // X_BC known but not looking down into the bin: from +z of the bin frame
};

struct CloudProjection {
  Frame frame;  // organized: depth (z in V, metres) + intrinsics, X_BC = X_BV; truth, source, timestamp kept
  CloudGrid grid = CloudGrid::kFromSpacing;
  CloudViewSource view = CloudViewSource::kCamera;
  int config_id = 0;       // kCameraConfig: the config's id
  int64_t points = 0;      // finite points in front of V, within 84.3 deg of its axis
  int64_t pixels = 0;      // pixels holding a point; points - pixels were behind a nearer point
  double max_shift_px = 0; // largest sideways distance of a point from its pixel's ray, pixels
  // One line: the view, the grid, the points kept.
  std::string Describe() const;
};

struct CloudProjectionOptions {
  // Largest virtual image, pixels (a 4096 x 3072 sensor; 48 MB of depth).
  // kFromSpacing coarsens its pitch to fit.
  int64_t max_pixels = 12'582'912;
  // A point is on a lattice when its projection is this close to a pixel
  // centre, pixels. Float32 clouds deprojected from a 1920-wide image are
  // within 2e-4 px; 0.01 px leaves room and still rejects any cloud not made
  // from that grid.
  double lattice_tolerance_px = 0.01;
  // No lattice: the pixel is pitch_margin times this quantile of the points'
  // spacing to their nearest neighbour (angle seen from V). A lattice
  // written in another frame spreads about its median spacing; a high
  // quantile leaves few holes in the grid (docs/tuning.md, "Unorganized
  // clouds").
  double spacing_quantile = 0.95;  // (0, 1]
  double pitch_margin = 1.0;       // > 0
};

// The unorganized `cloud` (points_C in C, at cloud.X_BC) seen through a
// virtual pinhole (header comment). `X_BC_known`: cloud.X_BC came from the
// file rather than a default.
// @returns InvalidArgument if the cloud is organized already or no point lies
// in front of the virtual camera within 84.3 deg of its axis (points
// farther off it are dropped).
Result<CloudProjection> ProjectCloud(const Frame& cloud, const Cell& cell, bool X_BC_known,
                                     const CloudProjectionOptions& options = {});

}  // namespace bp
