// The one pose type. Frames are named by monogram (STYLE.md): X_AB is the pose
// of frame B expressed in frame A, so X_AC = X_AB * X_BC. SI units: metres,
// radians.
#pragma once

#include <Eigen/Geometry>

namespace bp {

using Pose = Eigen::Isometry3d;
using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;
using Quat = Eigen::Quaterniond;

inline Pose MakePose(const Mat3& R, const Vec3& t) {
  Pose X = Pose::Identity();
  X.linear() = R;
  X.translation() = t;
  return X;
}

inline Pose MakePose(const Quat& q, const Vec3& t) { return MakePose(q.normalized().toRotationMatrix(), t); }

// Rotation angle of R (radians, in [0, pi]).
inline double RotationAngle(const Mat3& R) { return Eigen::AngleAxisd(R).angle(); }

}  // namespace bp
