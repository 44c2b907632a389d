// Scene points as a collision obstacle: an occupancy octree (FCL's OcTree over
// octomap) built once per frame, queried with placed CollisionGeometry.
//
// Every voxel (edge `resolution`) that holds at least one point is occupied;
// a geometry collides when it overlaps an occupied voxel, so the obstacle is
// the points inflated by up to one voxel. FCL stays behind the pimpl.
//
// Thread-safety: immutable after FromPoints; Collides may be called
// concurrently from any number of threads.
#pragma once

#include <Eigen/Core>
#include <memory>
#include <span>

#include "collision/mesh_collider.h"
#include "core/pose.h"
#include "core/status.h"

namespace bp {

class PointObstacle {
 public:
  // Points in the world frame W (the frame of later queries). Non-finite
  // points are skipped. @returns InvalidArgument for resolution <= 0.
  static Result<std::shared_ptr<const PointObstacle>> FromPoints(std::span<const Eigen::Vector3f> points_W,
                                                                  double resolution);
  ~PointObstacle();
  PointObstacle(const PointObstacle&) = delete;
  PointObstacle& operator=(const PointObstacle&) = delete;

  // True when `geometry` at X_WG overlaps an occupied voxel. An obstacle
  // without points never collides.
  bool Collides(const CollisionGeometry& geometry, const Pose& X_WG) const;
  size_t num_points() const { return num_points_; }
  size_t num_occupied_voxels() const;
  double resolution() const { return resolution_; }

 private:
  class Impl;
  PointObstacle(std::unique_ptr<Impl> impl, size_t num_points, double resolution);
  std::unique_ptr<Impl> impl_;
  size_t num_points_ = 0;
  double resolution_ = 0;
};

using PointObstaclePtr = std::shared_ptr<const PointObstacle>;

}  // namespace bp
