#include "pipeline/bin_detection.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <vector>

#include <pcl/point_cloud.h>
#include <pcl/point_types.h>
#include <pcl/sample_consensus/ransac.h>
#include <pcl/sample_consensus/sac_model_perpendicular_plane.h>

#include <Eigen/Eigenvalues>

namespace bp {

const char* ToString(BinDetectSpec::Mode mode) {
  switch (mode) {
    case BinDetectSpec::Mode::kOff: return "off";
    case BinDetectSpec::Mode::kOn: return "on";
    case BinDetectSpec::Mode::kRequired: return "required";
  }
  return "?";
}

namespace {

// A symmetric 3x3 matrix given by its lower triangle (a_rc: row r, column
// c); the upper triangle is left zero, for readers of the lower one only
// (LDLT, the self-adjoint eigensolver).
Eigen::Matrix3d FromLowerTriangle(double a00, double a10, double a11, double a20, double a21, double a22) {
  Eigen::Matrix3d m = Eigen::Matrix3d::Zero();
  m(0, 0) = a00;
  m(1, 0) = a10;
  m(1, 1) = a11;
  m(2, 0) = a20;
  m(2, 1) = a21;
  m(2, 2) = a22;
  return m;
}

constexpr double kDegToRad = M_PI / 180.0;
constexpr int kWallPieces = 20;  // a wall's length in this many pieces for the seen share
// The rim plane is fitted to band points within this much (m) beyond the
// rim's half width + slack of the consensus outline.
constexpr double kNearRim = 0.006;

// Points of the frame near the rim and near the floor, in the nominal bin
// frame (W0), sampled every `stride` pixels.
struct SampledPoints {
  std::vector<Eigen::Vector3f> band_W0;   // within the band about the rim height, in the search annulus
  std::vector<Eigen::Vector3f> floor_W0;  // within 15 mm of the nominal floor, inside the walls
};

// The bin model's rim seen from above: centre lines of the walls at
// x = +-a (running along y, |y| <= ly) and y = +-b (along x, |x| <= lx).
struct RimModel {
  double a = 0, b = 0;    // centre lines' distances from the centre
  double lx = 0, ly = 0;  // half lengths of the walls (outer corners)
  double half_width = 0;  // half the wall thickness
};

// The wall a point (in the bin frame, 2D) belongs to: its outward normal,
// the signed distance to its centre line (> 0 outward) and the position
// along it in [0, 1].
struct WallHit {
  int wall = 0;  // 0: +x, 1: -x, 2: +y, 3: -y
  double r = 0;
  double along = 0;
};

// The outward normal of wall `wall` (WallHit::wall) in the bin frame.
Eigen::Vector2d WallNormal(int wall) {
  switch (wall) {
    case 0: return {1, 0};
    case 1: return {-1, 0};
    case 2: return {0, 1};
    default: return {0, -1};
  }
}

// Small enough to be inlined into the per-point loops that call it (a call
// per point cost about as many instructions as its body).
inline WallHit NearestWall(const RimModel& rim, const Eigen::Vector2d& m) {
  const double dx = std::abs(m.x()) - rim.a, dy = std::abs(m.y()) - rim.b;
  WallHit h;
  if (std::abs(dx) < std::abs(dy)) {
    h.wall = m.x() >= 0 ? 0 : 1;
    h.r = dx;
    h.along = (m.y() + rim.ly) / (2 * rim.ly);
  } else {
    h.wall = m.y() >= 0 ? 2 : 3;
    h.r = dy;
    h.along = (m.x() + rim.lx) / (2 * rim.lx);
  }
  return h;
}

Eigen::Matrix2d Rot2(double theta) {
  Eigen::Matrix2d R;
  R << std::cos(theta), -std::sin(theta), std::sin(theta), std::cos(theta);
  return R;
}

// The rim's pose in its plane: centre c and yaw theta (the bin's x axis).
struct RimPose {
  Eigen::Vector2d c = Eigen::Vector2d::Zero();
  double theta = 0;
};

// Point-to-line ICP of the rim model against the points q (in the plane's
// 2D frame), Gauss-Newton on (c, theta), from `start`, with the gate on the
// residuals shrinking from `first_gate` to the rim's half width + slack.
RimPose FitRim(const std::vector<Eigen::Vector2d>& q, const RimModel& rim, double first_gate, double slack,
               RimPose pose) {
  const double final_gate = rim.half_width + slack;
  for (int it = 0; it < 30; ++it) {
    const double gate = std::max(final_gate, first_gate * std::pow(0.5, it));
    const Eigen::Matrix2d R = Rot2(pose.theta), Rt = R.transpose();
    // The wall normals turned by the pose, once per iteration.
    const std::array<Eigen::Vector2d, 4> normals = {R * WallNormal(0), R * WallNormal(1), R * WallNormal(2),
                                                     R * WallNormal(3)};
    // JtJ's lower triangle only, in scalars (s_rc: row r, column c): ldlt()
    // reads no other (the upper one is the same products).
    double s00 = 0, s10 = 0, s11 = 0, s20 = 0, s21 = 0, s22 = 0;
    double t0 = 0, t1 = 0, t2 = 0;  // Jtr
    int used = 0;
    for (const Eigen::Vector2d& p : q) {
      const Eigen::Vector2d d = p - pose.c;
      const WallHit h = NearestWall(rim, Rt * d);
      if (std::abs(h.r) > gate || h.along < -0.02 || h.along > 1.02) continue;
      const Eigen::Vector2d& n = normals[static_cast<size_t>(h.wall)];
      const double j0 = -n.x(), j1 = -n.y(), j2 = -n.y() * d.x() + n.x() * d.y();
      s00 += j0 * j0;
      s10 += j1 * j0;
      s11 += j1 * j1;
      s20 += j2 * j0;
      s21 += j2 * j1;
      s22 += j2 * j2;
      t0 += j0 * h.r;
      t1 += j1 * h.r;
      t2 += j2 * h.r;
      ++used;
    }
    if (used < 10) break;
    const Eigen::Matrix3d JtJ = FromLowerTriangle(s00, s10, s11, s20, s21, s22);
    const Eigen::Vector3d Jtr(t0, t1, t2);
    const Eigen::Vector3d delta = JtJ.ldlt().solve(-Jtr);
    if (!delta.allFinite()) break;
    pose.c += delta.head<2>();
    pose.theta += delta.z();
    if (gate <= final_gate && delta.head<2>().norm() < 1e-6 && std::abs(delta.z()) < 1e-6) break;
  }
  return pose;
}

// The rim's yaw period (rad): a rectangular rim looks the same turned by
// 180 deg, a square one by 90 deg.
double YawPeriod(const BinSpec& bin) {
  return std::abs(bin.inner_size.x() - bin.inner_size.y()) < 1e-3 ? M_PI / 2 : M_PI;
}

// The yaw half range the search covers (rad): the window's, at most half
// the period (a window that wide takes any yaw).
double SearchYaw(const BinSpec& bin) {
  return std::min(bin.detect.search_yaw_deg * kDegToRad, YawPeriod(bin) / 2);
}

// How far a rim point may move in the rim's plane turned by up to `yaw`
// (rad) about the centre and shifted by the window's translation (m).
double RimReach(const BinSpec& bin, double yaw) {
  const double corner = std::hypot(bin.inner_size.x() / 2 + bin.wall_thickness,
                                   bin.inner_size.y() / 2 + bin.wall_thickness);
  return bin.detect.search_translation + 2 * corner * std::sin(yaw / 2);
}

SampledPoints SamplePoints(const Frame& frame, const BinSpec& bin, const BinDetectOptions& o) {
  SampledPoints out;
  const Intrinsics& K = frame.intrinsics;
  const Eigen::Affine3f X_W0C = (bin.X_BW.inverse() * frame.X_BC).cast<float>();
  const double X = bin.inner_size.x() / 2, Y = bin.inner_size.y() / 2, H = bin.inner_size.z();
  const double t = bin.wall_thickness;
  // How far the rim may lie from nominal in the plane: the window's
  // translation and its yaw at the outer corners. Whatever the yaw, the rim
  // lies within the outer corners' circle about a centre that moved at most
  // sqrt(2) x translation (15 mm of slack: tilt), and everything inside the
  // inner walls' inscribed circle about it is inside the bin.
  const double reach = RimReach(bin, SearchYaw(bin)) + 0.005;
  const double shift = std::sqrt(2.0) * bin.detect.search_translation;
  const float outer_x = static_cast<float>(X + t + reach), outer_y = static_cast<float>(Y + t + reach);
  const float inner_x = static_cast<float>(X - reach), inner_y = static_cast<float>(Y - reach);
  const float floor_x = static_cast<float>(X - reach), floor_y = static_cast<float>(Y - reach);
  const float outer_r = static_cast<float>(std::hypot(X + t, Y + t) + shift + 0.015);
  const float inner_r = static_cast<float>(std::max(0.0, std::min(X, Y) - shift - 0.005));
  const float outer_r2 = outer_r * outer_r, inner_r2 = inner_r * inner_r;
  const float rim_z = static_cast<float>(H), band = static_cast<float>(o.band);
  // Pixel footprint at the nominal rim centre's depth sets the stride.
  const Eigen::Vector3d rim_C = (frame.X_BC.inverse() * bin.X_BW) * Eigen::Vector3d(0, 0, H);
  const double footprint = rim_C.z() > 0 ? rim_C.z() / K.fx : 0.0;
  const int stride = footprint > 0 ? std::max(1, static_cast<int>(o.sample_spacing / footprint)) : 1;
  const Eigen::Matrix3f R = X_W0C.linear();
  const Eigen::Vector3f T = X_W0C.translation();
  const float fy_inv = static_cast<float>(1.0 / K.fy), cy = static_cast<float>(K.cy);
  // x / z of each sampled column and its product with R(2, 0), once per frame.
  std::vector<float> ray_x, ray_zx;
  for (int u = 0; u < K.width; u += stride) ray_x.push_back(static_cast<float>((u - K.cx) / K.fx));
  for (const float rx : ray_x) ray_zx.push_back(R(2, 0) * rx);
  const size_t columns = ray_x.size();
  // The floor check needs far fewer points: every fourth sampled row and column.
  constexpr size_t kFloorEvery = 4;
  // The sampled pixels of a row in blocks of kBlock: one branch-free look at
  // a block's heights (the compiler vectorizes it) finds most blocks without
  // a pixel in the band (the bin's inside, the floor around it), whose
  // pixels can then only be kept on the floor's columns.
  constexpr size_t kBlock = 32;
  static_assert(kBlock % kFloorEvery == 0, "a block starts on a floor column");
  std::vector<float> sampled_row(stride > 1 ? columns : 0);
  for (int v = 0, row_index = 0; v < K.height; v += stride, ++row_index) {
    const float* row = &frame.depth.data[static_cast<size_t>(v) * K.width];
    if (stride > 1) {
      for (size_t i = 0; i < columns; ++i) sampled_row[i] = row[i * static_cast<size_t>(stride)];
      row = sampled_row.data();
    }
    const float ry = (static_cast<float>(v) - cy) * fy_inv;
    // p = z * (R * (rx, ry, 1)) + T: the row's part of R * ray once.
    const Eigen::Vector3f row_part = R.col(1) * ry + R.col(2);
    const float row_z = row_part.z(), T_z = T.z();
    const bool floor_row = row_index % kFloorEvery == 0;
    const auto visit = [&](size_t i) {
      const float z = row[i];
      if (!(z > 0.0f)) return;  // NaN and non-positive: no measurement
      // Height first: most pixels (the bin's inside) fail the band test.
      const float pz = z * (ray_zx[i] + row_z) + T_z;
      const bool in_band = std::abs(pz - rim_z) < band;
      const bool on_floor = floor_row && i % kFloorEvery == 0 && std::abs(pz) < 0.015f;
      if (!in_band && !on_floor) return;
      const Eigen::Vector3f p(z * (R(0, 0) * ray_x[i] + row_part.x()) + T.x(),
                              z * (R(1, 0) * ray_x[i] + row_part.y()) + T.y(), pz);
      const float ax = std::abs(p.x()), ay = std::abs(p.y()), r2 = ax * ax + ay * ay;
      const bool inside = (ax < inner_x && ay < inner_y) || r2 < inner_r2;
      if (in_band) {
        if (ax < outer_x && ay < outer_y && r2 < outer_r2 && !inside) out.band_W0.push_back(p);
      } else if ((ax < floor_x && ay < floor_y) || r2 < inner_r2) {
        out.floor_W0.push_back(p);
      }
    };
    for (size_t i = 0; i < columns; i += kBlock) {
      const size_t end = std::min(columns, i + kBlock);
      // Every pixel of a block with one in the band (or of the row's last,
      // partial block), else the floor's columns on a floor row, else none.
      size_t step = 1;
      if (end - i == kBlock) {
        int in_band = 0;
        for (size_t k = 0; k < kBlock; ++k) {
          const float z = row[i + k];
          const float pz = z * (ray_zx[i + k] + row_z) + T_z;
          in_band += static_cast<int>((z > 0.0f) & (std::abs(pz - rim_z) < band));
        }
        if (in_band == 0) {
          if (!floor_row) continue;
          step = kFloorEvery;
        }
      }
      for (size_t k = i; k < end; k += step) visit(k);
    }
  }
  return out;
}

// The rim plane (n . x + d = 0, n.z > 0) by RANSAC over at most
// max_points of the band points; false when none is found.
bool FitRimPlane(const std::vector<Eigen::Vector3f>& band, const BinDetectOptions& o, Eigen::Vector3d* n,
                 double* d) {
  pcl::PointCloud<pcl::PointXYZ>::Ptr cloud(new pcl::PointCloud<pcl::PointXYZ>);
  const size_t step = std::max<size_t>(1, band.size() / static_cast<size_t>(std::max(1, o.plane_max_points)));
  for (size_t i = 0; i < band.size(); i += step) cloud->push_back(pcl::PointXYZ(band[i].x(), band[i].y(), band[i].z()));
  // Both seed their generators with a fixed value (random = false): reproducible.
  auto model = std::make_shared<pcl::SampleConsensusModelPerpendicularPlane<pcl::PointXYZ>>(cloud);
  model->setAxis(Eigen::Vector3f::UnitZ());
  model->setEpsAngle(5.0 * kDegToRad);
  pcl::RandomSampleConsensus<pcl::PointXYZ> ransac(model, o.plane_distance);
  ransac.setMaxIterations(o.plane_iterations);
  if (!ransac.computeModel()) return false;
  pcl::Indices inliers;
  ransac.getInliers(inliers);
  Eigen::VectorXf coefficients;
  ransac.getModelCoefficients(coefficients);
  if (inliers.size() < 30 || coefficients.size() != 4) return false;
  Eigen::Vector3d normal(coefficients[0], coefficients[1], coefficients[2]);
  double offset = coefficients[3];
  const double norm = normal.norm();
  if (!(norm > 0)) return false;
  normal /= norm;
  offset /= norm;
  if (normal.z() < 0) {
    normal = -normal;
    offset = -offset;
  }
  *n = normal;
  *d = offset;
  return true;
}

// Least-squares plane through `points`: unit normal with n.z > 0 (in the
// frame of the points) and offset; false for fewer than 3 points.
bool FitPlane(const std::vector<Eigen::Vector3d>& points, Eigen::Vector3d* n, double* d) {
  if (points.size() < 3) return false;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  // The covariance's lower triangle only, in scalars (c_rc: row r, column
  // c): the solver reads no other.
  double c00 = 0, c10 = 0, c11 = 0, c20 = 0, c21 = 0, c22 = 0;
  for (const auto& p : points) {
    const Eigen::Vector3d q = p - mean;
    c00 += q(0) * q(0);
    c10 += q(1) * q(0);
    c11 += q(1) * q(1);
    c20 += q(2) * q(0);
    c21 += q(2) * q(1);
    c22 += q(2) * q(2);
  }
  const Eigen::Matrix3d cov = FromLowerTriangle(c00, c10, c11, c20, c21, c22);
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  Eigen::Vector3d normal = eig.eigenvectors().col(0);
  if (normal.z() < 0) normal = -normal;
  *n = normal;
  *d = -normal.dot(mean);
  return true;
}

// The least-squares plane of the rim points, fitted again twice on the
// points within 3 robust sigmas (1.4826 x the median residual, at least
// 0.3 mm) of the last fit: points on the walls' inner faces just below the
// rim (seen along its inner edge) drop out. *inliers: the points of the last
// fit; *gate: its distance bound (m). False for fewer than 3 points.
bool FitRimPlaneTight(const std::vector<Eigen::Vector3d>& points, Eigen::Vector3d* n, double* d,
                      std::vector<Eigen::Vector3d>* inliers, double* gate_out) {
  if (!FitPlane(points, n, d)) return false;
  std::vector<double> r(points.size()), sorted;
  for (int round = 0; round < 2; ++round) {
    for (size_t i = 0; i < points.size(); ++i) r[i] = std::abs(n->dot(points[i]) + *d);
    sorted = r;
    std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(sorted.size() / 2), sorted.end());
    const double gate = std::max(3.0 * 1.4826 * sorted[sorted.size() / 2], 0.0003);
    *gate_out = gate;
    inliers->clear();
    inliers->reserve(points.size());
    for (size_t i = 0; i < points.size(); ++i) {
      if (r[i] <= gate) inliers->push_back(points[i]);
    }
    if (!FitPlane(*inliers, n, d)) return false;
  }
  return true;
}

// Every k-th of `points` (in their order), k the least keeping at most
// max_points of them.
template <typename T>
std::vector<T> EvenSubsample(const std::vector<T>& points, int max_points) {
  const size_t cap = static_cast<size_t>(std::max(1, max_points));
  if (points.size() <= cap) return points;
  const size_t step = (points.size() + cap - 1) / cap;
  std::vector<T> out;
  out.reserve(points.size() / step + 1);
  for (size_t i = 0; i < points.size(); i += step) out.push_back(points[i]);
  return out;
}

// The consensus pose: the yaw and centre over a grid of the search window
// whose rim explains the most of the points q (2D, in the nominal bin
// frame's xy or the rim plane's frame: a tilt of a few degrees shrinks the
// rim's outline by under 0.1%), counted per axis. For each yaw in [lo, hi]
// (every `step`, rad) the points, turned into the rim's frame, fall into
// 1 mm histograms of x and y; the walls along y lie at x = c_x +- a, so the
// best c_x is the shift whose two windows (the rim's half width + slack
// about each line) hold the most points (prefix sums), and c_y likewise.
// A full pile's points in the height band scatter over the histograms
// while a wall's rim piles up in one window, so the pile cannot pull this
// pose inward the way it pulls an ICP whose first gate is the window's
// reach, or tilt a plane fitted to the whole band. Cost: yaws x points.
// The centre comes back to within a histogram bin, the yaw half a step.
RimPose ConsensusRimPose(const std::vector<Eigen::Vector2d>& q, const RimModel& rim, const BinSpec& bin,
                         const BinDetectOptions& o, double lo, double hi, double step) {
  constexpr double kBin = 0.001;  // histogram bin, m
  // The centre's reach in the rim's frame: the window's translation on both
  // axes and 15 mm of tilt.
  const double shift = std::sqrt(2.0) * bin.detect.search_translation + 0.015;
  const int shift_bins = static_cast<int>(std::ceil(shift / kBin));
  const double w = rim.half_width + o.rim_slack;
  const int w_bins = std::max(1, static_cast<int>(std::lround(w / kBin)));
  const double half_x = rim.a + shift + w, half_y = rim.b + shift + w;
  const int nx = static_cast<int>(std::ceil(2 * half_x / kBin)) + 1;
  const int ny = static_cast<int>(std::ceil(2 * half_y / kBin)) + 1;
  std::vector<int> hx(static_cast<size_t>(nx) + 1), hy(static_cast<size_t>(ny) + 1);
  // The most points in the two windows about shift +- line over shifts
  // within +-shift_bins; *best_shift in m. h: prefix sums (h[k]: points in
  // bins < k), half: the histogram's half range, line: a or b.
  const auto best_in = [&](const std::vector<int>& h, double half, double line, double* best_shift) {
    const int n = static_cast<int>(h.size()) - 1;
    const auto count = [&](int first, int last) {  // bins [first, last]
      first = std::clamp(first, 0, n);
      last = std::clamp(last + 1, 0, n);
      return last > first ? h[last] - h[first] : 0;
    };
    const int centre = static_cast<int>(std::lround(half / kBin));
    const int line_bins = static_cast<int>(std::lround(line / kBin));
    // The shifts whose two windows lie inside the histogram need no clamps
    // (the same counts): the lower window's first bin >= 0, the upper one's
    // last bin < n.
    const int unclamped_lo = w_bins + line_bins - centre, unclamped_hi = n - 1 - w_bins - line_bins - centre;
    const int* hp = h.data();
    int best = -1;
    for (int s = -shift_bins; s <= shift_bins; ++s) {
      const int plus = centre + s + line_bins, minus = centre + s - line_bins;
      const int c = s >= unclamped_lo && s <= unclamped_hi
                        ? (hp[plus + w_bins + 1] - hp[plus - w_bins]) + (hp[minus + w_bins + 1] - hp[minus - w_bins])
                        : count(plus - w_bins, plus + w_bins) + count(minus - w_bins, minus + w_bins);
      if (c > best) {
        best = c;
        *best_shift = (s + 0.5) * kBin;  // within half a bin of the windows' centre
      }
    }
    return best;
  };
  const int steps = std::max(0, static_cast<int>(std::floor((hi - lo) / step + 1e-9)));
  RimPose best;
  int best_count = -1;
  for (int k = 0; k <= steps; ++k) {
    const double theta = lo + k * step;
    const double c = std::cos(theta), s = std::sin(theta);
    std::fill(hx.begin(), hx.end(), 0);
    std::fill(hy.begin(), hy.end(), 0);
    for (const Eigen::Vector2d& p : q) {
      const double mx = c * p.x() + s * p.y(), my = -s * p.x() + c * p.y();  // R(theta)^T p
      // The bins' positions; a position in [0, n) truncates to its floor.
      const double tx = (mx + half_x) / kBin, ty = (my + half_y) / kBin;
      // A point counts for the walls along y when it lies within their
      // length (and likewise for x).
      if (tx >= 0 && tx < nx && std::abs(my) < rim.ly + shift) ++hx[static_cast<size_t>(tx) + 1];
      if (ty >= 0 && ty < ny && std::abs(mx) < rim.lx + shift) ++hy[static_cast<size_t>(ty) + 1];
    }
    for (size_t i = 1; i < hx.size(); ++i) hx[i] += hx[i - 1];
    for (size_t i = 1; i < hy.size(); ++i) hy[i] += hy[i - 1];
    double sx = 0, sy = 0;
    const int count = best_in(hx, half_x, rim.a, &sx) + best_in(hy, half_y, rim.b, &sy);
    if (count > best_count) {
      best_count = count;
      best.theta = theta;
      best.c = Rot2(theta) * Eigen::Vector2d(sx, sy);
    }
  }
  return best;
}

// The rim's pose in the nominal bin frame's xy from the band's points
// anywhere in the search window: the consensus pose every 2 deg across the
// window's yaw range on a quarter of fit_max_points of them (fewer for a
// wide window, below), then every
// 0.5 deg within 2 deg of the best on half (a wall's ends move 4.4 mm per
// degree of yaw error on the default bin, within the 8 mm half window at a
// coarse step's worst 1 deg). The yaw comes back within half the rim's
// period.
RimPose StartRimPose(const std::vector<Eigen::Vector2d>& band_xy, const RimModel& rim, const BinSpec& bin,
                     const BinDetectOptions& o) {
  constexpr double kFine = 0.5 * kDegToRad, kCoarse = 2.0 * kDegToRad;
  const double yaw = SearchYaw(bin), period = YawPeriod(bin);
  // A window of any yaw stops short of +period / 2 (the same rim as
  // -period / 2).
  const double hi = yaw >= period / 2 - 1e-9 ? yaw - 0.5 * kCoarse : yaw;
  const double step = std::min(kCoarse, 2 * yaw);
  // At most kCoarseWork point-yaws: the default window's 11 yaws take their
  // 1000 points, a window of any yaw (90 yaws of a rectangular rim) half of
  // them; the finer pass below looks again on 2000.
  constexpr double kCoarseWork = 45000;
  const int yaws = static_cast<int>(std::floor((hi + yaw) / step + 1e-9)) + 1;
  const int coarse_points = std::min(o.fit_max_points / 4, static_cast<int>(kCoarseWork / yaws));
  const RimPose coarse = ConsensusRimPose(EvenSubsample(band_xy, coarse_points), rim, bin, o, -yaw, hi, step);
  RimPose pose = ConsensusRimPose(EvenSubsample(band_xy, o.fit_max_points / 2), rim, bin, o,
                                  coarse.theta - kCoarse, coarse.theta + kCoarse, kFine);
  pose.theta = std::remainder(pose.theta, period);
  return pose;
}

// A 2D frame in the plane (n, d): origin under (0, 0, H) of W0, x along W0's
// x projected into the plane.
struct PlaneFrame {
  Eigen::Vector3d origin, ex, ey, n;
  Eigen::Vector2d To2D(const Eigen::Vector3d& p) const { return {(p - origin).dot(ex), (p - origin).dot(ey)}; }
};

PlaneFrame MakePlaneFrame(const Eigen::Vector3d& n, double d, double H) {
  PlaneFrame f;
  f.n = n;
  const Eigen::Vector3d above(0, 0, H);
  f.origin = above - (n.dot(above) + d) * n;
  f.ex = (Eigen::Vector3d::UnitX() - n.x() * n).normalized();
  f.ey = n.cross(f.ex);
  return f;
}

// The band points near the rim's outline at the consensus start pose
// (seen from above): a full pile's points in the band outnumber the rim's
// and tilt a plane fitted to the whole band. Sets *start.
std::vector<Eigen::Vector3f> BandPointsNearRim(const SampledPoints& sampled, const RimModel& rim,
                                               const BinSpec& bin, const BinDetectOptions& o, RimPose* start) {
  const std::vector<Eigen::Vector3f> band_sub = EvenSubsample(sampled.band_W0, o.fit_max_points);
  std::vector<Eigen::Vector2d> band_xy;
  band_xy.reserve(band_sub.size());
  for (const Eigen::Vector3f& p : band_sub) band_xy.emplace_back(p.x(), p.y());
  *start = StartRimPose(band_xy, rim, bin, o);
  std::vector<Eigen::Vector3f> near_rim;
  const Eigen::Matrix2d Rt0 = Rot2(start->theta).transpose();
  for (size_t i = 0; i < band_xy.size(); ++i) {
    const WallHit h = NearestWall(rim, Rt0 * (band_xy[i] - start->c));
    if (std::abs(h.r) <= rim.half_width + o.rim_slack + kNearRim && h.along >= -0.02 && h.along <= 1.02) {
      near_rim.push_back(band_sub[i]);
    }
  }
  return near_rim;
}

// What a rim pose explains on the plane: the points on the rim, the least
// seen share of a wall's length (0-1, over kWallPieces pieces with >= 3
// points each), and the points just inside the rim (a surface continuing
// inward at its height: a lid, a flat part on top, not a bin).
struct RimCoverage {
  std::vector<Eigen::Vector3d> rim_points;  // in W0
  double least_seen = 1.0;
  int inward = 0;
};

RimCoverage MeasureRimCoverage(const std::vector<Eigen::Vector2d>& q, const std::vector<Eigen::Vector3d>& on_plane,
                               const RimModel& rim, const RimPose& pose, const BinDetectOptions& o) {
  RimCoverage cov;
  const Eigen::Matrix2d Rt = Rot2(pose.theta).transpose();
  std::array<std::array<int, kWallPieces>, 4> pieces{};
  // Written by index, then cut to size (a push_back per point was a call).
  cov.rim_points.resize(q.size());
  size_t kept = 0;
  for (size_t i = 0; i < q.size(); ++i) {
    const WallHit h = NearestWall(rim, Rt * (q[i] - pose.c));
    if (h.along < 0 || h.along > 1) continue;
    if (std::abs(h.r) <= rim.half_width + o.rim_slack) {
      ++pieces[h.wall][std::min(kWallPieces - 1, static_cast<int>(h.along * kWallPieces))];
      cov.rim_points[kept++] = on_plane[i];
    } else if (h.r < -(rim.half_width + 0.006) && h.r > -(rim.half_width + 0.020)) {
      ++cov.inward;
    }
  }
  cov.rim_points.resize(kept);
  for (const auto& wall : pieces) {
    const int seen = static_cast<int>(std::count_if(wall.begin(), wall.end(), [](int c) { return c >= 3; }));
    cov.least_seen = std::min(cov.least_seen, static_cast<double>(seen) / kWallPieces);
  }
  return cov;
}

// The rim plane again over the rim points alone (tightened to their noise;
// a subsample is plenty for a plane), and the rim's pose in it again on
// every rim point within the plane's gate: the points spread across the
// wall's width, so the pose's noise is that width over the square root of
// their number (12 mm / sqrt(12 x 1000) ~ 0.1 mm at 4000). Leaves
// everything as it was when the tight plane cannot be fitted.
void RefitOnRimPoints(const RimModel& rim, const BinSpec& bin, const BinDetectOptions& o, Eigen::Vector3d* n,
                      double* d, PlaneFrame* plane, RimPose* pose, std::vector<Eigen::Vector3d>* rim_points) {
  std::vector<Eigen::Vector3d> tight;
  double gate = 0;
  if (!FitRimPlaneTight(EvenSubsample(*rim_points, o.fit_max_points), n, d, &tight, &gate)) return;
  // Written by index, then cut to size (a push_back per point was a call).
  tight.resize(rim_points->size());
  size_t kept = 0;
  for (const Eigen::Vector3d& p : *rim_points) {
    if (std::abs(n->dot(p) + *d) <= gate) tight[kept++] = p;
  }
  tight.resize(kept);
  const PlaneFrame refined = MakePlaneFrame(*n, *d, bin.inner_size.z());
  std::vector<Eigen::Vector2d> q_tight(tight.size());
  for (size_t i = 0; i < tight.size(); ++i) q_tight[i] = refined.To2D(tight[i]);
  // The pose so far, in the refined plane's 2D frame.
  const Eigen::Vector3d c_3d = plane->origin + pose->c.x() * plane->ex + pose->c.y() * plane->ey;
  const Eigen::Vector3d x_3d = std::cos(pose->theta) * plane->ex + std::sin(pose->theta) * plane->ey;
  RimPose start;
  start.c = refined.To2D(c_3d);
  start.theta = std::atan2(x_3d.dot(refined.ey), x_3d.dot(refined.ex));
  *pose = FitRim(q_tight, rim, rim.half_width + o.rim_slack, o.rim_slack, start);
  pose->theta = std::remainder(pose->theta, YawPeriod(bin));
  *plane = refined;
  *rim_points = std::move(tight);
}

// The measured bin frame in W0: z the rim's normal, x the fitted yaw, the
// origin the inner height H below the rim's centre.
Pose BinFrameFromRim(const PlaneFrame& plane, const RimPose& pose, const Eigen::Vector3d& n, double d, double H) {
  const Eigen::Vector3d centre_on_rim = plane.origin + pose.c.x() * plane.ex + pose.c.y() * plane.ey;
  const Eigen::Vector3d rim_centre = centre_on_rim - (n.dot(centre_on_rim) + d) * n;
  const Eigen::Vector3d x_dir = std::cos(pose.theta) * plane.ex + std::sin(pose.theta) * plane.ey;
  const Eigen::Vector3d ex = (x_dir - x_dir.dot(n) * n).normalized();
  Pose X_W0W = Pose::Identity();
  X_W0W.linear().col(0) = ex;
  X_W0W.linear().col(1) = n.cross(ex);
  X_W0W.linear().col(2) = n;
  X_W0W.translation() = rim_centre - H * n;
  return X_W0W;
}

}  // namespace

BinDetection DetectBin(const Frame& frame, const BinSpec& bin, const BinDetectOptions& o) {
  const auto started = std::chrono::steady_clock::now();
  BinDetection det;
  det.X_BW = bin.X_BW;
  const auto finish = [&](std::string reason) {
    det.reason = std::move(reason);
    det.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - started).count();
    return det;
  };
  if (!frame.organized()) return finish("bin detection needs an organized frame");
  if (!frame.X_BC.matrix().allFinite()) return finish("the frame has no valid camera pose");

  const double H = bin.inner_size.z(), t = bin.wall_thickness;
  const double X = bin.inner_size.x() / 2, Y = bin.inner_size.y() / 2;
  const SampledPoints sampled = SamplePoints(frame, bin, o);
  if (sampled.band_W0.size() < 50) {
    return finish("no rim: " + std::to_string(sampled.band_W0.size()) +
                  " points near the rim's height within the search window");
  }
  RimModel rim;
  rim.half_width = t / 2;
  rim.a = X + t / 2;
  rim.b = Y + t / 2;
  rim.lx = X + t;
  rim.ly = Y + t;
  // Where the rim lies seen from above, then its plane on the band points
  // near that outline only.
  RimPose start;
  const std::vector<Eigen::Vector3f> near_rim = BandPointsNearRim(sampled, rim, bin, o, &start);
  Eigen::Vector3d n;
  double d = 0;
  if (near_rim.size() < 50 || !FitRimPlane(near_rim, o, &n, &d)) {
    return finish("no rim: no plane near the rim's height");
  }

  // The rim candidates: band points on the plane, in its 2D frame.
  PlaneFrame plane = MakePlaneFrame(n, d, H);
  // Written by index, then cut to size (a push_back per point was a call).
  std::vector<Eigen::Vector2d> q(sampled.band_W0.size());
  std::vector<Eigen::Vector3d> on_plane(sampled.band_W0.size());
  size_t kept = 0;
  for (const Eigen::Vector3f& pf : sampled.band_W0) {
    const Eigen::Vector3d p = pf.cast<double>();
    if (std::abs(n.dot(p) + d) > o.plane_distance) continue;
    q[kept] = plane.To2D(p);
    on_plane[kept++] = p;
  }
  q.resize(kept);
  on_plane.resize(kept);
  // ICP from the start, its gate 10 mm beyond the rim's half width + slack
  // (the start lies within a histogram bin and a quarter yaw step).
  RimPose start_in_plane = start;
  start_in_plane.c = plane.To2D(Eigen::Vector3d(start.c.x(), start.c.y(), H));
  RimPose pose = FitRim(EvenSubsample(q, o.fit_max_points), rim, rim.half_width + o.rim_slack + 0.01, o.rim_slack,
                        start_in_plane);
  pose.theta = std::remainder(pose.theta, YawPeriod(bin));

  RimCoverage cov = MeasureRimCoverage(q, on_plane, rim, pose, o);
  det.rim_points = static_cast<int>(cov.rim_points.size());
  det.rim_seen = cov.least_seen;
  if (cov.least_seen < o.min_wall_seen) {
    return finish("no rim: a wall's rim is seen along " + std::to_string(static_cast<int>(100 * cov.least_seen)) +
                  "% of its length (needs " + std::to_string(static_cast<int>(100 * o.min_wall_seen)) + "%)");
  }
  if (cov.inward > o.max_inward_share * static_cast<double>(cov.rim_points.size())) {
    return finish("no rim: a surface continues inward at the rim's height (" + std::to_string(cov.inward) +
                  " points inside the rim on its plane, " + std::to_string(cov.rim_points.size()) + " on the rim)");
  }
  std::vector<Eigen::Vector3d>& rim_points = cov.rim_points;
  RefitOnRimPoints(rim, bin, o, &n, &d, &plane, &pose, &rim_points);
  double sq = 0;
  for (const auto& p : rim_points) sq += std::pow(n.dot(p) + d, 2);
  det.rim_rms = std::sqrt(sq / std::max<size_t>(1, rim_points.size()));

  const Pose X_W0W = BinFrameFromRim(plane, pose, n, d, H);
  // The window is a square in the nominal floor plane (the floor centre's x
  // and y each within +-search_translation) and a yaw range, with 5 mm /
  // 0.5 deg of slack. It is judged on the floor centre, not the rim's: a bin
  // tilted by a few degrees about its floor moves its rim H * sin(tilt)
  // sideways (7 mm at 2 deg for the default cell's 200 mm deep bin) while its
  // floor stays put.
  const Eigen::Vector2d floor_offset = X_W0W.translation().head<2>();
  if (floor_offset.cwiseAbs().maxCoeff() > bin.detect.search_translation + 0.005 ||
      (SearchYaw(bin) < YawPeriod(bin) / 2 && std::abs(pose.theta) > SearchYaw(bin) + 0.5 * kDegToRad)) {
    char why[192];
    std::snprintf(why, sizeof(why),
                  "the bin's floor fitted (%.1f, %.1f) mm / %.1f deg from nominal, outside the search window",
                  1e3 * floor_offset.x(), 1e3 * floor_offset.y(), pose.theta / kDegToRad);
    return finish(why);
  }
  det.found = true;
  det.X_BW = bin.X_BW * X_W0W;
  det.offset = X_W0W.translation().norm();
  det.offset_deg = Eigen::AngleAxisd(X_W0W.linear()).angle() / kDegToRad;
  det.warn = det.offset > bin.detect.warn_offset || det.offset_deg > bin.detect.warn_offset_deg;

  // The floor where it shows, against the measured bin.
  const Pose X_WW0 = X_W0W.inverse();
  double floor_sum = 0;
  for (const Eigen::Vector3f& p : sampled.floor_W0) {
    const double z = (X_WW0 * p.cast<double>()).z();
    if (std::abs(z) > 0.01) continue;
    floor_sum += z;
    ++det.floor_points;
  }
  if (det.floor_points > 0) det.floor_height = floor_sum / det.floor_points;
  return finish("");
}

}  // namespace bp
