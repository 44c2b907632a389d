#include "calib/board.h"

#include <opencv2/calib3d.hpp>
#include <opencv2/core/eigen.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>
#include <random>
#include <string>

namespace bp {
namespace {

constexpr double kBackground = 100;
constexpr double kWhite = 230;
constexpr double kBlack = 25;
constexpr int kSupersample = 4;         // sub-samples per pixel and axis
constexpr double kMaxViewAngleDeg = 70;  // beyond this a board is "edge-on"

cv::Mat CameraMatrix(const Intrinsics& k) {
  return (cv::Mat_<double>(3, 3) << k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1);
}

// Grey value of the board texture at board coordinates (x, y) (metres):
// a white margin of one square around (cols + 1) x (rows + 1) squares, the
// square before the first inner corner black. NaN outside the board.
double BoardTexture(const CalibrationSpec& b, double x, double y) {
  const double s = b.square_size;
  if (x < -2 * s || y < -2 * s || x > (b.cols + 1) * s || y > (b.rows + 1) * s) return NAN;
  if (x < -s || y < -s || x > b.cols * s || y > b.rows * s) return kWhite;
  const int i = static_cast<int>(std::floor(x / s));
  const int j = static_cast<int>(std::floor(y / s));
  return ((i + j) % 2 == 0) ? kBlack : kWhite;
}

}  // namespace

std::vector<Vec3> BoardCorners(const CalibrationSpec& b) {
  std::vector<Vec3> corners;
  corners.reserve(static_cast<size_t>(b.cols) * b.rows);
  for (int r = 0; r < b.rows; ++r) {
    for (int c = 0; c < b.cols; ++c) corners.emplace_back(c * b.square_size, r * b.square_size, 0.0);
  }
  return corners;
}

Vec3 BoardCentre(const CalibrationSpec& b) {
  return Vec3((b.cols - 1) * b.square_size / 2, (b.rows - 1) * b.square_size / 2, 0.0);
}

Status BoardVisibility(const CalibrationSpec& b, const Intrinsics& k, const Pose& X_CT) {
  const double s = b.square_size;
  // Visibility: every outer corner of the board in front of the camera and
  // inside the image, the camera on the board's front side, not edge-on.
  const Vec3 centre_C = X_CT * BoardCentre(b);
  const Vec3 z_C = X_CT.linear().col(2);  // into the board
  if (centre_C.z() <= 0) return Status::OutOfRange("the board is behind the camera");
  const double cos_view = z_C.dot(centre_C.normalized());
  if (cos_view <= 0) return Status::OutOfRange("the camera sees the back of the board");
  const double view_deg = std::acos(std::min(1.0, cos_view)) * 180 / M_PI;
  if (view_deg > kMaxViewAngleDeg) {
    return Status::OutOfRange("the board is seen at " + std::to_string(static_cast<int>(view_deg)) +
                              " deg from its normal (more than " + std::to_string(static_cast<int>(kMaxViewAngleDeg)) +
                              ")");
  }
  const double lo = -2 * s, hx = (b.cols + 1) * s, hy = (b.rows + 1) * s;
  for (const Vec3& p_T : {Vec3(lo, lo, 0), Vec3(hx, lo, 0), Vec3(lo, hy, 0), Vec3(hx, hy, 0)}) {
    const Vec3 p = X_CT * p_T;
    if (p.z() <= 0.05) return Status::OutOfRange("a board corner is behind the camera");
    const double u = k.fx * p.x() / p.z() + k.cx, v = k.fy * p.y() / p.z() + k.cy;
    if (u < 2 || v < 2 || u > k.width - 3 || v > k.height - 3) {
      return Status::OutOfRange("the board is not fully in the image (a corner at " + std::to_string(int(u)) + ", " +
                                std::to_string(int(v)) + " px)");
    }
  }
  return Status::Ok();
}

Result<IntensityImage> RenderBoard(const CalibrationSpec& b, const Intrinsics& k, const Pose& X_CT, uint64_t seed) {
  if (!k.valid()) return Status::InvalidArgument("RenderBoard: invalid intrinsics");
  // The back of the board shows no pattern.
  const bool front = X_CT.linear().col(2).dot(X_CT * BoardCentre(b)) > 0;

  // Each sub-sample's ray d = ((uu - cx) / fx, (vv - cy) / fy, 1) meets the
  // board plane n.(p - t) = 0 at lambda * d, lambda = n.t / n.d; on the board
  // that is p_T = R^T (lambda d - t). R^T d and n.d are affine in (uu, vv):
  // per sub-sample only the x and y of p_T are computed, in scalars.
  const Mat3 R = X_CT.linear();
  const Vec3 t = X_CT.translation();
  const Vec3 n = R.col(2);
  const double nt = n.dot(t);
  const Mat3 Rt = R.transpose();
  const Vec3 du = Rt.col(0) / k.fx, dv = Rt.col(1) / k.fy;
  const Vec3 d0 = Rt.col(2) - du * k.cx - dv * k.cy;  // R^T d at (uu, vv) = (0, 0)
  const Vec3 Rt_t = Rt * t;
  const double nd_u = n.x() / k.fx, nd_v = n.y() / k.fy, nd_0 = n.z() - nd_u * k.cx - nd_v * k.cy;
  cv::Mat img(k.height, k.width, CV_32F);
  const double step = 1.0 / kSupersample;
  for (int v = 0; v < k.height; ++v) {
    float* row = img.ptr<float>(v);
    for (int u = 0; u < k.width; ++u) {
      double sum = 0;
      for (int sv = 0; sv < kSupersample; ++sv) {
        const double vv = v - 0.5 + (sv + 0.5) * step;
        for (int su = 0; su < kSupersample; ++su) {
          const double uu = u - 0.5 + (su + 0.5) * step;
          const double nd = nd_0 + nd_u * uu + nd_v * vv;
          double g = kBackground;
          if (front && std::abs(nd) > 1e-12) {
            const double lambda = nt / nd;
            if (lambda > 0) {
              const double x = lambda * (d0.x() + du.x() * uu + dv.x() * vv) - Rt_t.x();
              const double y = lambda * (d0.y() + du.y() * uu + dv.y() * vv) - Rt_t.y();
              const double tex = BoardTexture(b, x, y);
              if (!std::isnan(tex)) g = tex;
            }
          }
          sum += g;
        }
      }
      row[u] = static_cast<float>(sum / (kSupersample * kSupersample));
    }
  }
  if (b.blur_sigma > 0) cv::GaussianBlur(img, img, cv::Size(0, 0), b.blur_sigma);
  std::mt19937_64 rng(seed);
  std::normal_distribution<float> noise(0.0f, static_cast<float>(b.image_noise));
  IntensityImage out(k.width, k.height);
  for (int v = 0; v < k.height; ++v) {
    const float* row = img.ptr<float>(v);
    for (int u = 0; u < k.width; ++u) {
      const float g = row[u] + (b.image_noise > 0 ? noise(rng) : 0.0f);
      out.at(u, v) = static_cast<uint8_t>(std::clamp(std::lround(g), 0L, 255L));
    }
  }
  return out;
}

Result<BoardDetection> DetectBoard(const IntensityImage& image, const CalibrationSpec& b, const Intrinsics& k) {
  if (image.empty()) return Status::InvalidArgument("DetectBoard: empty image");
  cv::Mat img(image.height, image.width, CV_8U, const_cast<uint8_t*>(image.data.data()));
  std::vector<cv::Point2f> found;
  const cv::Size pattern(b.cols, b.rows);
  if (!cv::findChessboardCorners(img, pattern, found,
                                 cv::CALIB_CB_ADAPTIVE_THRESH | cv::CALIB_CB_NORMALIZE_IMAGE | cv::CALIB_CB_FAST_CHECK)) {
    return Status::NotFound("no " + std::to_string(b.cols) + "x" + std::to_string(b.rows) +
                            " checkerboard found in the image");
  }
  cv::cornerSubPix(img, found, cv::Size(5, 5), cv::Size(-1, -1),
                   cv::TermCriteria(cv::TermCriteria::EPS + cv::TermCriteria::COUNT, 100, 1e-4));
  const cv::Mat K = CameraMatrix(k);
  const cv::Mat dist(1, 5, CV_64F, const_cast<double*>(k.distortion.data()));
  std::vector<cv::Point3f> object;
  for (const Vec3& p : BoardCorners(b)) object.emplace_back(float(p.x()), float(p.y()), float(p.z()));

  auto solve = [&](const std::vector<cv::Point2f>& pts, cv::Mat& rvec, cv::Mat& tvec) {
    cv::solvePnP(object, pts, K, dist, rvec, tvec, false, cv::SOLVEPNP_IPPE);
    cv::solvePnPRefineLM(object, pts, K, dist, rvec, tvec);
  };
  cv::Mat rvec, tvec;
  solve(found, rvec, tvec);
  // OpenCV may order the corners from either end of the board. The square
  // before the first inner corner is black; if the image shows white there,
  // the order is reversed (cols + rows is odd, so the flip changes colour).
  {
    std::vector<cv::Point3f> probe = {cv::Point3f(float(-b.square_size / 2), float(-b.square_size / 2), 0)};
    std::vector<cv::Point2f> at;
    cv::projectPoints(probe, rvec, tvec, K, dist, at);
    const int u = std::clamp(int(std::lround(at[0].x)), 0, image.width - 1);
    const int v = std::clamp(int(std::lround(at[0].y)), 0, image.height - 1);
    const int expected_black = image.at(u, v);
    // Compare with the first white square inside the grid, (0, -1).
    std::vector<cv::Point3f> probe_w = {cv::Point3f(float(b.square_size / 2), float(-b.square_size / 2), 0)};
    cv::projectPoints(probe_w, rvec, tvec, K, dist, at);
    const int uw = std::clamp(int(std::lround(at[0].x)), 0, image.width - 1);
    const int vw = std::clamp(int(std::lround(at[0].y)), 0, image.height - 1);
    if (expected_black > image.at(uw, vw)) {
      std::reverse(found.begin(), found.end());
      solve(found, rvec, tvec);
    }
  }
  std::vector<cv::Point2f> reprojected;
  cv::projectPoints(object, rvec, tvec, K, dist, reprojected);
  BoardDetection d;
  double sq = 0;
  for (size_t i = 0; i < found.size(); ++i) {
    d.corners.emplace_back(found[i].x, found[i].y);
    const cv::Point2f e = found[i] - reprojected[i];
    sq += e.dot(e);
  }
  d.rms_px = std::sqrt(sq / found.size());
  cv::Mat Rcv;
  cv::Rodrigues(rvec, Rcv);
  Mat3 R;
  cv::cv2eigen(Rcv, R);
  d.X_CT = MakePose(R, Vec3(tvec.at<double>(0), tvec.at<double>(1), tvec.at<double>(2)));
  return d;
}

}  // namespace bp
