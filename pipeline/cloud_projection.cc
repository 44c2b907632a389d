#include "pipeline/cloud_projection.h"

#include <algorithm>
#include <cassert>
#include <cmath>
#include <cstdio>
#include <limits>
#include <optional>
#include <random>
#include <vector>

#include <Eigen/Geometry>

namespace bp {
namespace {

// A camera looks down into the bin when its optical axis is within this angle
// of the bin's -z (binpick's cells tilt cameras up to ~45 deg; a cloud whose
// X_BC looks sideways or up was not seen from there, e.g. a merged cloud in
// the base frame with X_BC = identity).
constexpr double kMaxViewTiltDeg = 75.0;
// The assumed view's height above the bin floor when the cell's camera is not
// above the bin, metres.
constexpr double kDefaultViewHeight = 1.0;
// The assumed view stays at least this far above the highest point, metres.
constexpr double kViewClearance = 0.1;
// Points closer to V than this along its axis are dropped, metres.
constexpr double kMinDepth = 1e-3;
// Points more than atan(10) = 84.3 deg off V's axis are dropped (no pinhole
// images them; binpick's cameras see up to about 40 deg off axis). Bounded
// tangents keep every pixel coordinate exact to 1e-5 px: a point at tangent
// 1e33 put its pixel's rounding error beyond the grid (fuzz/pcd_fuzz).
constexpr double kMaxTangent = 10.0;
// Lattice recovery: random sample of the points (seeded), its smallest
// number of columns for a lattice, and the smallest ratio between the gaps
// of one column's values and those between columns (SameColumnGap).
constexpr size_t kLatticeSample = 50000;
constexpr size_t kMinLatticeColumns = 8;
constexpr double kColumnGapRatio = 20.0;
// The pitch without a lattice: nearest-neighbour distances of this many
// sampled points (CloudProjectionOptions::spacing_quantile).
constexpr size_t kSpacingQueries = 4000;
// The pitch is coarsened by steps of kCoarsenStep, at most kMaxCoarsenSteps
// times (x 21.7), while its grid leaves holes (Coverage): more than
// kMaxHoleFraction one-pixel holes or less than kMinFill of the blocks
// holding points filled. A camera's own depth image of a pile has 5% holes
// (its dropouts) and fills 0.85 to 0.95 of its blocks (edges, dropouts); a
// pitch below the sampling's leaves 20% holes and more, or fills a third.
constexpr double kMaxHoleFraction = 0.12;
constexpr double kMinFill = 0.7;
constexpr int kFillBlock = 4;
constexpr double kCoarsenStep = 1.08;
constexpr int kMaxCoarsenSteps = 40;
// The grid from the point spacing has at most this many pixels per point.
constexpr double kMaxPixelsPerPoint = 16.0;
// Two pixels two apart are on one surface when their depths differ by less
// than this fraction of their depth (1 cm at 1 m).
constexpr float kHoleDepthStep = 0.01f;

// A point's tangent coordinates in V (a = x/z, b = y/z) and depth.
struct RayPoint {
  double a, b;
  float z;
};

// One axis of a lattice: coordinate = origin + pitch * k, k integer.
struct Axis {
  double pitch = 0.0, origin = 0.0;
};

// Above the bin's centre looking down -z of W, at the cell camera's height
// (else kDefaultViewHeight), raised to kViewClearance above the highest point.
Pose ViewFromAboveBin(const Cell& cell, const Frame& cloud) {
  const Pose X_WC = cell.bin.X_BW.inverse() * cloud.X_BC;
  double height = X_WC.translation().z();
  if (!(height > cell.roi.height + kViewClearance)) height = kDefaultViewHeight;
  const Eigen::Matrix3f R_WC = X_WC.linear().cast<float>();
  const Eigen::Vector3f t_WC = X_WC.translation().cast<float>();
  for (const Eigen::Vector3f& p_C : cloud.points_C) {
    if (p_C.allFinite()) height = std::max(height, static_cast<double>((R_WC * p_C + t_WC).z()) + kViewClearance);
  }
  Mat3 R_WV;
  R_WV << 1, 0, 0, 0, -1, 0, 0, 0, -1;  // x along the bin's x, looking down -z
  return cell.bin.X_BW * MakePose(R_WV, Vec3(0.0, 0.0, height));
}

bool LooksIntoBin(const Pose& X_BC, const Cell& cell) {
  const Vec3 axis_W = cell.bin.X_BW.linear().transpose() * X_BC.linear().col(2);
  return -axis_W.z() >= std::cos(kMaxViewTiltDeg * M_PI / 180.0);
}

std::vector<RayPoint> ToRays(const Frame& cloud, const Pose& X_VC) {
  const Eigen::Matrix3f R = X_VC.linear().cast<float>();
  const Eigen::Vector3f t = X_VC.translation().cast<float>();
  const bool same = X_VC.matrix().isIdentity(0.0);  // V = C: the points as stored, not rounded again
  std::vector<RayPoint> rays;
  rays.reserve(cloud.points_C.size());
  for (const Eigen::Vector3f& p_C : cloud.points_C) {
    if (!p_C.allFinite()) continue;
    const Eigen::Vector3f p = same ? p_C : Eigen::Vector3f(R * p_C + t);
    if (!(p.z() > kMinDepth)) continue;
    const RayPoint r{static_cast<double>(p.x()) / p.z(), static_cast<double>(p.y()) / p.z(), p.z()};
    if (std::abs(r.a) > kMaxTangent || std::abs(r.b) > kMaxTangent) continue;
    rays.push_back(r);
  }
  return rays;
}

double Median(std::vector<double> v) {
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

// The gap below which two sorted sampled coordinates are one column: the
// gaps are rounding noise within a column (float x / z, a writer's decimals:
// 1e-7 to 1e-6) and a pitch or more between columns (above 1e-4); the
// threshold sits in the largest ratio between consecutive sorted gaps of
// the upper half, if that ratio is at least kColumnGapRatio. 0 if no ratio
// is that large.
double SameColumnGap(const std::vector<double>& sorted) {
  std::vector<double> gaps;
  gaps.reserve(sorted.size());
  for (size_t i = 0; i + 1 < sorted.size(); ++i) {
    if (sorted[i + 1] > sorted[i]) gaps.push_back(sorted[i + 1] - sorted[i]);
  }
  std::sort(gaps.begin(), gaps.end());
  // The upper half only: with at least two samples per column on average the
  // step is there, and the smallest noise gaps span decades below it.
  double best_ratio = 0.0, threshold = 0.0;
  for (size_t i = gaps.size() / 2; i + 1 < gaps.size(); ++i) {
    const double ratio = gaps[i + 1] / gaps[i];
    if (ratio > best_ratio) {
      best_ratio = ratio;
      threshold = std::sqrt(gaps[i] * gaps[i + 1]);
    }
  }
  return best_ratio >= kColumnGapRatio ? threshold : 0.0;
}

// A regular lattice through the sampled coordinates (sorted in place), or
// nothing: the median gap between columns is the pitch's first guess, every
// gap's multiple of it refines it, and every value must lie within tol_px
// pixels of the lattice.
std::optional<Axis> FitAxis(std::vector<double>& values, double tol_px) {
  std::sort(values.begin(), values.end());
  const double same = SameColumnGap(values);
  std::vector<double> distinct;
  for (double v : values) {
    if (distinct.empty() || v - distinct.back() > same) distinct.push_back(v);
  }
  if (distinct.size() < kMinLatticeColumns) return std::nullopt;
  std::vector<double> gaps(distinct.size() - 1);
  for (size_t i = 0; i + 1 < distinct.size(); ++i) gaps[i] = distinct[i + 1] - distinct[i];
  const double guess = Median(gaps);
  if (!(guess > 0.0)) return std::nullopt;
  double span = 0.0, steps = 0.0;
  for (double g : gaps) {
    if (g < 0.5 * guess) continue;  // one column split by noise SameColumnGap did not catch
    span += g;
    steps += std::round(g / guess);
  }
  Axis axis{span / steps, distinct.front()};
  // Least squares of value = origin + pitch * k over the distinct values.
  double sk = 0, sv = 0, skk = 0, skv = 0;
  const double n = static_cast<double>(distinct.size());
  for (double v : distinct) {
    const double k = std::round((v - axis.origin) / axis.pitch);
    sk += k;
    sv += v;
    skk += k * k;
    skv += k * v;
  }
  const double det = n * skk - sk * sk;
  if (!(det > 0)) return std::nullopt;
  axis.pitch = (n * skv - sk * sv) / det;
  axis.origin = (sv - axis.pitch * sk) / n;
  for (double v : values) {
    const double u = (v - axis.origin) / axis.pitch;
    if (std::abs(u - std::round(u)) > tol_px) return std::nullopt;
  }
  return axis;
}

// The pinhole whose pixel centres every ray goes through, or nothing.
std::optional<Intrinsics> RecoverLattice(const std::vector<RayPoint>& rays, const CloudProjectionOptions& options) {
  std::vector<double> a, b;
  const size_t n = std::min(rays.size(), kLatticeSample);
  a.reserve(n);
  b.reserve(n);
  std::mt19937 rng{1};  // a fixed sample: the same cloud gives the same grid
  std::uniform_int_distribution<size_t> pick(0, rays.size() - 1);
  for (size_t i = 0; i < n; ++i) {
    const RayPoint& r = rays[n == rays.size() ? i : pick(rng)];
    a.push_back(r.a);
    b.push_back(r.b);
  }
  const std::optional<Axis> ax = FitAxis(a, options.lattice_tolerance_px);
  const std::optional<Axis> ay = ax ? FitAxis(b, options.lattice_tolerance_px) : std::nullopt;
  if (!ax || !ay) return std::nullopt;
  // Every point, not only the sample, on the lattice; its extent.
  double k_min[2] = {std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()};
  double k_max[2] = {-k_min[0], -k_min[1]};
  for (const RayPoint& r : rays) {
    const double u = (r.a - ax->origin) / ax->pitch, v = (r.b - ay->origin) / ay->pitch;
    const double ku = std::round(u), kv = std::round(v);
    if (std::abs(u - ku) > options.lattice_tolerance_px || std::abs(v - kv) > options.lattice_tolerance_px) {
      return std::nullopt;
    }
    k_min[0] = std::min(k_min[0], ku);
    k_max[0] = std::max(k_max[0], ku);
    k_min[1] = std::min(k_min[1], kv);
    k_max[1] = std::max(k_max[1], kv);
  }
  const double w = k_max[0] - k_min[0] + 1, h = k_max[1] - k_min[1] + 1;
  if (w * h > static_cast<double>(options.max_pixels)) return std::nullopt;
  // u = a * fx + cx with pixel k_min at column 0.
  Intrinsics K;
  K.width = static_cast<int>(w);
  K.height = static_cast<int>(h);
  K.fx = 1.0 / ax->pitch;
  K.fy = 1.0 / ay->pitch;
  K.cx = -ax->origin / ax->pitch - k_min[0];
  K.cy = -ay->origin / ay->pitch - k_min[1];
  return K;
}

// True if every ray goes through a pixel centre of K inside its image.
bool OnConfigGrid(const std::vector<RayPoint>& rays, const Intrinsics& K, double tol_px) {
  if (!K.valid()) return false;
  for (const RayPoint& r : rays) {
    const double u = r.a * K.fx + K.cx, v = r.b * K.fy + K.cy;
    const double ku = std::round(u), kv = std::round(v);
    if (std::abs(u - ku) > tol_px || std::abs(v - kv) > tol_px) return false;
    if (ku < 0 || kv < 0 || ku >= K.width || kv >= K.height) return false;
  }
  return true;
}

// Bounds of the tangent coordinates.
struct RayBounds {
  double a0 = std::numeric_limits<double>::infinity(), a1 = -std::numeric_limits<double>::infinity();
  double b0 = a0, b1 = a1;
};
RayBounds BoundsOf(const std::vector<RayPoint>& rays) {
  RayBounds r;
  for (const RayPoint& p : rays) {
    r.a0 = std::min(r.a0, p.a);
    r.a1 = std::max(r.a1, p.a);
    r.b0 = std::min(r.b0, p.b);
    r.b1 = std::max(r.b1, p.b);
  }
  return r;
}

// The number of pixels along one axis that holds the largest coordinate
// `hi`: PixelIndex computes its pixel coordinate as hi * f + c, which can
// differ from (hi - lo) / pitch in the last bits. When that lands on a
// half-integer the point would fall off a grid sized from the extent alone
// (found by fuzz/pcd_fuzz: an out-of-range index in NeighbourSpacing).
int PixelsToCover(double hi, double f, double c, double extent_px) {
  const int from_extent = static_cast<int>(std::lround(extent_px)) + 1;
  return std::max(from_extent, static_cast<int>(std::floor(hi * f + c + 0.5)) + 1);
}

// Square pixels of `pitch` (tangent units) covering the bounds, the first
// pixel's centre on the smallest coordinates. Every ray within the bounds has
// a pixel (PixelIndex >= 0).
Intrinsics GridOfPitch(const RayBounds& bounds, double pitch) {
  Intrinsics K;
  K.fx = K.fy = 1.0 / pitch;
  K.cx = -bounds.a0 / pitch;
  K.cy = -bounds.b0 / pitch;
  K.width = PixelsToCover(bounds.a1, K.fx, K.cx, (bounds.a1 - bounds.a0) / pitch);
  K.height = PixelsToCover(bounds.b1, K.fy, K.cy, (bounds.b1 - bounds.b0) / pitch);
  return K;
}

// The pixel whose centre is nearest the ray, -1 off the image.
int PixelIndex(const RayPoint& r, const Intrinsics& K) {
  const double x = r.a * K.fx + K.cx, y = r.b * K.fy + K.cy;
  if (!(x > -0.5 && y > -0.5 && x < K.width - 0.5 && y < K.height - 0.5)) return -1;  // NaN too
  const long u = std::lround(x), v = std::lround(y);
  if (u >= K.width || v >= K.height) return -1;  // x just below width - 0.5 rounds up
  return static_cast<int>(v * K.width + u);
}

// The `quantile` quantile of the distances between a sample of points
// and their nearest neighbours, tangent units: a grid of cells `cell` wide
// (a counting sort of the points), searched 3 x 3 around each query. 0 if no
// query found a neighbour within `cell`.
double NeighbourSpacing(const std::vector<RayPoint>& rays, const RayBounds& bounds, double cell, double quantile) {
  const Intrinsics G = GridOfPitch(bounds, cell);
  const size_t cells = static_cast<size_t>(G.width) * G.height;
  std::vector<int32_t> start(cells + 1, 0);
  std::vector<int32_t> cell_of(rays.size());
  for (size_t i = 0; i < rays.size(); ++i) {
    cell_of[i] = PixelIndex(rays[i], G);
    assert(cell_of[i] >= 0);  // G covers every ray
    ++start[static_cast<size_t>(cell_of[i]) + 1];
  }
  for (size_t c = 0; c < cells; ++c) start[c + 1] += start[c];
  std::vector<int32_t> members(rays.size()), fill(start.begin(), start.end() - 1);
  for (size_t i = 0; i < rays.size(); ++i) {
    members[static_cast<size_t>(fill[static_cast<size_t>(cell_of[i])]++)] = static_cast<int32_t>(i);
  }
  std::vector<double> nearest;
  const size_t step = std::max<size_t>(1, rays.size() / kSpacingQueries);
  for (size_t q = 0; q < rays.size(); q += step) {
    const int c = cell_of[q], cu = c % G.width, cv = c / G.width;
    double best = std::numeric_limits<double>::infinity();
    for (int v = std::max(0, cv - 1); v <= std::min(G.height - 1, cv + 1); ++v) {
      for (int u = std::max(0, cu - 1); u <= std::min(G.width - 1, cu + 1); ++u) {
        const size_t n = static_cast<size_t>(v) * G.width + static_cast<size_t>(u);
        for (int32_t k = start[n]; k < start[n + 1]; ++k) {
          const auto j = static_cast<size_t>(members[static_cast<size_t>(k)]);
          if (j == q) continue;
          best = std::min(best, std::hypot(rays[j].a - rays[q].a, rays[j].b - rays[q].b));
        }
      }
    }
    if (best <= cell) nearest.push_back(best);
  }
  if (nearest.empty()) return 0.0;
  const auto at = nearest.begin() + static_cast<std::ptrdiff_t>(quantile * static_cast<double>(nearest.size() - 1));
  std::nth_element(nearest.begin(), at, nearest.end());
  return *at;
}

// How a pixel grid covers the rays' surfaces. holes: empty pixels between
// two filled neighbours in their row or column whose depths agree within
// kHoleDepthStep of their depth (gaps at depth steps are the shadows of
// nearer surfaces), over filled pixels plus holes. fill: filled pixels over
// the pixels of the kFillBlock x kFillBlock blocks holding any point (wider
// gaps than one pixel, which `holes` does not see).
struct GridCoverage {
  double holes = 0.0;
  double fill = 1.0;
};
GridCoverage Coverage(const std::vector<RayPoint>& rays, const Intrinsics& K) {
  const float kEmpty = std::numeric_limits<float>::infinity();
  std::vector<float> z(static_cast<size_t>(K.width) * K.height, kEmpty);
  for (const RayPoint& r : rays) {
    const int i = PixelIndex(r, K);
    if (i >= 0) z[static_cast<size_t>(i)] = std::min(z[static_cast<size_t>(i)], r.z);
  }
  const auto smooth = [&](size_t p, size_t q) {
    return z[p] != kEmpty && z[q] != kEmpty && std::abs(z[p] - z[q]) <= kHoleDepthStep * std::min(z[p], z[q]);
  };
  const int bw = (K.width + kFillBlock - 1) / kFillBlock, bh = (K.height + kFillBlock - 1) / kFillBlock;
  std::vector<uint8_t> block(static_cast<size_t>(bw) * bh, 0);
  int64_t full = 0, holes = 0;
  const auto W = static_cast<size_t>(K.width);
  for (int v = 0; v < K.height; ++v) {
    for (int u = 0; u < K.width; ++u) {
      const size_t i = static_cast<size_t>(v) * W + static_cast<size_t>(u);
      if (z[i] != kEmpty) {
        ++full;
        block[static_cast<size_t>(v / kFillBlock) * bw + static_cast<size_t>(u / kFillBlock)] = 1;
        continue;
      }
      const bool row = u > 0 && u + 1 < K.width && smooth(i - 1, i + 1);
      const bool col = v > 0 && v + 1 < K.height && smooth(i - W, i + W);
      holes += (row || col) ? 1 : 0;
    }
  }
  int64_t covered = 0;
  for (int bv = 0; bv < bh; ++bv) {
    for (int bu = 0; bu < bw; ++bu) {
      if (!block[static_cast<size_t>(bv) * bw + bu]) continue;
      covered += static_cast<int64_t>(std::min(kFillBlock, K.width - bu * kFillBlock)) *
                 std::min(kFillBlock, K.height - bv * kFillBlock);
    }
  }
  GridCoverage c;
  if (full + holes > 0) c.holes = static_cast<double>(holes) / static_cast<double>(full + holes);
  if (covered > 0) c.fill = static_cast<double>(full) / static_cast<double>(covered);
  return c;
}

bool LeavesHoles(const GridCoverage& c) { return c.holes > kMaxHoleFraction || c.fill < kMinFill; }

// Square pixels as wide as nearly every point's spacing to its nearest
// neighbour, so that a surface sampled by a warped or merged lattice leaves
// no grid holes (holes split the organized path's regions), within
// max_pixels; coarsened while holes are more than kMaxHoleFraction of the
// surfaces (points bunched so that the quantile falls below the sampling's
// pitch, as where several cameras' clouds overlap).
Intrinsics GridFromSpacing(const std::vector<RayPoint>& rays, const CloudProjectionOptions& options) {
  const RayBounds bounds = BoundsOf(rays);
  const double A = bounds.a1 - bounds.a0, B = bounds.b1 - bounds.b0;
  // The smallest pitch p that fits the image (max_pixels, and at most
  // kMaxPixelsPerPoint per point: a finer grid is mostly empty whatever the
  // points): GridOfPitch's width is at most A / p + 1.5, so
  // (A + 1.5 p)(B + 1.5 p) <= M p^2, the larger root.
  const double M = std::max(std::min(static_cast<double>(options.max_pixels),
                                     kMaxPixelsPerPoint * static_cast<double>(rays.size())),
                            64.0) -
                   2.25;
  const double fit = std::max((1.5 * (A + B) + std::sqrt(2.25 * (A + B) * (A + B) + 4.0 * M * A * B)) / (2.0 * M),
                              1e-9);
  // The mean spacing of the points spread over their bounds (at least their
  // nearest-neighbour spacing).
  const double mean = std::max(std::sqrt(A * B / static_cast<double>(rays.size())), fit);
  const double spacing = NeighbourSpacing(rays, bounds, 2.0 * mean, options.spacing_quantile);
  double pitch = std::max(spacing > 0.0 ? options.pitch_margin * spacing : mean, fit);
  Intrinsics K = GridOfPitch(bounds, pitch);
  for (int step = 0; step < kMaxCoarsenSteps && LeavesHoles(Coverage(rays, K)); ++step) {
    pitch *= kCoarsenStep;
    K = GridOfPitch(bounds, pitch);
  }
  return K;
}

}  // namespace

std::string CloudProjection::Describe() const {
  const Intrinsics& K = frame.intrinsics;
  const char* view_text = view == CloudViewSource::kCamera ? "its camera (X_BC)"
                          : view == CloudViewSource::kAboveBinNoPose
                              ? "+z of the bin frame (no X_BC: assumed)"
                              : "+z of the bin frame (X_BC does not look down into the bin)";
  char grid_text[200];
  if (grid == CloudGrid::kCameraConfig) {
    std::snprintf(grid_text, sizeof(grid_text), "the pixel grid of camera config %d", config_id);
  } else if (grid == CloudGrid::kRecovered) {
    std::snprintf(grid_text, sizeof(grid_text), "a pinhole lattice recovered from the points");
  } else {
    std::snprintf(grid_text, sizeof(grid_text),
                  "no pixel lattice: pitch %.3f mrad from the point spacing, points moved up to %.2f px "
                  "to their pixel's ray",
                  1000.0 / K.fx, max_shift_px);
  }
  char buf[512];
  std::snprintf(buf, sizeof(buf),
                "organized through a virtual pinhole seen from %s, %s: %dx%d, fx %.4f fy %.4f cx %.4f cy %.4f; "
                "%lld points, %lld pixels (%lld behind a nearer point)",
                view_text, grid_text, K.width, K.height, K.fx, K.fy, K.cx, K.cy, static_cast<long long>(points),
                static_cast<long long>(pixels), static_cast<long long>(points - pixels));
  return buf;
}

Result<CloudProjection> ProjectCloud(const Frame& cloud, const Cell& cell, bool X_BC_known,
                                     const CloudProjectionOptions& options) {
  if (cloud.organized()) return Status::InvalidArgument("'" + cloud.source + "': the frame is organized already");
  CloudProjection out;
  Pose X_BV = cloud.X_BC;
  if (!X_BC_known) {
    out.view = CloudViewSource::kAboveBinNoPose;
  } else if (!LooksIntoBin(cloud.X_BC, cell)) {
    out.view = CloudViewSource::kAboveBinTilted;
  }
  if (out.view != CloudViewSource::kCamera) X_BV = ViewFromAboveBin(cell, cloud);
  const std::vector<RayPoint> rays = ToRays(cloud, X_BV.inverse() * cloud.X_BC);
  if (rays.empty()) {
    return Status::InvalidArgument("'" + cloud.source +
                                   "': no point in front of the virtual camera within 84.3 deg of its axis");
  }

  Intrinsics K;
  if (const std::optional<Intrinsics> lattice = RecoverLattice(rays, options)) {
    K = *lattice;
    out.grid = CloudGrid::kRecovered;
    for (const CameraConfig& c : cell.camera.configs) {
      if (OnConfigGrid(rays, c.intrinsics, options.lattice_tolerance_px)) {
        K = c.intrinsics;
        K.distortion = {};
        out.grid = CloudGrid::kCameraConfig;
        out.config_id = c.id;
        break;
      }
    }
  } else {
    K = GridFromSpacing(rays, options);
    out.grid = CloudGrid::kFromSpacing;
  }

  Frame& f = out.frame;
  f.intrinsics = K;
  f.depth = DepthImage(K.width, K.height, std::numeric_limits<float>::quiet_NaN());
  f.X_BC = X_BV;
  f.timestamp_ns = cloud.timestamp_ns;
  f.source = cloud.source;
  f.truth = cloud.truth;
  for (const RayPoint& r : rays) {
    const int i = PixelIndex(r, K);
    if (i < 0) continue;
    float& z = f.depth.data[static_cast<size_t>(i)];
    if (!(z <= r.z)) {  // NaN (empty) or farther
      if (std::isnan(z)) ++out.pixels;
      z = r.z;
    }
    const double du = r.a * K.fx + K.cx, dv = r.b * K.fy + K.cy;
    out.max_shift_px = std::max(out.max_shift_px, std::hypot(du - std::round(du), dv - std::round(dv)));
  }
  out.points = static_cast<int64_t>(rays.size());
  return out;
}

}  // namespace bp
