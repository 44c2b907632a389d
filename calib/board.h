// The checkerboard target: rendering it as a pinhole camera sees it (the
// simulator) and finding it in an image (the solver's only input besides
// the robot poses). Frames: C camera (OpenCV), T board (origin at the first
// inner corner, x along a row, y down the columns, z into the board).
#pragma once

#include <cstdint>
#include <vector>

#include <Eigen/Core>

#include "core/cell.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/status.h"

namespace bp {

// The board's inner corners in its own frame (z = 0), row by row.
std::vector<Vec3> BoardCorners(const CalibrationSpec& board);
// Centre of the inner-corner grid, in the board frame.
Vec3 BoardCentre(const CalibrationSpec& board);

// OK when the whole board (with its white margin) is in view at X_CT;
// OutOfRange naming why not (behind the camera, its back or edge-on beyond
// 70 degrees, or a corner outside the image).
Status BoardVisibility(const CalibrationSpec& board, const Intrinsics& intrinsics, const Pose& X_CT);

// Renders the board at X_CT through `intrinsics` (no lens distortion), in
// view or not: each pixel's 4x4 sub-sample rays meet the board plane (exact
// for a planar target; the back of the board is blank), then blur_sigma and
// gaussian noise image_noise drawn from `seed`.
Result<IntensityImage> RenderBoard(const CalibrationSpec& board, const Intrinsics& intrinsics, const Pose& X_CT,
                                   uint64_t seed);

struct BoardDetection {
  Pose X_CT = Pose::Identity();
  std::vector<Eigen::Vector2d> corners;  // sub-pixel, in BoardCorners order
  double rms_px = 0;                     // reprojection RMS of X_CT
};

// findChessboardCorners + cornerSubPix + solvePnP (iterative).
// @returns NotFound when the board is not found in the image.
Result<BoardDetection> DetectBoard(const IntensityImage& image, const CalibrationSpec& board,
                                   const Intrinsics& intrinsics);

}  // namespace bp
