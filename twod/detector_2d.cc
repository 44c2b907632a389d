#include "twod/detector_2d.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Dense>
#include <opencv2/imgproc.hpp>

#include "twod/internal/cv_util.h"

namespace bp {
namespace {

// Otsu's threshold, but never closer than `min_contrast` grey levels to the
// median (the background): an empty plane is noise, not parts.
cv::Mat Foreground(const cv::Mat& gray, double min_contrast) {
  cv::Mat binary;
  const double otsu = cv::threshold(gray, binary, 0, 255, cv::THRESH_BINARY | cv::THRESH_OTSU);
  int hist[256] = {};
  for (int v = 0; v < gray.rows; ++v) {
    const uint8_t* row = gray.ptr<uint8_t>(v);
    for (int u = 0; u < gray.cols; ++u) ++hist[row[u]];
  }
  const int64_t half = static_cast<int64_t>(gray.total()) / 2;
  int64_t seen = 0;
  int median = 0;
  while (median < 255 && (seen += hist[median]) < half) ++median;
  if (otsu < median + min_contrast) cv::threshold(gray, binary, median + min_contrast, 255, cv::THRESH_BINARY);
  return binary;
}

constexpr double kRasterM = 0.00025;  // IoU raster cell (m)
constexpr int kShift = 4;

struct ClassTemplate {
  const PartSpec* part = nullptr;
  std::vector<cv::Point2f> outline_mm;  // part frame, mm
  double area_mm2 = 0;
  Eigen::Vector2d centroid_m = Eigen::Vector2d::Zero();
  double axis = 0;        // principal axis angle in the part frame (rad)
  double anisotropy = 1;  // major / minor second moment
  double radius_m = 0;    // about the centroid
};

struct Moments2 {
  Eigen::Vector2d centroid_m;
  double axis = 0;
  double anisotropy = 1;
  double area_mm2 = 0;
};

Moments2 PolygonMoments(const std::vector<cv::Point2f>& mm) {
  const cv::Moments m = cv::moments(mm);
  Moments2 r;
  r.area_mm2 = std::abs(m.m00);
  r.centroid_m = Eigen::Vector2d(m.m10 / m.m00, m.m01 / m.m00) / 1000.0;
  r.axis = 0.5 * std::atan2(2 * m.mu11, m.mu20 - m.mu02);
  const double common = std::sqrt(4 * m.mu11 * m.mu11 + (m.mu20 - m.mu02) * (m.mu20 - m.mu02));
  const double l1 = (m.mu20 + m.mu02 + common) / 2, l2 = (m.mu20 + m.mu02 - common) / 2;
  r.anisotropy = l2 > 0 ? l1 / l2 : 1e9;
  return r;
}

std::vector<cv::Point2f> ToMm(const std::vector<Eigen::Vector2d>& p) {
  std::vector<cv::Point2f> out;
  out.reserve(p.size());
  for (const Eigen::Vector2d& q : p) out.emplace_back(static_cast<float>(q.x() * 1000), static_cast<float>(q.y() * 1000));
  return out;
}

// Rasterizes polygon points (m, already centred) into a square mask of side
// 2 * half cells around the origin.
cv::Mat Rasterize(const std::vector<Eigen::Vector2d>& p, int half) {
  cv::Mat mask(2 * half, 2 * half, CV_8UC1, cv::Scalar(0));
  std::vector<cv::Point> pts;
  pts.reserve(p.size());
  for (const Eigen::Vector2d& q : p) {
    pts.emplace_back(static_cast<int>(std::lround((q.x() / kRasterM + half - 0.5) * (1 << kShift))),
                     static_cast<int>(std::lround((q.y() / kRasterM + half - 0.5) * (1 << kShift))));
  }
  const cv::Point* ptr = pts.data();
  const int n = static_cast<int>(pts.size());
  cv::fillPoly(mask, &ptr, &n, 1, cv::Scalar(255), cv::LINE_8, kShift);
  return mask;
}

double Iou(const cv::Mat& a, const cv::Mat& b) {
  const double inter = cv::countNonZero(a & b);
  const double uni = cv::countNonZero(a | b);
  return uni > 0 ? inter / uni : 0.0;
}

// IoU of the template rotated by phi about its centroid with the blob mask
// (both centred on their centroids).
double TemplateIou(const ClassTemplate& t, double phi, const cv::Mat& blob, int half) {
  const double c = std::cos(phi), s = std::sin(phi);
  std::vector<Eigen::Vector2d> rotated;
  rotated.reserve(t.part->flat_2d->outline.size());
  for (const Eigen::Vector2d& p : t.part->flat_2d->outline) {
    const Eigen::Vector2d q = p - t.centroid_m;
    rotated.emplace_back(c * q.x() - s * q.y(), s * q.x() + c * q.y());
  }
  return Iou(Rasterize(rotated, half), blob);
}

}  // namespace

Detector2D::Detector2D(const Cell& cell, Detector2DOptions options) : cell_(cell), options_(options) {}

Result<Detect2DResult> Detector2D::Detect(const IntensityImage& image, const PlaneCalibration& calibration,
                                          const std::vector<int>& classes) const {
  if (image.empty()) return Status::InvalidArgument("2D detection: empty image");
  if (image.width != calibration.intrinsics.width || image.height != calibration.intrinsics.height) {
    return Status::InvalidArgument("2D detection: image size differs from the calibration's camera");
  }
  std::vector<ClassTemplate> templates;
  for (const PartSpec& p : cell_.parts) {
    if (!p.flat_2d) continue;
    if (!classes.empty() && std::find(classes.begin(), classes.end(), p.class_id) == classes.end()) continue;
    ClassTemplate t;
    t.part = &p;
    t.outline_mm = ToMm(p.flat_2d->outline);
    const Moments2 m = PolygonMoments(t.outline_mm);
    t.area_mm2 = m.area_mm2;
    t.centroid_m = m.centroid_m;
    t.axis = m.axis;
    t.anisotropy = m.anisotropy;
    for (const Eigen::Vector2d& q : p.flat_2d->outline) t.radius_m = std::max(t.radius_m, (q - t.centroid_m).norm());
    templates.push_back(std::move(t));
  }
  if (templates.empty()) return Status::InvalidArgument("2D detection: no part class with flat_2d");

  const cv::Mat gray = internal::AsMat(image);
  const cv::Mat binary = Foreground(gray, options_.min_contrast);
  std::vector<std::vector<cv::Point>> contours;
  cv::findContours(binary, contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_NONE);

  Detect2DResult result;
  for (const std::vector<cv::Point>& contour : contours) {
    const double pixels = cv::contourArea(contour);
    if (pixels < options_.min_blob_pixels) continue;
    result.foreground_pixels += static_cast<int64_t>(pixels);
    result.largest_blob_pixels = std::max(result.largest_blob_pixels, static_cast<int64_t>(pixels));
    std::vector<Eigen::Vector2d> uv;
    uv.reserve(contour.size());
    for (const cv::Point& p : contour) uv.emplace_back(p.x, p.y);
    std::vector<Eigen::Vector2d> plane = calibration.PixelsToPlane(uv, 0.0);
    const std::vector<cv::Point2f> plane_mm = ToMm(plane);
    const Moments2 m0 = PolygonMoments(plane_mm);

    // Classify: area within bounds, smallest Hu-moment distance.
    const ClassTemplate* best = nullptr;
    double best_distance = options_.max_shape_distance;
    for (const ClassTemplate& t : templates) {
      const double ratio = m0.area_mm2 / t.area_mm2;
      if (ratio < options_.min_area_ratio || ratio > options_.max_area_ratio) continue;
      const double d = cv::matchShapes(plane_mm, t.outline_mm, cv::CONTOURS_MATCH_I1, 0);
      if (d < best_distance) {
        best_distance = d;
        best = &t;
      }
    }
    if (!best) {
      result.blobs_P.push_back(std::move(plane));
      continue;
    }
    // The silhouette of a flat part spans its bottom and top outlines: map it
    // at half the thickness.
    plane = calibration.PixelsToPlane(uv, best->part->flat_2d->thickness / 2);
    const Moments2 m = PolygonMoments(ToMm(plane));
    const int half = static_cast<int>(std::ceil(best->radius_m * 1.2 / kRasterM)) + 4;
    std::vector<Eigen::Vector2d> centred;
    centred.reserve(plane.size());
    for (const Eigen::Vector2d& q : plane) centred.push_back(q - m.centroid_m);
    const cv::Mat blob = Rasterize(centred, half);

    double phi = 0, iou = -1;
    auto consider = [&](double a) {
      const double v = TemplateIou(*best, a, blob, half);
      if (v > iou) {
        iou = v;
        phi = a;
      }
    };
    const bool has_axis = best->anisotropy > 1.15 && m.anisotropy > 1.15;
    if (options_.method == Match2DMethod::kMoments && has_axis) {
      const double a = m.axis - best->axis;
      consider(a);
      consider(a + M_PI);
    } else {
      for (int k = 0; k < 120; ++k) consider(2 * M_PI * k / 120);
      // Golden-section search on [phi - 3 deg, phi + 3 deg].
      const double g = (std::sqrt(5.0) - 1) / 2;
      double lo = phi - M_PI / 60, hi = phi + M_PI / 60;
      double x1 = hi - g * (hi - lo), x2 = lo + g * (hi - lo);
      double f1 = TemplateIou(*best, x1, blob, half), f2 = TemplateIou(*best, x2, blob, half);
      while (hi - lo > 0.0002) {
        if (f1 > f2) {
          hi = x2, x2 = x1, f2 = f1;
          x1 = hi - g * (hi - lo);
          f1 = TemplateIou(*best, x1, blob, half);
        } else {
          lo = x1, x1 = x2, f1 = f2;
          x2 = lo + g * (hi - lo);
          f2 = TemplateIou(*best, x2, blob, half);
        }
      }
      // The raster IoU is piecewise constant at this scale: a least-squares
      // parabola through 13 samples 0.25 deg apart smooths it.
      const double centre = (lo + hi) / 2, step = M_PI / 720;
      Eigen::Matrix<double, 13, 3> A;
      Eigen::Matrix<double, 13, 1> b;
      for (int k = -6; k <= 6; ++k) {
        A.row(k + 6) << k * k, k, 1.0;
        b(k + 6) = TemplateIou(*best, centre + k * step, blob, half);
      }
      const Eigen::Vector3d q = A.colPivHouseholderQr().solve(b);
      const double vertex = q(0) < 0 ? std::clamp(-q(1) / (2 * q(0)), -6.0, 6.0) : 0.0;
      phi = centre + vertex * step;
      iou = TemplateIou(*best, phi, blob, half);
    }
    if (iou < options_.min_iou) {
      result.blobs_P.push_back(std::move(plane));
      continue;
    }
    Detection2D d;
    d.class_id = best->part->class_id;
    d.score = iou;
    d.X_PO.theta = WrapAngle(phi);
    const double c = std::cos(phi), s = std::sin(phi);
    const Eigen::Vector2d rc(c * best->centroid_m.x() - s * best->centroid_m.y(),
                             s * best->centroid_m.x() + c * best->centroid_m.y());
    d.X_PO.x = m.centroid_m.x() - rc.x();
    d.X_PO.y = m.centroid_m.y() - rc.y();
    d.outline_P = plane;
    result.part_blob.push_back(static_cast<int>(result.blobs_P.size()));
    result.blobs_P.push_back(std::move(plane));
    result.parts.push_back(std::move(d));
  }
  return result;
}

Result<Eigen::Vector2d> FindMarker(const IntensityImage& image, double min_contrast) {
  if (image.empty()) return Status::InvalidArgument("marker: empty image");
  const cv::Mat gray = internal::AsMat(image);
  const cv::Mat binary = Foreground(gray, min_contrast);
  std::vector<std::vector<cv::Point>> contours;
  cv::findContours(binary, contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_NONE);
  const std::vector<cv::Point>* best = nullptr;
  double best_area = 20;  // px: smaller is noise
  for (const auto& c : contours) {
    const double a = cv::contourArea(c);
    if (a > best_area) {
      best_area = a;
      best = &c;
    }
  }
  if (!best) return Status::NotFound("marker: no bright blob in the image");
  // Background-subtracted intensity centroid over the blob's box, grown by 3
  // px so the anti-aliased rim counts.
  const cv::Rect box = (cv::boundingRect(*best) + cv::Size(6, 6) - cv::Point(3, 3)) & cv::Rect(0, 0, gray.cols, gray.rows);
  std::vector<uint8_t> outside;
  cv::Mat grown;
  cv::dilate(binary(box), grown, cv::Mat(), cv::Point(-1, -1), 3);
  for (int v = 0; v < box.height; ++v) {
    for (int u = 0; u < box.width; ++u) {
      if (!grown.at<uint8_t>(v, u)) outside.push_back(gray.at<uint8_t>(box.y + v, box.x + u));
    }
  }
  double background = 0;
  if (!outside.empty()) {
    std::nth_element(outside.begin(), outside.begin() + outside.size() / 2, outside.end());
    background = outside[outside.size() / 2];
  }
  double sw = 0, su = 0, sv = 0;
  for (int v = 0; v < box.height; ++v) {
    for (int u = 0; u < box.width; ++u) {
      if (!grown.at<uint8_t>(v, u)) continue;
      const double w = std::max(0.0, gray.at<uint8_t>(box.y + v, box.x + u) - background);
      sw += w;
      su += w * (box.x + u);
      sv += w * (box.y + v);
    }
  }
  if (sw <= 0) return Status::NotFound("marker: blob has no contrast");
  return Eigen::Vector2d(su / sw, sv / sw);
}

namespace {
double Cross(const Eigen::Vector2d& a, const Eigen::Vector2d& b, const Eigen::Vector2d& c) {
  return (b - a).x() * (c - a).y() - (b - a).y() * (c - a).x();
}
bool Inside(const std::vector<Eigen::Vector2d>& poly, const Eigen::Vector2d& p) {
  bool in = false;
  for (size_t i = 0, j = poly.size() - 1; i < poly.size(); j = i++) {
    const Eigen::Vector2d& a = poly[i];
    const Eigen::Vector2d& b = poly[j];
    if ((a.y() > p.y()) != (b.y() > p.y()) && p.x() < (b.x() - a.x()) * (p.y() - a.y()) / (b.y() - a.y()) + a.x()) {
      in = !in;
    }
  }
  return in;
}
}  // namespace

bool PolygonsOverlap(const std::vector<Eigen::Vector2d>& a, const std::vector<Eigen::Vector2d>& b) {
  if (a.size() < 3 || b.size() < 3) return false;
  for (const Eigen::Vector2d& p : a) {
    if (Inside(b, p)) return true;
  }
  for (const Eigen::Vector2d& p : b) {
    if (Inside(a, p)) return true;
  }
  for (size_t i = 0; i < a.size(); ++i) {
    const Eigen::Vector2d& p = a[i];
    const Eigen::Vector2d& q = a[(i + 1) % a.size()];
    for (size_t j = 0; j < b.size(); ++j) {
      const Eigen::Vector2d& r = b[j];
      const Eigen::Vector2d& s = b[(j + 1) % b.size()];
      if (Cross(p, q, r) * Cross(p, q, s) < 0 && Cross(r, s, p) * Cross(r, s, q) < 0) return true;
    }
  }
  return false;
}

}  // namespace bp
