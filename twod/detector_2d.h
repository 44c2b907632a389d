// 2D part detection on the top-view intensity image (issue 9). Parts lie flat
// (cell parts[].flat_2d); the image is thresholded (Otsu), each external
// contour is mapped into the plane through the calibration (undistorted,
// intersected with the plane at half the part's thickness), classified by
// area and Hu moments against each class outline, and posed:
//
//   kMoments:         the principal axis of the contour's second moments; the
//                     180 deg ambiguity is settled by the better overlap (IoU)
//                     with the class outline. Outlines with no principal axis
//                     (isotropic inertia) fall back to the template search.
//   kRotatedTemplate: the class outline, rasterized at 0.25 mm, rotated about
//                     its centroid: a 3 deg sweep of the full turn maximizing
//                     IoU with the contour, then a golden-section refinement.
//
// Both take the position from the centroids. docs/protocols.md "2D tasks"
// has the measured accuracy of each.
//
// Thread-safety: Detect is const and keeps no state; concurrent calls are safe.
#pragma once

#include <cstdint>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "core/cell.h"
#include "core/image.h"
#include "core/status.h"
#include "twod/plane_calibration.h"
#include "twod/plane_camera.h"

namespace bp {

enum class Match2DMethod { kMoments, kRotatedTemplate };

struct Detector2DOptions {
  Match2DMethod method = Match2DMethod::kRotatedTemplate;
  double min_area_ratio = 0.75;  // contour area / class outline area accepted
  double max_area_ratio = 1.35;
  double max_shape_distance = 0.5;  // cv::matchShapes (CONTOURS_MATCH_I1) limit
  double min_iou = 0.8;             // a posed outline must cover the contour this well
  int min_blob_pixels = 30;         // smaller blobs are noise
  double min_contrast = 40;         // grey levels above the median (background) for foreground
};

struct Detection2D {
  int class_id = 0;
  Pose2D X_PO;                             // part in the plane
  double score = 0.0;                      // IoU of the posed outline with the contour
  std::vector<Eigen::Vector2d> outline_P;  // the contour in the plane (m)
};

struct Detect2DResult {
  std::vector<Detection2D> parts;
  // Every blob's contour in the plane, matched or not (obstacles for the
  // gripper footprint); parts[i] is blobs[part_blob[i]].
  std::vector<std::vector<Eigen::Vector2d>> blobs_P;
  std::vector<int> part_blob;
  int64_t foreground_pixels = 0;  // pixels above the threshold in blobs kept
  int64_t largest_blob_pixels = 0;
};

class Detector2D {
 public:
  explicit Detector2D(const Cell& cell, Detector2DOptions options = {});
  // Detects parts of `classes` (empty = every class with flat_2d).
  Result<Detect2DResult> Detect(const IntensityImage& image, const PlaneCalibration& calibration,
                                const std::vector<int>& classes = {}) const;
  const Detector2DOptions& options() const { return options_; }

 private:
  Cell cell_;
  Detector2DOptions options_;
};

// The calibration marker's centre in pixels: the brightest blob's
// background-subtracted intensity centroid. @returns NotFound without a blob
// `min_contrast` grey levels above the background.
Result<Eigen::Vector2d> FindMarker(const IntensityImage& image, double min_contrast = 40);

// True when polygon `a` (e.g. a gripper footprint) and polygon `b` (a
// neighbour's contour) overlap: a vertex of one inside the other or two edges
// crossing. Both in the same frame.
bool PolygonsOverlap(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b);

}  // namespace bp
