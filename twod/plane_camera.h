// The top-view camera of 2D tasks: an intensity image of the robot's plane P.
// SyntheticPlaneCamera renders flat parts (cell parts[].flat_2d: outline
// extruded by its thickness) and the calibration marker through the camera's
// distorted pinhole model, with anti-aliasing and Gaussian noise.
//
// The synthetic plane is the bin frame W: X_CP = inverse(X_BC) * X_BW (the
// robot's plane coincides with the bin floor / table).
//
// Thread-safety: SyntheticPlaneCamera is internally locked (calibration steps
// and captures may come from different workers).
#pragma once

#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <vector>

#include <Eigen/Core>

#include "core/cell.h"
#include "core/image.h"
#include "core/pose.h"
#include "core/status.h"

namespace bp {

// A pose in the plane: position (m) and rotation about the plane normal (rad).
struct Pose2D {
  double x = 0.0, y = 0.0, theta = 0.0;
  Eigen::Vector2d xy() const { return {x, y}; }
  Eigen::Vector2d Apply(const Eigen::Vector2d& p) const;  // this * p
  Pose2D Compose(const Pose2D& b) const;                   // this * b
};
// Wraps to (-pi, pi].
double WrapAngle(double a);

struct FlatPartTruth {
  int instance_id = 0;
  int class_id = 0;
  Pose2D X_PO;  // part in plane
};

struct PlaneImage {
  IntensityImage image;
  Intrinsics intrinsics;
  std::vector<FlatPartTruth> truth;  // synthetic only (empty for a real camera)
};

struct PlaneCaptureRequest {
  // The robot carries the calibration marker at its tool centre point, at
  // X_PT (the pose it sent); nullopt: an ordinary capture of the parts.
  std::optional<Pose> marker_X_PT;
};

class PlaneCamera {
 public:
  virtual ~PlaneCamera() = default;
  virtual Result<PlaneImage> Capture(const PlaneCaptureRequest& request) = 0;
  // Simulated pick: the part leaves the scene (real cameras ignore it).
  virtual void RemovePart(int /*instance_id*/) {}
  virtual Intrinsics intrinsics() const = 0;
};

struct SyntheticPlaneOptions {
  double noise_sigma = 2.0;         // grey levels
  int supersample = 4;              // anti-aliasing factor per axis
  double marker_radius = 0.008;     // m, a white disc at the tool centre point
  // The robot's positioning error: the marker lands this far (sigma per
  // axis, m) from the pose the robot reports (UR-class repeatability).
  double robot_sigma = 0.00003;
  uint8_t background = 40, top = 200, side = 140, marker = 235;
  double min_gap = 0.006;           // m between scattered parts' outlines (bounding circles)
};

class SyntheticPlaneCamera final : public PlaneCamera {
 public:
  // Uses the cell's default camera config and X_CP = inverse(X_BC) * X_BW.
  static Result<std::unique_ptr<SyntheticPlaneCamera>> Create(const Cell& cell,
                                                              SyntheticPlaneOptions options = {});
  // Drops `count` parts of `classes` (those with flat_2d; empty = all) at
  // random poses inside the bin's inner area, non-overlapping; seeded.
  Status Scatter(int count, uint64_t seed, const std::vector<int>& classes = {});
  // Replaces the scene with explicit parts (tests).
  void SetParts(std::vector<FlatPartTruth> parts);
  std::vector<FlatPartTruth> parts() const;
  Pose X_CP() const { return X_CP_; }

  Result<PlaneImage> Capture(const PlaneCaptureRequest& request) override;
  void RemovePart(int instance_id) override;
  Intrinsics intrinsics() const override { return K_; }

 private:
  SyntheticPlaneCamera(const Cell& cell, const Intrinsics& K, const Pose& X_CP, SyntheticPlaneOptions o)
      : cell_(cell), K_(K), X_CP_(X_CP), options_(o) {}
  const Cell cell_;
  const Intrinsics K_;
  const Pose X_CP_;
  const SyntheticPlaneOptions options_;
  mutable std::mutex mutex_;
  std::vector<FlatPartTruth> parts_;  // GUARDED_BY(mutex_)
  uint64_t captures_ = 0;             // GUARDED_BY(mutex_); seeds the noise
};

}  // namespace bp
