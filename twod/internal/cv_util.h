// OpenCV helpers of the 2D module (private: OpenCV stays out of public headers).
#pragma once

#include <vector>

#include <Eigen/Core>
#include <opencv2/core.hpp>

#include "core/cell.h"
#include "core/image.h"
#include "core/pose.h"

namespace bp::internal {

cv::Mat CameraMatrix(const Intrinsics& K);
cv::Mat Distortion(const Intrinsics& K);
// Pixels -> undistorted normalized image coordinates (x/z, y/z).
std::vector<Eigen::Vector2d> Undistort(const Intrinsics& K, const std::vector<Eigen::Vector2d>& uv);
// Points in the plane frame P -> pixels, through X_CP and the distorted pinhole.
std::vector<cv::Point2d> Project(const Intrinsics& K, const Pose& X_CP, const std::vector<Vec3>& p_P);

// Views of the plain images as cv::Mat (no copy).
inline cv::Mat AsMat(IntensityImage& image) { return cv::Mat(image.height, image.width, CV_8UC1, image.data.data()); }
inline cv::Mat AsMat(const IntensityImage& image) {
  return cv::Mat(image.height, image.width, CV_8UC1, const_cast<uint8_t*>(image.data.data()));
}

}  // namespace bp::internal
