#include "twod/internal/cv_util.h"

#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

namespace bp::internal {

cv::Mat CameraMatrix(const Intrinsics& K) {
  return (cv::Mat_<double>(3, 3) << K.fx, 0, K.cx, 0, K.fy, K.cy, 0, 0, 1);
}

cv::Mat Distortion(const Intrinsics& K) {
  return (cv::Mat_<double>(1, 5) << K.distortion[0], K.distortion[1], K.distortion[2], K.distortion[3],
          K.distortion[4]);
}

std::vector<Eigen::Vector2d> Undistort(const Intrinsics& K, const std::vector<Eigen::Vector2d>& uv) {
  if (uv.empty()) return {};
  std::vector<cv::Point2d> in, out;
  in.reserve(uv.size());
  for (const Eigen::Vector2d& p : uv) in.emplace_back(p.x(), p.y());
  // Enough iterations for sub-0.01 px accuracy at the image corners.
  cv::undistortPoints(in, out, CameraMatrix(K), Distortion(K), cv::noArray(), cv::noArray(),
                      cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-12));
  std::vector<Eigen::Vector2d> n;
  n.reserve(out.size());
  for (const cv::Point2d& p : out) n.emplace_back(p.x, p.y);
  return n;
}

std::vector<cv::Point2d> Project(const Intrinsics& K, const Pose& X_CP, const std::vector<Vec3>& p_P) {
  std::vector<cv::Point2d> out;
  if (p_P.empty()) return out;
  std::vector<cv::Point3d> in;
  in.reserve(p_P.size());
  for (const Vec3& p : p_P) in.emplace_back(p.x(), p.y(), p.z());
  cv::Mat R, rvec, tvec;
  cv::eigen2cv(Mat3(X_CP.linear()), R);
  cv::Rodrigues(R, rvec);
  cv::eigen2cv(Vec3(X_CP.translation()), tvec);
  cv::projectPoints(in, rvec, tvec, CameraMatrix(K), Distortion(K), out);
  return out;
}

}  // namespace bp::internal
