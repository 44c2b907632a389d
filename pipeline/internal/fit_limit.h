// The largest point-to-plane fit residual a detection may leave, from the
// depth noise of the camera that captured the frame (PerceptionOptions::
// max_fit_rms_sigmas). Private to bp_pipeline. Frames: B base, C camera,
// O part. SI units.
#pragma once

#include <utility>

#include "core/cell.h"
#include "core/image.h"
#include "core/pose.h"
#include "pipeline/frame.h"

namespace bp::internal {

class ClassModel;

// The depth noise of the camera config that captured a frame (organized: the
// one whose intrinsics it has), else of the default config; nullptr when the
// cell has no config.
const NoiseModel* FrameNoise(const CameraSpec& camera, const Frame& frame);

// Axial noise of an organized frame, measured: the median absolute second
// difference along rows (z[u-1] - 2 z[u] + z[u+1], variance 6 sigma^2 for
// independent noise; edges and curvature are outliers the median ignores)
// over a sparse lattice of pixels. Returns {sigma, median depth}, metres;
// {0, 0} for too few samples.
std::pair<double, double> MeasureDepthNoise(const DepthImage& depth);

// The axial depth noise of one frame, sigma(z) in metres at depth z along
// C's optical axis: the capturing config's NoiseModel (FrameNoise) scaled up
// by measured / modelled at the frame's median depth when the frame is
// noisier than modelled (never down: the model is the floor); the measured
// sigma at every depth when the cell has no noise model; 0 when neither is
// known.
class DepthNoise {
 public:
  DepthNoise() = default;
  // Measures organized frames (MeasureDepthNoise).
  DepthNoise(const CameraSpec& camera, const Frame& frame);
  double Sigma(double z) const;
  double measured_sigma() const { return measured_sigma_; }  // 0: not measured
  double measured_at() const { return measured_at_; }        // median depth of the measurement
  double scale() const { return scale_; }                    // measured / modelled, >= 1

 private:
  double ModelSigma(double z) const;
  const NoiseModel* model_ = nullptr;
  double measured_sigma_ = 0.0;
  double measured_at_ = 0.0;
  double scale_ = 1.0;
};

// Per frame: the residual limit at a part's pose, max_sigmas x the frame's
// DepthNoise at the part's centroid depth (and at least min_limit).
class FitRmsLimit {
 public:
  // max_sigmas <= 0: no limit. min_limit: metres.
  FitRmsLimit(double max_sigmas, double min_limit, const DepthNoise& noise, const Frame& frame);
  bool enabled() const { return max_sigmas_ > 0.0; }
  // Metres; infinity when there is no noise figure.
  double At(const ClassModel& model, const Pose& X_BO) const;

 private:
  double max_sigmas_;
  double min_limit_;
  DepthNoise noise_;
  Pose X_CB_ = Pose::Identity();
};

}  // namespace bp::internal
