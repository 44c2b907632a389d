#include "twod/plane_calibration.h"

#include <yaml-cpp/yaml.h>

#include <cmath>
#include <fstream>
#include <iomanip>
#include <sstream>

#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>

#include "core/atomic_file.h"
#include "twod/internal/cv_util.h"

namespace bp {

Eigen::Vector2d PlaneCalibration::PixelToPlane(const Eigen::Vector2d& uv, double height) const {
  return PixelsToPlane({uv}, height).front();
}

std::vector<Eigen::Vector2d> PlaneCalibration::PixelsToPlane(const std::vector<Eigen::Vector2d>& uv,
                                                             double height) const {
  const std::vector<Eigen::Vector2d> n = internal::Undistort(intrinsics, uv);
  const Pose X_PC = X_CP.inverse();
  const Vec3 o_P = X_PC.translation();
  std::vector<Eigen::Vector2d> out;
  out.reserve(n.size());
  for (const Eigen::Vector2d& xy : n) {
    const Vec3 d_P = X_PC.linear() * Vec3(xy.x(), xy.y(), 1.0);
    const double s = (height - o_P.z()) / d_P.z();
    out.emplace_back(o_P.x() + s * d_P.x(), o_P.y() + s * d_P.y());
  }
  return out;
}

Result<PlaneCalibration> FitPlaneCalibration(const Intrinsics& K, const std::vector<Eigen::Vector2d>& pixels,
                                             const std::vector<Eigen::Vector2d>& plane_xy) {
  if (!K.valid()) return Status::InvalidArgument("2D calibration: invalid intrinsics");
  if (pixels.size() != plane_xy.size()) return Status::InvalidArgument("2D calibration: point count mismatch");
  if (pixels.size() < 4) {
    return Status::InvalidArgument("2D calibration: needs >= 4 points, got " + std::to_string(pixels.size()));
  }
  const std::vector<Eigen::Vector2d> n = internal::Undistort(K, pixels);
  std::vector<cv::Point2d> src, dst;
  std::vector<cv::Point3d> obj;
  for (size_t i = 0; i < n.size(); ++i) {
    src.emplace_back(n[i].x(), n[i].y());
    dst.emplace_back(plane_xy[i].x(), plane_xy[i].y());
    obj.emplace_back(plane_xy[i].x(), plane_xy[i].y(), 0.0);
  }
  // Degenerate layouts (collinear points) make the homography meaningless.
  cv::Mat cov;
  cv::Mat mean;
  cv::Mat pts(static_cast<int>(dst.size()), 2, CV_64F, dst.data());
  cv::calcCovarMatrix(pts, cov, mean, cv::COVAR_NORMAL | cv::COVAR_ROWS);
  cv::Mat eig;
  cv::eigen(cov, eig);
  if (eig.at<double>(1) < 1e-12 * static_cast<double>(dst.size())) {
    return Status::InvalidArgument("2D calibration: points are collinear");
  }
  const cv::Mat H = cv::findHomography(src, dst, 0);
  if (H.empty()) return Status::InvalidArgument("2D calibration: homography fit failed");

  PlaneCalibration c;
  c.intrinsics = K;
  cv::cv2eigen(H, c.H_PN);
  // Plane pose in the camera: planar PnP on the undistorted points (identity
  // camera matrix), which starts from the homography and refines with LM.
  cv::Mat rvec, tvec;
  if (!cv::solvePnP(obj, src, cv::Mat::eye(3, 3, CV_64F), cv::Mat(), rvec, tvec, false,
                    cv::SOLVEPNP_ITERATIVE)) {
    return Status::InvalidArgument("2D calibration: plane pose fit failed");
  }
  cv::Mat R;
  cv::Rodrigues(rvec, R);
  Mat3 R_CP;
  Vec3 t_CP;
  cv::cv2eigen(R, R_CP);
  cv::cv2eigen(tvec, t_CP);
  c.X_CP = MakePose(R_CP, t_CP);
  c.points = static_cast<int>(pixels.size());
  const std::vector<Eigen::Vector2d> mapped = c.PixelsToPlane(pixels, 0.0);
  double sum = 0;
  for (size_t i = 0; i < mapped.size(); ++i) {
    const double e = (mapped[i] - plane_xy[i]).norm() * 1000.0;
    sum += e * e;
    c.residual_max_mm = std::max(c.residual_max_mm, e);
  }
  c.residual_rms_mm = std::sqrt(sum / static_cast<double>(mapped.size()));
  return c;
}

std::string SerializePlaneCalibration(const PlaneCalibration& c) {
  std::ostringstream o;
  o << std::setprecision(17);
  o << "# binpick 2D (plane) calibration: image -> robot plane. docs/file_formats.md\n";
  o << "format: binpick-plane-calibration-1\n";
  const Intrinsics& K = c.intrinsics;
  o << "intrinsics: {width: " << K.width << ", height: " << K.height << ", fx: " << K.fx << ", fy: " << K.fy
    << ", cx: " << K.cx << ", cy: " << K.cy << ", distortion: [" << K.distortion[0] << ", " << K.distortion[1]
    << ", " << K.distortion[2] << ", " << K.distortion[3] << ", " << K.distortion[4] << "]}\n";
  o << "homography: [";
  for (int i = 0; i < 9; ++i) o << (i ? ", " : "") << c.H_PN(i / 3, i % 3);
  o << "]\n";
  const Eigen::Matrix4d M = c.X_CP.matrix();
  o << "plane_in_camera: [";
  for (int i = 0; i < 12; ++i) o << (i ? ", " : "") << M(i / 4, i % 4);
  o << "]\n";
  o << "residual_rms_mm: " << c.residual_rms_mm << "\nresidual_max_mm: " << c.residual_max_mm
    << "\npoints: " << c.points << "\n";
  return o.str();
}

Result<PlaneCalibration> ParsePlaneCalibration(const std::string& text, const std::string& path) {
  try {
    const YAML::Node root = YAML::Load(text);
    auto need = [&](const YAML::Node& n, const char* key) {
      if (!n[key].IsDefined()) throw std::runtime_error(std::string("missing key '") + key + "'");
      return n[key];
    };
    if (need(root, "format").as<std::string>() != "binpick-plane-calibration-1") {
      return Status::InvalidArgument(path + ": format: unknown format '" + root["format"].as<std::string>() + "'");
    }
    PlaneCalibration c;
    const YAML::Node k = need(root, "intrinsics");
    c.intrinsics.width = need(k, "width").as<int>();
    c.intrinsics.height = need(k, "height").as<int>();
    c.intrinsics.fx = need(k, "fx").as<double>();
    c.intrinsics.fy = need(k, "fy").as<double>();
    c.intrinsics.cx = need(k, "cx").as<double>();
    c.intrinsics.cy = need(k, "cy").as<double>();
    const YAML::Node d = need(k, "distortion");
    if (!d.IsSequence() || d.size() != 5) return Status::InvalidArgument(path + ": intrinsics.distortion: expected 5 numbers");
    for (int i = 0; i < 5; ++i) c.intrinsics.distortion[i] = d[i].as<double>();
    if (!c.intrinsics.valid()) return Status::InvalidArgument(path + ": intrinsics: invalid");
    const YAML::Node h = need(root, "homography");
    if (!h.IsSequence() || h.size() != 9) return Status::InvalidArgument(path + ": homography: expected 9 numbers");
    for (int i = 0; i < 9; ++i) c.H_PN(i / 3, i % 3) = h[i].as<double>();
    const YAML::Node p = need(root, "plane_in_camera");
    if (!p.IsSequence() || p.size() != 12) {
      return Status::InvalidArgument(path + ": plane_in_camera: expected 12 numbers (3x4 row-major)");
    }
    Mat3 R;
    Vec3 t;
    for (int i = 0; i < 12; ++i) (i % 4 == 3 ? t(i / 4) : R(i / 4, i % 4)) = p[i].as<double>();
    if ((R * R.transpose() - Mat3::Identity()).norm() > 1e-6 || R.determinant() < 0) {
      return Status::InvalidArgument(path + ": plane_in_camera: not a rotation");
    }
    c.X_CP = MakePose(R, t);
    c.residual_rms_mm = need(root, "residual_rms_mm").as<double>();
    c.residual_max_mm = need(root, "residual_max_mm").as<double>();
    c.points = need(root, "points").as<int>();
    return c;
  } catch (const YAML::ParserException& e) {
    return Status::Corruption(path + ":" + std::to_string(e.mark.line + 1) + ": YAML syntax error: " + e.msg);
  } catch (const std::exception& e) {
    return Status::Corruption(path + ": " + e.what());
  }
}

Status SavePlaneCalibration(const PlaneCalibration& calibration, const std::string& path) {
  AtomicWriteOptions options;
  options.keep_backup = true;
  return WriteFileAtomic(path, SerializePlaneCalibration(calibration), options);
}

Result<PlaneCalibration> LoadPlaneCalibration(const std::string& path) {
  std::ifstream in(path);
  if (!in) return Status::NotFound(path + ": no 2D calibration file");
  std::stringstream s;
  s << in.rdbuf();
  return ParsePlaneCalibration(s.str(), path);
}

}  // namespace bp
