// Perception's last stage for parts nearly round about an axis (a pipe tee
// about its run; docs/perception_pipeline.md, "Turns on the part's own
// points"): once every detection of the frame is accepted, each such part's
// turn is decided again on its own points, those its accepted neighbours
// explain left out. Private to bp_pipeline. Frames: B base, O part. SI units.
#pragma once

#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include <Eigen/Core>

#include "pipeline/frame.h"
#include "pipeline/internal/class_model.h"
#include "pipeline/perception.h"

namespace bp::internal {

// For each detection whose class has turn axes: the ROI points within the
// part's reach of its surface centre, less those within 2.5 mm of another
// detection's surface, are its own points; the frame's depth image with
// the others' pixels blanked is its view. ClassModel::ChooseTurn on that
// view; a pose that explains more than (1 + min_gain) times what the
// detection's pose does (supported minus free-space samples) becomes the
// pose, the detection's pose its first alternative when the two are
// distinct (ClassModel::DistinctPoses; at most the class's max_alternatives
// kept; alternatives within the tolerance of the new pose are dropped), its
// support the old support on the new surface;
// its score stays the one acceptance ranked it by. A part whose neighbours
// hold less than min_foreign_fraction of the points within its reach is
// left as it is unless its pose is ambiguous (Detection::pose_ambiguous):
// its own points are then about the view the fine pass judged its turns on
// (but its 30 deg grid may have stepped over the true turn: a tee fully in
// view, its branch hidden behind its run, 13 deg off in pile 1043 of the
// tuning range, hence the ambiguous ones).
// Detections are judged in order, each against its neighbours as they
// stand. Organized frames only (point_of_pixel: RoiCloud::point_of_pixel);
// an unorganized frame changes nothing. @returns how many poses changed.
int RedecideTurns(std::span<const ClassModel* const> models, const Frame& frame,
                  std::span<const Eigen::Vector3f> roi_points_B, std::span<const int32_t> point_of_pixel,
                  const std::optional<Eigen::Vector4d>& floor_plane_B, double min_gain,
                  double min_foreign_fraction, std::vector<Detection>* detections);

}  // namespace bp::internal
