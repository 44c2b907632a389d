#include "pipeline/pose_estimator.h"

#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <functional>
#include <limits>
#include <numeric>
#include <sstream>
#include <tuple>

#include <Eigen/Eigenvalues>

#include "pipeline/frame.h"
#include "pipeline/internal/closest_point_field.h"
#include "pipeline/internal/depth_window.h"
#include "pipeline/internal/model_sampling.h"
#include "pipeline/internal/point_hash.h"
#include "pipeline/internal/point_to_plane_icp.h"
#include "pipeline/internal/ppf_matcher.h"

namespace bp {

using internal::OrientedPoints;

namespace {

using Clock = std::chrono::steady_clock;
double Ms(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

constexpr uint64_t kSamplingSeed = 0x5eed;
constexpr double kDeg = M_PI / 180.0;

// 2D convex hull (Andrew's monotone chain), counter-clockwise.
std::vector<Eigen::Vector2f> ConvexHull2(std::vector<Eigen::Vector2f> p) {
  std::sort(p.begin(), p.end(), [](const Eigen::Vector2f& a, const Eigen::Vector2f& b) {
    return a.x() < b.x() || (a.x() == b.x() && a.y() < b.y());
  });
  if (p.size() < 3) return p;
  auto cross = [](const Eigen::Vector2f& o, const Eigen::Vector2f& a, const Eigen::Vector2f& b) {
    return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
  };
  std::vector<Eigen::Vector2f> h(2 * p.size());
  size_t k = 0;
  for (size_t i = 0; i < p.size(); ++i) {
    while (k >= 2 && cross(h[k - 2], h[k - 1], p[i]) <= 0) --k;
    h[k++] = p[i];
  }
  for (size_t i = p.size() - 1, t = k + 1; i-- > 0;) {
    while (k >= t && cross(h[k - 2], h[k - 1], p[i]) <= 0) --k;
    h[k++] = p[i];
  }
  h.resize(k - 1);
  return h;
}

// An orthonormal basis (u, v) of the plane normal to unit d.
std::pair<Eigen::Vector3f, Eigen::Vector3f> PlaneBasis(const Eigen::Vector3f& d) {
  const Eigen::Vector3f u = d.unitOrthogonal();
  return {u, d.cross(u)};
}

struct RestingPose {
  Eigen::Vector3f down;  // unit, in O, pointing into the floor
  float depth = 0;       // largest down . p over the samples: the contact height
  // Seed anchors (AppendRestingSeeds), over the PPF samples: the centroid of
  // the samples within kRestTopBand of the top, and of the upward faces.
  Eigen::Vector3f top_O = Eigen::Vector3f::Zero();
  Eigen::Vector3f up_O = Eigen::Vector3f::Zero();
};

// The orientations in which the part rests on a flat floor. Candidates are
// the mesh's face normals (merged within 1 deg); one is a resting direction d
// (pointing into the floor) when the samples within `tol` of the lowest in
// that direction span an area whose convex hull holds the projection of the
// centroid (so the part neither tips nor rolls). Directions within 3 deg are
// one, and so are directions a symmetry of the part maps onto each other.
std::vector<RestingPose> RestingPoses(const TriangleMesh& mesh, std::span<const Eigen::Vector3f> pts,
                                      const Eigen::Vector3f& centroid, const Symmetry& symmetry, float tol) {
  // Face normals merged within 1 deg, with their total area, largest first:
  // where directions within 3 deg are one below, the broad face's own normal
  // stands for them, not a facet of a hole wall 2.9 deg off it (which tilted
  // an L-bracket lying on its side by 3 deg).
  std::vector<std::pair<float, Eigen::Vector3f>> by_area;
  const float cos1 = static_cast<float>(std::cos(1 * kDeg));
  for (const Eigen::Vector3i& t : mesh.triangles) {
    const Eigen::Vector3f c = (mesh.vertices[t[1]] - mesh.vertices[t[0]]).cross(mesh.vertices[t[2]] - mesh.vertices[t[0]]);
    if (!(c.norm() > 1e-12f)) continue;
    const Eigen::Vector3f n = c.normalized();
    auto same = std::find_if(by_area.begin(), by_area.end(), [&](const auto& e) { return e.second.dot(n) > cos1; });
    if (same == by_area.end()) {
      by_area.emplace_back(0.5f * c.norm(), n);
    } else {
      same->first += 0.5f * c.norm();
    }
  }
  std::stable_sort(by_area.begin(), by_area.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
  std::vector<Eigen::Vector3f> candidates;
  for (const auto& [area, n] : by_area) candidates.push_back(n);
  const Eigen::Vector3f axis = symmetry.axis.cast<float>().normalized();
  auto same_rest = [&](const Eigen::Vector3f& a, const Eigen::Vector3f& b) {
    const float cos3 = static_cast<float>(std::cos(3 * kDeg));
    if (a.dot(b) > cos3) return true;
    switch (symmetry.kind) {
      case Symmetry::Kind::kRevolute:
        return std::abs(a.dot(axis) - b.dot(axis)) < 0.05f;
      case Symmetry::Kind::kDiscrete:
        for (int k = 1; k < symmetry.order; ++k) {
          const Eigen::AngleAxisf r(static_cast<float>(2 * M_PI * k / symmetry.order), axis);
          if ((r * a).dot(b) > cos3) return true;
        }
        return false;
      default:
        return false;
    }
  };
  std::vector<RestingPose> rests;
  for (const Eigen::Vector3f& d : candidates) {
    if (std::any_of(rests.begin(), rests.end(), [&](const RestingPose& r) { return same_rest(r.down, d); })) continue;
    float depth = -std::numeric_limits<float>::infinity();
    for (const auto& p : pts) depth = std::max(depth, d.dot(p));
    const auto [u, v] = PlaneBasis(d);
    std::vector<Eigen::Vector2f> contact;
    for (const auto& p : pts) {
      if (d.dot(p) >= depth - tol) contact.emplace_back(u.dot(p), v.dot(p));
    }
    const std::vector<Eigen::Vector2f> hull = ConvexHull2(std::move(contact));
    if (hull.size() < 3) continue;
    const Eigen::Vector2f c(u.dot(centroid), v.dot(centroid));
    bool inside = true;
    for (size_t i = 0; i < hull.size() && inside; ++i) {
      const Eigen::Vector2f& a = hull[i];
      const Eigen::Vector2f& b = hull[(i + 1) % hull.size()];
      inside = (b - a).x() * (c - a).y() - (b - a).y() * (c - a).x() >= 0;
    }
    if (inside) rests.push_back({d, depth});
  }
  return rests;
}
constexpr int kMinScenePoints = 30;
// Resting-pose seeds: height band of the top that centres them (metres);
// upward faces are within kTiltedFaceDeg of the floor's normal; a segment whose
// upward faces tilt more than kMinSeedTiltDeg also gets tilted seeds.
constexpr float kRestTopBand = 0.003f;
constexpr double kTiltedFaceDeg = 20.0;
constexpr double kMinSeedTiltDeg = 2.0;
constexpr int kMinSampledPoints = 8;
// PoseSearch::stop_score also needs the pose to explain this fraction of the
// view's subsampled points. Measured (all 130 scenes): 0.6 and 0.8 gave the
// same detections as no such condition, and 0.8 ran 1.2% more first-pass
// ICPs on seeds 1-40 while a view of two touching parts still gave both.
constexpr double kStopExplainedFraction = 0.8;
// The first pass keeps a refined coarse pose whose quick verification scores
// at least this fraction of min_score (the fine pass usually raises it).
constexpr double kFirstPassScoreFraction = 0.6;
// PPF peaks kept per reference point for a later search of the same view
// (PreparedView::votes): the second look examines 16.
constexpr size_t kRecordedPeaks = 16;

// Without a depth image: the segment's points splatted into an angular grid
// seen from the camera centre, keeping the nearest depth per cell. Cells
// without points are unknown.
struct SegmentDepth {
  Eigen::Vector3f c = Eigen::Vector3f::Zero(), x = Eigen::Vector3f::UnitX(), y = Eigen::Vector3f::UnitY(),
                  z = Eigen::Vector3f::UnitZ();
  float cell_ang = 1;
  int nu = 0, nv = 0;
  float u0 = 0, v0 = 0;
  std::vector<float> zmin;
  bool empty() const { return zmin.empty(); }
  // Nearest measured depth along the ray through p, NaN if unknown; *d gets p's depth.
  float At(const Eigen::Vector3f& p, float* d) const {
    const Eigen::Vector3f v = p - c;
    *d = v.dot(z);
    if (*d <= 0) return std::numeric_limits<float>::quiet_NaN();
    const int u = static_cast<int>(std::floor(v.dot(x) / *d / cell_ang - u0));
    const int w = static_cast<int>(std::floor(v.dot(y) / *d / cell_ang - v0));
    if (u < 0 || w < 0 || u >= nu || w >= nv) return std::numeric_limits<float>::quiet_NaN();
    const float zm = zmin[static_cast<size_t>(w) * nu + u];
    return std::isfinite(zm) ? zm : std::numeric_limits<float>::quiet_NaN();
  }
};

SegmentDepth BuildSegmentDepth(std::span<const Eigen::Vector3f> pts, const Eigen::Vector3f& camera, float cell_m) {
  SegmentDepth b;
  Eigen::Vector3f mean = Eigen::Vector3f::Zero();
  for (const auto& p : pts) mean += p;
  mean /= static_cast<float>(pts.size());
  b.c = camera;
  const float range = (mean - camera).norm();
  if (!(range > 1e-3f)) return b;
  b.z = (mean - camera) / range;
  b.x = b.z.unitOrthogonal();
  b.y = b.z.cross(b.x);
  b.cell_ang = cell_m / range;
  float umin = 1e30f, umax = -1e30f, vmin = 1e30f, vmax = -1e30f;
  std::vector<Eigen::Vector3f> uvd(pts.size());
  for (size_t i = 0; i < pts.size(); ++i) {
    const Eigen::Vector3f v = pts[i] - camera;
    const float d = v.dot(b.z);
    if (d <= 0) {
      uvd[i] = Eigen::Vector3f(0, 0, -1);
      continue;
    }
    uvd[i] = Eigen::Vector3f(v.dot(b.x) / d / b.cell_ang, v.dot(b.y) / d / b.cell_ang, d);
    umin = std::min(umin, uvd[i].x()), umax = std::max(umax, uvd[i].x());
    vmin = std::min(vmin, uvd[i].y()), vmax = std::max(vmax, uvd[i].y());
  }
  if (umin > umax) return b;
  b.u0 = std::floor(umin) - 1, b.v0 = std::floor(vmin) - 1;
  b.nu = static_cast<int>(umax - b.u0) + 2, b.nv = static_cast<int>(vmax - b.v0) + 2;
  if (static_cast<int64_t>(b.nu) * b.nv > 4'000'000) return SegmentDepth{};  // absurd extent: skip the test
  b.zmin.assign(static_cast<size_t>(b.nu) * b.nv, std::numeric_limits<float>::infinity());
  for (const auto& e : uvd) {
    if (e.z() <= 0) continue;
    const size_t k = static_cast<size_t>(static_cast<int>(e.y() - b.v0)) * b.nu + static_cast<int>(e.x() - b.u0);
    b.zmin[k] = std::min(b.zmin[k], e.z());
  }
  return b;
}

// Model points facing the camera by less than this cosine (more than 60 deg
// off the line of sight) lie on grazing faces, where depth sensors (and the
// synthetic noise model) drop pixels.
constexpr float kGrazingCos = 0.5f;

struct VerifyStats {
  int visible = 0, occluded = 0, supported = 0, free_space = 0;
  // Of the visible points, those on a grazing face (see kGrazingCos) whose
  // pixel has no measurement and that no scene point supports.
  int unmeasured = 0;
  bool below_support = false;
  double score = -1;
};

using internal::PixelOf;

// A view point deprojected from a depth image projects back onto its pixel's
// centre, at its depth, but for float rounding through B and back.
constexpr internal::OnPixelTolerance kOnPixel{};
// The largest depth-image window (half width, pixels) the support test
// scans before it asks the hash.
constexpr int kMaxSupportWindow = 3;

// The view's points for the support test of Verify: a hash of them and,
// when each of them lies on its pixel of the view's depth image (projects
// onto its centre, at the depth it holds: the grid samples of a frame), that
// fact. Then a model point with no pixel near it in the depth image at a
// depth within the support distance of its own has no view point within
// that distance either, and the hash is not asked (AnyWithin): the same
// answers, for a few pixel reads instead of eight hash probes. Measured
// (callgrind, 4 rendered piles, 1 thread): Verify's hash queries 206k ->
// 25k, its instructions 96.9 -> 70.8 M per frame (docs/perception.md,
// "Verification").
struct SceneSupport {
  internal::PointHash hash;
  bool on_depth = false;

  // Builds the hash of pts (finite) with cells of `cell` and checks them
  // against the view's depth image.
  void Build(std::span<const Eigen::Vector3f> pts, float cell, const SceneView& view) {
    hash.Build(pts, cell);
    on_depth = false;
    if (view.depth == nullptr || view.depth->empty() || !view.intrinsics.valid() || pts.empty()) return;
    const Pose X_CB = view.X_BC.inverse();
    const Eigen::Matrix3f R = X_CB.linear().cast<float>();
    const Eigen::Vector3f t = X_CB.translation().cast<float>();
    for (const Eigen::Vector3f& p : pts) {
      if (!internal::OnItsPixel(view.intrinsics, *view.depth, R * p + t, kOnPixel)) return;
    }
    on_depth = true;
  }

  // True when a view point lies within r of p (p_C: p in C, (u, v) its pixel).
  bool AnyWithin(const Eigen::Vector3f& p, float r, const Eigen::Vector3f& p_C, int u, int v,
                 const SceneView& view) const {
    if (on_depth && !internal::DepthWindowMayHoldPointNear(*view.depth, view.intrinsics, p_C, u, v, r, kOnPixel,
                                                           kMaxSupportWindow)) {
      return false;
    }
    return hash.AnyWithin(p, r);
  }
};

// 1 for points on the boundary of the sampled surface: the centroid of their
// neighbours within radius is off-centre by more than a quarter radius (a
// straight edge gives 4 / (3 pi) ~ 0.42 radius, the interior ~0).
// queries: the points to flag; hashed: the points hash was built on.
std::vector<uint8_t> BoundaryFlags(std::span<const Eigen::Vector3f> queries, std::span<const Eigen::Vector3f> hashed,
                                   const internal::PointHash& hash, float radius) {
  std::vector<uint8_t> flags(queries.size(), 0);
  for (size_t i = 0; i < queries.size(); ++i) {
    Eigen::Vector3f sum = Eigen::Vector3f::Zero();
    int n = 0;
    hash.ForEachWithin(queries[i], radius, [&](int j, float) {
      sum += hashed[j];
      ++n;
    });
    flags[i] = (n < 4 || (sum / static_cast<float>(n) - queries[i]).norm() > 0.25f * radius) ? 1 : 0;
  }
  return flags;
}

// A planar face of the part, for PoseSearch::face_seeds.
struct PlanarFace {
  Eigen::Vector3f n = Eigen::Vector3f::UnitZ();  // outward unit normal, O
  Eigen::Vector3f c = Eigen::Vector3f::Zero();   // centroid of the face's samples, O
  Eigen::Vector3f u = Eigen::Vector3f::UnitX();  // in-plane principal axis (largest extent)
  Eigen::Vector3f v = Eigen::Vector3f::UnitY();  // n x u
  Eigen::Vector2f lo = Eigen::Vector2f::Zero(), hi = Eigen::Vector2f::Zero();  // samples' box in (u, v) about c
};
// Faces are triangles whose normals agree within this and whose planes within kFacePlaneTol.
constexpr double kFaceNormalDeg = 2.0;
constexpr float kFacePlaneTol = 0.0006f;
// A face seeds poses when both its extents are at least this (metres).
constexpr float kMinFaceExtent = 0.015f;
// Face seeds align a face's axes with the view's principal axis and with up
// to this many more directions, those of the view's longest convex-hull edges
// (merged within kFaceEdgeMergeDeg, modulo 90 deg).
constexpr int kFaceEdgeDirections = 2;
constexpr double kFaceEdgeMergeDeg = 5.0;
// Face seeds are ranked by a verification of every this-many-th sample
// (measured: 6 ranks as well as 3 on seeds 1-70, at half the cost), after a
// screen of every kFaceSeedScreenStride-th sample has kept the best
// kFaceSeedsScreened. Measured (all 130 scenes of
// docs/perception_pipeline.md, 2026-12-03): the same detections as ranking
// every seed at stride 6, for half the face seeds' time (seeds 11-40: 294
// -> 141 ms over the 30 frames); on the held-out 30 one true L-bracket
// detection fewer (a part under half visible: 490 / 494 -> 489 / 493); keeping 4 lost 3 true positives, a screen
// at stride 48 lost recall (seeds 11-40: 0.952 -> 0.946).
constexpr int kFaceSeedStride = 6;
constexpr int kFaceSeedScreenStride = 24;
constexpr size_t kFaceSeedsScreened = 6;
// A view is planar when its points' RMS distance from their plane is below
// this (depth noise on the default cell: ~0.45 mm).
constexpr double kPlanarViewRms = 0.0010;

// In-plane principal axes (u, v = n x u) and box of 2D points about their centroid.
void PlaneFrame(std::span<const Eigen::Vector3f> pts, const Eigen::Vector3f& n, Eigen::Vector3f* c,
                Eigen::Vector3f* u, Eigen::Vector3f* v, Eigen::Vector2f* lo, Eigen::Vector2f* hi) {
  *c = Eigen::Vector3f::Zero();
  for (const auto& p : pts) *c += p;
  *c /= static_cast<float>(std::max<size_t>(1, pts.size()));
  const Eigen::Vector3f a = n.unitOrthogonal(), b = n.cross(a);
  Eigen::Matrix2f C = Eigen::Matrix2f::Zero();
  for (const auto& p : pts) {
    const Eigen::Vector2f q(a.dot(p - *c), b.dot(p - *c));
    C += q * q.transpose();
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix2f> es(C);
  const Eigen::Vector2f e = es.eigenvectors().col(1);
  *u = (a * e.x() + b * e.y()).normalized();
  *v = n.cross(*u);
  *lo = Eigen::Vector2f::Constant(std::numeric_limits<float>::infinity());
  *hi = -*lo;
  for (const auto& p : pts) {
    const Eigen::Vector2f q(u->dot(p - *c), v->dot(p - *c));
    *lo = lo->cwiseMin(q);
    *hi = hi->cwiseMax(q);
  }
}

// A point of a planar face's plane in one of its holes (PoseEstimatorOptions::hole_max_filled).
struct HolePoint {
  Eigen::Vector3f p;  // O
  Eigen::Vector3f n;  // the face's outward normal, O
};
// Hole points are laid on a grid of this pitch (metres) in the face's plane.
constexpr float kHolePitch = 0.001f;
// A hole point in view faces the camera by at least this cosine (its face does).
constexpr float kHoleMinCos = 0.3f;

// Distance from q to the triangle (a, b, c) in 2D (0 inside).
float DistanceToTriangle2(const Eigen::Vector2f& q, const Eigen::Vector2f& a, const Eigen::Vector2f& b,
                          const Eigen::Vector2f& c) {
  auto cross = [](const Eigen::Vector2f& x, const Eigen::Vector2f& y) { return x.x() * y.y() - x.y() * y.x(); };
  const float d1 = cross(b - a, q - a), d2 = cross(c - b, q - b), d3 = cross(a - c, q - c);
  const bool neg = d1 < 0 || d2 < 0 || d3 < 0, pos = d1 > 0 || d2 > 0 || d3 > 0;
  if (!(neg && pos)) return 0.f;
  auto seg = [&](const Eigen::Vector2f& x, const Eigen::Vector2f& y) {
    const Eigen::Vector2f e = y - x;
    const float t = std::clamp(e.dot(q - x) / std::max(e.squaredNorm(), 1e-20f), 0.f, 1.f);
    return (x + t * e - q).norm();
  };
  return std::min({seg(a, b), seg(b, c), seg(c, a)});
}

// The hole points of one face (triangles `tris` of `mesh`, frame of `f`):
// grid points of the face's box that no triangle covers, at least `margin`
// from every triangle, with covered grid points on both sides along both
// in-plane axes (enclosed: a bore, not the notch of an L-shaped face). Each
// triangle visits the grid points of its own box grown by the margin, so
// the cost follows the face's area, not area x triangles; the pitch grows
// past kHolePitch to keep a very large face's grid under kMaxHoleGrid points.
constexpr size_t kMaxHoleGrid = 250000;
std::vector<HolePoint> FaceHoles(const TriangleMesh& mesh, const std::vector<int>& tris, const PlanarFace& f,
                                 float margin) {
  const Eigen::Vector2f extent = f.hi - f.lo;
  const float pitch = std::max(kHolePitch, std::sqrt(extent.x() * extent.y() / static_cast<float>(kMaxHoleGrid)));
  const int nx = static_cast<int>(std::floor(extent.x() / pitch)) + 1;
  const int ny = static_cast<int>(std::floor(extent.y() / pitch)) + 1;
  const auto at = [&](int x, int y) { return static_cast<size_t>(y) * nx + x; };
  std::vector<float> dist(static_cast<size_t>(nx) * ny, std::numeric_limits<float>::infinity());
  for (int ti : tris) {
    std::array<Eigen::Vector2f, 3> t;
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3f p = mesh.vertices[mesh.triangles[ti][k]] - f.c;
      t[k] = Eigen::Vector2f(f.u.dot(p), f.v.dot(p));
    }
    const Eigen::Vector2f lo = (t[0].cwiseMin(t[1]).cwiseMin(t[2]) - f.lo).array() - margin;
    const Eigen::Vector2f hi = (t[0].cwiseMax(t[1]).cwiseMax(t[2]) - f.lo).array() + margin;
    const int x0 = std::max(0, static_cast<int>(std::floor(lo.x() / pitch)));
    const int y0 = std::max(0, static_cast<int>(std::floor(lo.y() / pitch)));
    const int x1 = std::min(nx - 1, static_cast<int>(std::ceil(hi.x() / pitch)));
    const int y1 = std::min(ny - 1, static_cast<int>(std::ceil(hi.y() / pitch)));
    for (int y = y0; y <= y1; ++y) {
      for (int x = x0; x <= x1; ++x) {
        float& d = dist[at(x, y)];
        if (d == 0.f) continue;
        const Eigen::Vector2f q = f.lo + pitch * Eigen::Vector2f(static_cast<float>(x), static_cast<float>(y));
        d = std::min(d, DistanceToTriangle2(q, t[0], t[1], t[2]));
      }
    }
  }
  // Enclosed: between the first and the last covered point of its row and of its column.
  std::vector<int> row_lo(ny, nx), row_hi(ny, -1), col_lo(nx, ny), col_hi(nx, -1);
  for (int y = 0; y < ny; ++y) {
    for (int x = 0; x < nx; ++x) {
      if (dist[at(x, y)] != 0.f) continue;
      row_lo[y] = std::min(row_lo[y], x);
      row_hi[y] = std::max(row_hi[y], x);
      col_lo[x] = std::min(col_lo[x], y);
      col_hi[x] = std::max(col_hi[x], y);
    }
  }
  std::vector<HolePoint> holes;
  for (int y = 0; y < ny; ++y) {
    for (int x = 0; x < nx; ++x) {
      if (dist[at(x, y)] < margin) continue;
      if (!(row_lo[y] < x && x < row_hi[y] && col_lo[x] < y && y < col_hi[x])) continue;
      const Eigen::Vector2f q = f.lo + pitch * Eigen::Vector2f(static_cast<float>(x), static_cast<float>(y));
      holes.push_back({f.c + q.x() * f.u + q.y() * f.v, f.n});
    }
  }
  return holes;
}

// The part's large planar faces: mesh triangles grouped by normal and plane,
// each group with the dense samples on it. Appends the faces' hole points
// (FaceHoles) to `holes`.
std::vector<PlanarFace> PlanarFaces(const TriangleMesh& mesh, const OrientedPoints& dense, float hole_margin,
                                    std::vector<HolePoint>* holes) {
  struct Group {
    Eigen::Vector3f n;
    float d;
    float area;
    std::vector<int> tris;
  };
  std::vector<Group> groups;
  const float cos_tol = static_cast<float>(std::cos(kFaceNormalDeg * kDeg));
  for (size_t ti = 0; ti < mesh.triangles.size(); ++ti) {
    const Eigen::Vector3i& t = mesh.triangles[ti];
    const Eigen::Vector3f& a = mesh.vertices[t[0]];
    const Eigen::Vector3f cr = (mesh.vertices[t[1]] - a).cross(mesh.vertices[t[2]] - a);
    if (!(cr.norm() > 1e-12f)) continue;
    const Eigen::Vector3f n = cr.normalized();
    const float d = n.dot(a);
    auto g = std::find_if(groups.begin(), groups.end(),
                          [&](const Group& e) { return e.n.dot(n) > cos_tol && std::abs(e.d - d) < kFacePlaneTol; });
    if (g == groups.end()) {
      groups.push_back({n, d, 0.5f * cr.norm(), {static_cast<int>(ti)}});
    } else {
      g->area += 0.5f * cr.norm();
      g->tris.push_back(static_cast<int>(ti));
    }
  }
  std::vector<PlanarFace> faces;
  for (const Group& g : groups) {
    if (g.area < kMinFaceExtent * kMinFaceExtent) continue;
    std::vector<Eigen::Vector3f> on;
    for (size_t i = 0; i < dense.size(); ++i) {
      if (dense.normals[i].dot(g.n) > cos_tol && std::abs(g.n.dot(dense.points[i]) - g.d) < kFacePlaneTol) {
        on.push_back(dense.points[i]);
      }
    }
    if (on.size() < 20) continue;
    PlanarFace f;
    f.n = g.n;
    PlaneFrame(on, g.n, &f.c, &f.u, &f.v, &f.lo, &f.hi);
    if ((f.hi - f.lo).minCoeff() < kMinFaceExtent) continue;
    faces.push_back(f);
    if (holes) {
      const std::vector<HolePoint> h = FaceHoles(mesh, g.tris, f, hole_margin);
      holes->insert(holes->end(), h.begin(), h.end());
    }
  }
  return faces;
}

// The points of `pts` that are lowest along one of ~2500 directions spread
// over the sphere: nearly the convex hull's vertices. The minimum of a linear
// function over `pts` (how deep a pose sinks the part into a plane) is then
// taken over these alone, off the exact minimum by at most
// radius * (1 - cos(2 deg)), about 0.04 mm for these parts.
std::vector<Eigen::Vector3f> ExtremePoints(std::span<const Eigen::Vector3f> pts) {
  constexpr int kDirections = 2562;
  std::vector<uint8_t> extreme(pts.size(), 0);
  const double golden = M_PI * (3.0 - std::sqrt(5.0));
  for (int k = 0; k < kDirections && !pts.empty(); ++k) {
    const double z = 1.0 - 2.0 * (k + 0.5) / kDirections;
    const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
    const Eigen::Vector3f d(static_cast<float>(r * std::cos(golden * k)), static_cast<float>(r * std::sin(golden * k)),
                            static_cast<float>(z));
    size_t best = 0;
    for (size_t i = 1; i < pts.size(); ++i) {
      if (d.dot(pts[i]) < d.dot(pts[best])) best = i;
    }
    extreme[best] = 1;
  }
  std::vector<Eigen::Vector3f> out;
  for (size_t i = 0; i < pts.size(); ++i) {
    if (extreme[i]) out.push_back(pts[i]);
  }
  return out;
}

// Reorders the samples along a Morton (Z-order) curve over 2 mm cells, so
// that samples near each other in space are near each other in memory: ICP
// reads the samples a segment's points map to, and in sample order those
// reads missed the cache (tens of thousands of samples, several MB per part).
void SortByMortonCode(internal::OrientedPoints& s) {
  if (s.size() < 2) return;
  Eigen::AlignedBox3f box;
  for (const auto& p : s.points) box.extend(p);
  const auto spread = [](uint32_t v) {  // 10 bits -> every third of 30 bits
    uint64_t x = v & 0x3ff;
    x = (x | (x << 16)) & 0x030000FF;
    x = (x | (x << 8)) & 0x0300F00F;
    x = (x | (x << 4)) & 0x030C30C3;
    x = (x | (x << 2)) & 0x09249249;
    return x;
  };
  std::vector<std::pair<uint64_t, uint32_t>> keys(s.size());
  for (size_t i = 0; i < s.size(); ++i) {
    const Eigen::Vector3f g = (s.points[i] - box.min()) / 0.002f;
    const auto c = [](float v) { return static_cast<uint32_t>(std::clamp(v, 0.f, 1023.f)); };
    keys[i] = {spread(c(g.x())) | (spread(c(g.y())) << 1) | (spread(c(g.z())) << 2), static_cast<uint32_t>(i)};
  }
  std::sort(keys.begin(), keys.end());
  internal::OrientedPoints sorted;
  sorted.points.reserve(s.size());
  sorted.normals.reserve(s.size());
  for (const auto& [key, i] : keys) {
    sorted.points.push_back(s.points[i]);
    sorted.normals.push_back(s.normals[i]);
  }
  s = std::move(sorted);
}

// A sample maps onto the surface under a near symmetry when its image lies
// within this of a dense sample whose normal is within kNearSymmetryDeg.
constexpr float kNearSymmetryDistance = 0.001f;
constexpr double kNearSymmetryDeg = 30.0;
// Two transforms of O are one near symmetry (or one is the identity modulo
// the declared symmetry) within this rotation and this fraction of the
// diameter at the centroid.
constexpr double kSameTransformDeg = 10.0;
constexpr double kSameTransformRelative = 0.05;
// Plates: two antiparallel faces at most this fraction of the diameter apart
// whose boxes overlap.
constexpr double kPlateRelativeThickness = 0.2;
// A near-symmetric turn of a hypothesis is refined only when, at a quick
// look (every third verification sample), it explains at least this fraction
// of what the hypothesis does.
constexpr double kNearSymmetryScreen = 0.8;

// A model point counts as in free space only when the measured surface lies
// beyond it at the pixel and at the pixels about kFreeSpaceReach (metres)
// around it: one pixel off the part's silhouette, where the depth jumps to
// what is behind, is an alignment error of a pixel, not evidence against the
// pose.
constexpr double kFreeSpaceReach = 0.0013;

// True if every finite depth at (u, v) and at the 8 pixels `reach` away is
// beyond `limit`.
bool FreeAround(const DepthImage& depth, int u, int v, float limit, double reach_px) {
  const int r = std::max(1, static_cast<int>(std::lround(reach_px)));
  for (int dv = -r; dv <= r; dv += r) {
    const int vv = v + dv;
    if (vv < 0 || vv >= depth.height) continue;
    for (int du = -r; du <= r; du += r) {
      const int uu = u + du;
      if (uu < 0 || uu >= depth.width) continue;
      const float z = depth.at(uu, vv);
      if (std::isfinite(z) && z > 0 && z <= limit) return false;
    }
  }
  return true;
}

// The 180 deg turn about the line through c along unit axis a.
Pose HalfTurn(const Eigen::Vector3f& a, const Eigen::Vector3f& c) {
  const Eigen::Vector3d ad = a.cast<double>().normalized();
  const Eigen::Matrix3d R = 2.0 * ad * ad.transpose() - Eigen::Matrix3d::Identity();
  const Eigen::Vector3d cd = c.cast<double>();
  return MakePose(R, cd - R * cd);
}

}  // namespace

// What Estimate derives from a view before its search; an estimate of the
// same view by the same class (the perception's second look) reuses it
// (PoseSearch::prepared).
struct PreparedView {
  const void* owner = nullptr;  // the PoseEstimator::Impl that made it
  size_t input_points = 0;      // SceneView::points_B.size()
  std::vector<Eigen::Vector3f> pts;  // finite points
  std::vector<int> index;            // their indices in SceneView::points_B
  std::optional<Eigen::Vector3f> view_plane;  // a planar view's normal, towards the camera
  std::vector<Eigen::Vector3f> sub_p, sub_n;  // subsampled at the PPF step, with normals
  SegmentDepth segment_depth;                 // without a depth image only
  SceneSupport support;                        // of pts, for the support queries
  std::vector<uint8_t> sub_boundary;          // per subsampled point
  std::vector<Eigen::Vector3f> fine;          // the fine ICP pass's points
  std::vector<uint8_t> fine_boundary;
  // The first search's PPF peaks (PpfMatchOptions::record), with
  // kRecordedPeaks per reference point: a wider search (more peaks per
  // reference point) reads them instead of voting again.
  internal::PpfVotes votes;
};

bool PoseEstimatorOptions::IsValid(std::string* error) const {
  auto fail = [&](const char* what) {
    if (error) *error = what;
    return false;
  };
  if (!(ppf_relative_sampling > 0.005 && ppf_relative_sampling <= 0.2)) return fail("ppf_relative_sampling must be in (0.005, 0.2]");
  if (!(ppf_angle_step_deg >= 3 && ppf_angle_step_deg <= 45)) return fail("ppf_angle_step_deg must be in [3, 45]");
  if (!(icp_model_spacing > 0) || !(verify_model_spacing > 0)) return fail("model spacings must be > 0");
  if (!(reference_fraction > 0 && reference_fraction <= 1)) return fail("reference_fraction must be in (0, 1]");
  if (!(coarse_stop_score >= 0 && coarse_stop_score <= 1)) return fail("coarse_stop_score must be in [0, 1]");
  if (ppf_max_bucket_entries < 1 || ppf_max_partners < 1 || max_reference_points < 1 || max_coarse_poses < 1 || max_hypotheses < 1) return fail("counts must be >= 1");
  if (icp_iterations < 1 || icp_coarse_iterations < 1 || icp_max_points < 100 || icp_shrink_iterations < 1) {
    return fail("icp_iterations, icp_coarse_iterations and icp_shrink_iterations must be >= 1, icp_max_points >= 100");
  }
  if (!(icp_convergence > 0) || !(icp_coarse_convergence > 0)) return fail("icp_convergence and icp_coarse_convergence must be > 0");
  if (!(icp_final_distance > 0) || !(icp_initial_relative_distance > 0)) return fail("icp distances must be > 0");
  if (!(support_distance > 0) || !(free_space_distance > 0)) return fail("support/free-space distances must be > 0");
  if (quick_screen_stride < 1 || !(quick_screen_min_score >= 0 && quick_screen_min_score <= 1)) {
    return fail("quick_screen_stride must be >= 1, quick_screen_min_score in [0, 1]");
  }
  if (!(visible_min_cos >= 0 && visible_min_cos < 1)) return fail("visible_min_cos must be in [0, 1)");
  if (!(near_symmetry_min_overlap >= 0 && near_symmetry_min_overlap <= 1) || max_near_symmetries < 0 ||
      !(near_symmetry_score_slack >= 0 && near_symmetry_score_slack < 1)) {
    return fail("near_symmetry_min_overlap must be in [0, 1], near_symmetry_score_slack in [0, 1), max_near_symmetries >= 0");
  }
  if (!(hole_margin > 0) || hole_min_visible < 1 || !(hole_max_filled >= 0)) {
    return fail("hole_margin must be > 0, hole_min_visible >= 1, hole_max_filled >= 0");
  }
  return true;
}

struct PoseEstimator::Impl {
  PoseEstimatorOptions options;
  Symmetry symmetry;
  double diameter = 0;
  float step = 0;                  // PPF sampling distance
  Eigen::Vector3f centroid_O = Eigen::Vector3f::Zero();
  OrientedPoints dense;            // ICP targets
  std::vector<internal::EdgePlane> edge_planes;  // per dense sample
  internal::ClosestPointField field;
  OrientedPoints verify;           // verification samples
  OrientedPoints ppf_points;
  // ExtremePoints of ppf_points and of verify: the support-plane tests.
  std::vector<Eigen::Vector3f> ppf_extreme, verify_extreme;
  internal::PpfModel ppf;
  std::vector<RestingPose> rests;  // over the dense samples
  std::vector<PlanarFace> faces;   // PoseSearch::face_seeds
  // PoseEstimatorOptions::hole_max_filled; only those farther than
  // hole_margin from the rest of the part's surface.
  std::vector<HolePoint> holes;
  // Hole points in view and, of those, filled, for a pose (depth image only).
  std::pair<int, int> HoleStats(const Pose& X_BO, const SceneView& view) const;
  // Fills w from the view; false (out.no_result_reason set) when the view
  // cannot be matched.
  bool Prepare(const SceneView& view, PreparedView& w, PoseEstimates& out) const;
  // The closest-point field's bounding sphere (ClosestPointField::grid_radius)
  // at X_BO: centre in B, squared radius.
  std::pair<Eigen::Vector3f, float> FieldSphere(const Pose& X_BO) const {
    const float r = field.grid_radius();
    return {(X_BO * field.grid_centre().cast<double>()).cast<float>(), r * r};
  }
  // True when q (in O) lies within tol of the part's surface (the nearest
  // dense sample through the closest-point field; false beyond its band).
  bool OnSurface(const Eigen::Vector3f& q, float tol) const {
    const int idx = field.Lookup(q);
    return idx >= 0 && (q - dense.points[static_cast<size_t>(idx)]).squaredNorm() <= tol * tol;
  }
  // Points of `scene` within the support distance of the part at X_BO, as a fraction.
  double ExplainedFraction(const Pose& X_BO, std::span<const Eigen::Vector3f> scene) const {
    if (scene.empty()) return 0.0;
    const Pose X_OB = X_BO.inverse();
    const Eigen::Matrix3f R = X_OB.linear().cast<float>();
    const Eigen::Vector3f t = X_OB.translation().cast<float>();
    const float tol = SupportTolerance();
    size_t on = 0;
    for (const Eigen::Vector3f& p : scene) on += OnSurface(R * p + t, tol) ? 1 : 0;
    return static_cast<double>(on) / static_cast<double>(scene.size());
  }
  // A scene point supports the part within this of its dense surface samples.
  float SupportTolerance() const {
    return static_cast<float>(options.support_distance + 0.5 * options.icp_model_spacing);
  }

  // PoseSearch::resting_seeds: appends the part lying on `plane` (n, d; n
  // towards the parts) in each resting orientation, centred on the segment.
  // sub_p / sub_n: the subsampled scene points and their normals (towards
  // the camera), for the tilt of the segment's upward faces.
  void AppendRestingSeeds(std::span<const Eigen::Vector3f> scene, std::span<const Eigen::Vector3f> sub_p,
                          std::span<const Eigen::Vector3f> sub_n, const Eigen::Vector4d& plane,
                          std::vector<internal::CoarsePose>& coarse) const;

  // PoseSearch::face_seeds: the part with one of its planar faces on the
  // view's plane (normal n, towards the camera), the face's principal axis
  // along the view's principal axis or one of its longest hull edges (each in
  // four quarter turns), placed so that the face's box holds the view's; the
  // `keep` best by a quick verification are appended.
  void AppendFaceSeeds(std::span<const Eigen::Vector3f> scene, const Eigen::Vector3f& n, const SceneView& view,
                       const SceneSupport& support, const SegmentDepth& segment_depth, int keep,
                       std::vector<internal::CoarsePose>& coarse) const;

  std::vector<Pose> near_symmetries;  // PoseEstimatorOptions::near_symmetry_min_overlap
  // Finds them (after faces, field, dense and verify are built).
  std::vector<Pose> NearSymmetries() const;

  // Visible-surface test, support and free-space test for one pose.
  // stride > 1 checks every stride-th verification sample (a quick pass).
  VerifyStats Verify(const Pose& X_BO, const SceneView& view, const SceneSupport& scene,
                     const SegmentDepth& segment_depth, int stride = 1,
                     bool unmeasured_is_no_evidence = false) const;
  internal::IcpResult Refine(std::span<const Eigen::Vector3f> scene, std::span<const uint8_t> boundary,
                             const Pose& X_BO, const Vec3& camera_B, float initial, float final_gate,
                             int iterations, double convergence) const {
    internal::IcpModel model{dense.points, dense.normals, &field, edge_planes};
    internal::IcpOptions o;
    o.shrink_iterations = options.icp_shrink_iterations;
    o.boundary = boundary;
    o.iterations = iterations;
    o.initial_distance = initial;
    o.final_distance = final_gate;
    o.convergence = static_cast<float>(convergence);
    return internal::RefinePointToPlane(model, scene, X_BO, camera_B, o);
  }
};

PoseEstimator::PoseEstimator(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
PoseEstimator::~PoseEstimator() = default;
void PoseEstimator::MarkOnSurface(const Pose& X_BO, std::span<const Eigen::Vector3f> points_B, float tolerance,
                                  std::vector<uint8_t>* on_surface) const {
  const Pose X_OB = X_BO.inverse();
  const Eigen::Matrix3f R = X_OB.linear().cast<float>();
  const Eigen::Vector3f t = X_OB.translation().cast<float>();
  const auto [c_B, r2] = impl_->FieldSphere(X_BO);
  for (size_t i = 0; i < points_B.size() && i < on_surface->size(); ++i) {
    if ((*on_surface)[i] || (points_B[i] - c_B).squaredNorm() > r2) continue;
    const Eigen::Vector3f q = R * points_B[i] + t;
    if (impl_->OnSurface(q, tolerance)) (*on_surface)[i] = 1;
  }
}
size_t PoseEstimator::CountInside(const Pose& X_BO, std::span<const Eigen::Vector3f> points_B,
                                  float min_depth) const {
  const Pose X_OB = X_BO.inverse();
  const Eigen::Matrix3f R = X_OB.linear().cast<float>();
  const Eigen::Vector3f t = X_OB.translation().cast<float>();
  const auto [c_B, r2] = impl_->FieldSphere(X_BO);
  size_t inside = 0;
  for (const Eigen::Vector3f& p : points_B) {
    if ((p - c_B).squaredNorm() > r2) continue;  // no closest sample there
    const Eigen::Vector3f q = R * p + t;
    const int idx = impl_->field.Lookup(q);
    if (idx < 0) continue;
    const size_t i = static_cast<size_t>(idx);
    inside += impl_->dense.normals[i].dot(q - impl_->dense.points[i]) < -min_depth ? 1 : 0;
  }
  return inside;
}
double PoseEstimator::diameter() const { return impl_->diameter; }
double PoseEstimator::sampling_distance() const { return impl_->step; }
int PoseEstimator::model_point_count() const { return static_cast<int>(impl_->ppf_points.size()); }
const std::vector<Eigen::Vector3f>& PoseEstimator::surface_points_O() const { return impl_->verify.points; }
Eigen::Vector3f PoseEstimator::centroid_O() const { return impl_->centroid_O; }
const Symmetry& PoseEstimator::symmetry() const { return impl_->symmetry; }
const std::vector<Pose>& PoseEstimator::near_symmetries() const { return impl_->near_symmetries; }

std::vector<Pose> PoseEstimator::Impl::NearSymmetries() const {
  if (options.max_near_symmetries <= 0 || !(options.near_symmetry_min_overlap > 0) || faces.empty()) return {};
  std::vector<Pose> candidates;
  for (const PlanarFace& f : faces) {
    if ((f.hi - f.lo).minCoeff() < kMinFaceExtent) continue;
    // The centre of the face's box (holes pull its centroid off it).
    const Eigen::Vector3f box_c = f.c + 0.5f * (f.lo.x() + f.hi.x()) * f.u + 0.5f * (f.lo.y() + f.hi.y()) * f.v;
    candidates.push_back(HalfTurn(f.n, box_c));
    // A plate: the antiparallel face nearest behind this one whose box
    // overlaps it; turns about the in-plane axes through the mid-plane.
    float thickness = std::numeric_limits<float>::infinity();
    for (const PlanarFace& g : faces) {
      if (f.n.dot(g.n) > -0.99f) continue;
      const float t = f.n.dot(f.c - g.c);
      if (!(t > 0.f) || t > static_cast<float>(kPlateRelativeThickness * diameter)) continue;
      const Eigen::Vector3f d = g.c - f.c;
      const Eigen::Vector2f gc(d.dot(f.u), d.dot(f.v));
      if ((gc.array() < f.lo.array()).any() || (gc.array() > f.hi.array()).any()) continue;
      thickness = std::min(thickness, t);
    }
    if (!std::isfinite(thickness)) continue;
    const Eigen::Vector3f mid = box_c - 0.5f * thickness * f.n;
    candidates.push_back(HalfTurn(f.u, mid));
    candidates.push_back(HalfTurn(f.v, mid));
  }
  const Eigen::Vector3d centroid = centroid_O.cast<double>();
  const auto same = [&](const Pose& a, const Pose& b) {
    return SymmetricRotationError(a, b, symmetry) < kSameTransformDeg * kDeg &&
           (a * centroid - b * centroid).norm() < kSameTransformRelative * diameter;
  };
  const float cos_normal = static_cast<float>(std::cos(kNearSymmetryDeg * kDeg));
  std::vector<std::pair<double, Pose>> scored;
  for (const Pose& F : candidates) {
    if (same(F, Pose::Identity())) continue;
    const Eigen::Matrix3f R = F.linear().cast<float>();
    const Eigen::Vector3f t = F.translation().cast<float>();
    size_t on = 0;
    for (size_t i = 0; i < verify.size(); ++i) {
      const Eigen::Vector3f q = R * verify.points[i] + t;
      const int idx = field.Nearest(q, dense.points);
      if (idx < 0) continue;
      on += (q - dense.points[static_cast<size_t>(idx)]).squaredNorm() <= kNearSymmetryDistance * kNearSymmetryDistance &&
            (R * verify.normals[i]).dot(dense.normals[static_cast<size_t>(idx)]) >= cos_normal;
    }
    const double overlap = static_cast<double>(on) / static_cast<double>(std::max<size_t>(1, verify.size()));
    if (overlap >= options.near_symmetry_min_overlap) scored.emplace_back(overlap, F);
  }
  std::stable_sort(scored.begin(), scored.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
  std::vector<Pose> out;
  for (const auto& [overlap, F] : scored) {
    if (static_cast<int>(out.size()) >= options.max_near_symmetries) break;
    bool duplicate = false;
    for (const Pose& G : out) duplicate |= same(F, G);
    if (!duplicate) out.push_back(F);
  }
  return out;
}

void PoseEstimator::Impl::AppendRestingSeeds(std::span<const Eigen::Vector3f> scene,
                                              std::span<const Eigen::Vector3f> sub_p,
                                              std::span<const Eigen::Vector3f> sub_n, const Eigen::Vector4d& plane,
                                              std::vector<internal::CoarsePose>& coarse) const {
  const Eigen::Vector3f n = plane.head<3>().cast<float>();
  const float d = static_cast<float>(plane[3]);
  const auto [u, v] = PlaneBasis(n);
  // The segment above the floor, in plane coordinates: its centre and its
  // principal direction (angle in the (u, v) plane).
  auto principal_angle = [](const std::vector<Eigen::Vector2f>& q, Eigen::Vector2f& mean) {
    mean.setZero();
    for (const auto& p : q) mean += p;
    mean /= static_cast<float>(q.size());
    Eigen::Matrix2f C = Eigen::Matrix2f::Zero();
    for (const auto& p : q) C += (p - mean) * (p - mean).transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix2f> es(C);
    const Eigen::Vector2f e = es.eigenvectors().col(1);
    return std::atan2(e.y(), e.x());
  };
  std::vector<Eigen::Vector2f> seg;
  std::vector<float> heights;
  for (const auto& p : scene) {
    const float h = n.dot(p) + d;
    if (h > 0.5f * step) {
      seg.emplace_back(u.dot(p), v.dot(p));
      heights.push_back(h);
    }
  }
  if (seg.size() < 3) return;
  Eigen::Vector2f seg_mean;
  const float seg_angle = principal_angle(seg, seg_mean);
  // The seeds are centred on the segment's top: its points within
  // kRestTopBand of its top height (the 97th percentile, past outliers) are
  // laid over the part's samples within kRestTopBand of its top. The top is
  // what the camera sees whole; the segment's centre moves with the side
  // faces an off-centre camera also sees (measured on 36 L-brackets lying on
  // their side or standing, up to 17 cm off the optical axis: 6 not found
  // with this centring, 7 with the segment's centre).
  std::vector<float> sorted = heights;
  const size_t q = std::min(sorted.size() - 1, static_cast<size_t>(0.97 * static_cast<double>(sorted.size())));
  std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(q), sorted.end());
  const float seg_top = sorted[q];
  Eigen::Vector2f top_mean = Eigen::Vector2f::Zero();
  int top_count = 0;
  for (size_t i = 0; i < seg.size(); ++i) {
    if (heights[i] >= seg_top - kRestTopBand && heights[i] <= seg_top + kRestTopBand) {
      top_mean += seg[i];
      ++top_count;
    }
  }
  top_mean /= static_cast<float>(std::max(1, top_count));
  const Eigen::Vector3f top_in_plane = u * top_mean.x() + v * top_mean.y();
  // A part leaning on a neighbour or a wall rests a few degrees off the floor
  // (measured in cleared piles: L-brackets on their side tilted 3-9 deg,
  // which ICP from a flat seed did not recover on 5 mm edges). The mean
  // normal of the segment's upward faces (within kTiltedFaceDeg of the floor
  // normal) gives the tilt; above kMinSeedTiltDeg, every seed gets a tilted
  // copy whose upward faces' centroid sits on the segment's.
  Eigen::Vector3f up_normal = Eigen::Vector3f::Zero();
  const float cos_face = static_cast<float>(std::cos(kTiltedFaceDeg * kDeg));
  for (const auto& nn : sub_n) {
    if (nn.dot(n) > cos_face) up_normal += nn;
  }
  std::optional<Eigen::Matrix3f> R_tilt;
  Eigen::Vector3f up_centroid = Eigen::Vector3f::Zero();
  if (up_normal.norm() > 0) {
    up_normal.normalize();
    if (up_normal.dot(n) < static_cast<float>(std::cos(kMinSeedTiltDeg * kDeg))) {
      int count = 0;
      for (size_t i = 0; i < sub_p.size(); ++i) {
        if (sub_n[i].dot(up_normal) > cos_face) {
          up_centroid += sub_p[i];
          ++count;
        }
      }
      if (count >= 3) {
        up_centroid /= static_cast<float>(count);
        R_tilt = Eigen::Quaternionf::FromTwoVectors(n, up_normal).toRotationMatrix();
      }
    }
  }
  for (const RestingPose& rest : rests) {
    // R0 turns the resting direction onto -n.
    const Eigen::Matrix3f R0 = Eigen::Quaternionf::FromTwoVectors(rest.down, -n).toRotationMatrix();
    std::vector<Eigen::Vector2f> top;
    top.reserve(ppf_points.size());
    for (const auto& p : ppf_points.points) {
      const Eigen::Vector3f q = R0 * p;
      top.emplace_back(u.dot(q), v.dot(q));
    }
    Eigen::Vector2f model_mean;
    const float model_angle = principal_angle(top, model_mean);
    std::vector<float> yaws = {seg_angle - model_angle, seg_angle - model_angle + static_cast<float>(M_PI)};
    const bool spins_freely = symmetry.kind == Symmetry::Kind::kRevolute &&
                              std::abs(rest.down.dot(symmetry.axis.cast<float>().normalized())) > 0.999f;
    if (!spins_freely) {
      for (int k = 0; k < 36; ++k) yaws.push_back(static_cast<float>(k * 10 * kDeg));
    } else {
      yaws.resize(1);
    }
    for (const float yaw : yaws) {
      const Eigen::Matrix3f R = Eigen::AngleAxisf(yaw, n).toRotationMatrix() * R0;
      const Eigen::Vector3f c = R * rest.top_O;
      // In the plane: the part's top over the segment's. Along n: the
      // lowest samples (n . R p = -rest.depth) on the plane.
      const Eigen::Vector3f t = top_in_plane - (c - n * n.dot(c)) + n * (rest.depth - d);
      internal::CoarsePose cp;
      cp.X_BO = Pose::Identity();
      cp.X_BO.linear() = R.cast<double>();
      cp.X_BO.translation() = t.cast<double>();
      coarse.push_back(cp);
      if (R_tilt) {
        const Eigen::Matrix3f Rt = *R_tilt * R;
        cp.X_BO.linear() = Rt.cast<double>();
        cp.X_BO.translation() = (up_centroid - Rt * rest.up_O).cast<double>();
        coarse.push_back(cp);
      }
    }
  }
}

void PoseEstimator::Impl::AppendFaceSeeds(std::span<const Eigen::Vector3f> scene, const Eigen::Vector3f& n,
                                          const SceneView& view, const SceneSupport& support,
                                          const SegmentDepth& segment_depth, int keep,
                                          std::vector<internal::CoarsePose>& coarse) const {
  Eigen::Vector3f c, a, b;
  Eigen::Vector2f lo, hi;
  PlaneFrame(scene, n, &c, &a, &b, &lo, &hi);
  // The view in its plane, (a, b) coordinates about c.
  std::vector<Eigen::Vector2f> q;
  q.reserve(scene.size());
  for (const auto& p : scene) q.emplace_back(a.dot(p - c), b.dot(p - c));
  // In-plane directions to align a face's axes with: the view's principal
  // axis, and its convex hull's long edges (a partly hidden face keeps some
  // of its straight edges; its principal axes turn with what is hidden).
  // Directions modulo 90 deg: each is tried in its four quarter turns.
  std::vector<float> angles = {0.f};
  {
    const std::vector<Eigen::Vector2f> hull = ConvexHull2(q);
    std::vector<std::pair<float, float>> edges;  // (length, angle mod 90 deg)
    for (size_t i = 0; i < hull.size(); ++i) {
      const Eigen::Vector2f e = hull[(i + 1) % hull.size()] - hull[i];
      float ang = std::atan2(e.y(), e.x());
      ang = std::fmod(ang + static_cast<float>(4 * M_PI), static_cast<float>(M_PI / 2));
      edges.emplace_back(e.norm(), ang);
    }
    std::stable_sort(edges.begin(), edges.end(), [](const auto& x, const auto& y) { return x.first > y.first; });
    const float same = static_cast<float>(kFaceEdgeMergeDeg * kDeg), quarter = static_cast<float>(M_PI / 2);
    for (const auto& [len, edge_ang] : edges) {
      if (len < kMinFaceExtent || static_cast<int>(angles.size()) > kFaceEdgeDirections) break;
      const float ang = edge_ang;  // a copy: clang 14 cannot capture a structured binding
      const bool known = std::any_of(angles.begin(), angles.end(), [&](float x) {
        const float d = std::abs(x - ang);
        return std::min(d, quarter - d) < same;
      });
      if (!known) angles.push_back(ang);
    }
  }
  const float tol = 0.004f;  // box slack: depth noise and normal outliers along the view's border
  const Eigen::Vector3f axis = symmetry.axis.cast<float>().normalized();
  std::vector<std::pair<double, internal::CoarsePose>> seeds;
  for (const PlanarFace& f : faces) {
    const Eigen::Vector2f fext = f.hi - f.lo;
    // A face a revolute part's axis is normal to looks the same at every turn.
    const bool round = symmetry.kind == Symmetry::Kind::kRevolute && std::abs(f.n.dot(axis)) > 0.999f;
    for (size_t di = 0; di < (round ? 1 : angles.size()); ++di) {
      for (int k = 0; k < (round ? 1 : 4); ++k) {
        const float th = angles[di] + static_cast<float>(k * M_PI / 2);
        const Eigen::Vector2f dx(std::cos(th), std::sin(th)), dy(-dx.y(), dx.x());
        const Eigen::Vector3f x = dx.x() * a + dx.y() * b;
        const Eigen::Vector3f y = n.cross(x);  // = dy.x() a + dy.y() b
        // The view's box in (x, y) about c; the face's box must hold it.
        Eigen::Vector2f vlo = Eigen::Vector2f::Constant(std::numeric_limits<float>::infinity()), vhi = -vlo;
        for (const Eigen::Vector2f& p : q) {
          const Eigen::Vector2f r(p.dot(dx), p.dot(dy));
          vlo = vlo.cwiseMin(r);
          vhi = vhi.cwiseMax(r);
        }
        if ((vhi - vlo).x() > fext.x() + tol || (vhi - vlo).y() > fext.y() + tol) continue;
        Eigen::Matrix3f S, F;
        S << x, y, n;
        F << f.u, f.v, f.n;
        const Eigen::Matrix3f R = S * F.transpose();
        // Per axis: centre on centre when the face is no larger than the view
        // (within tol); else two placements, the boxes' low or high edges together.
        std::vector<float> off[2];
        for (int e = 0; e < 2; ++e) {
          if (fext[e] - (vhi[e] - vlo[e]) < tol) {
            off[e].push_back(0.5f * (vlo[e] + vhi[e]) - 0.5f * (f.lo[e] + f.hi[e]));
          } else {
            off[e].push_back(vlo[e] - f.lo[e]);
            off[e].push_back(vhi[e] - f.hi[e]);
          }
        }
        for (float ox : off[0]) {
          for (float oy : off[1]) {
            // The face centroid goes to c + ox x + oy y.
            internal::CoarsePose cp;
            cp.X_BO = Pose::Identity();
            cp.X_BO.linear() = R.cast<double>();
            cp.X_BO.translation() = (c + ox * x + oy * y - R * f.c).cast<double>();
            const VerifyStats st = Verify(cp.X_BO, view, support, segment_depth, kFaceSeedScreenStride);
            if (st.below_support || !(st.score > 0)) continue;
            seeds.emplace_back(st.score, cp);
          }
        }
      }
    }
  }
  const auto by_score = [](const auto& p, const auto& q) { return p.first > q.first; };
  std::stable_sort(seeds.begin(), seeds.end(), by_score);
  if (seeds.size() > kFaceSeedsScreened) seeds.resize(kFaceSeedsScreened);
  for (auto& [score, cp] : seeds) score = Verify(cp.X_BO, view, support, segment_depth, kFaceSeedStride).score;
  std::stable_sort(seeds.begin(), seeds.end(), by_score);
  for (size_t i = 0; i < seeds.size() && static_cast<int>(i) < keep; ++i) coarse.push_back(seeds[i].second);
}

Result<std::unique_ptr<PoseEstimator>> PoseEstimator::Build(const TriangleMesh& mesh, const Symmetry& symmetry,
                                                            const PoseEstimatorOptions& options) {
  std::string error;
  if (!options.IsValid(&error)) return Status::InvalidArgument("PoseEstimatorOptions: " + error);
  if (mesh.empty()) return Status::InvalidArgument("pose estimator: empty mesh");
  if (symmetry.kind != Symmetry::Kind::kNone && !(symmetry.axis.norm() > 1e-9)) {
    return Status::InvalidArgument("pose estimator: symmetry axis is zero");
  }
  auto impl = std::make_unique<Impl>();
  impl->options = options;
  impl->symmetry = symmetry;
  impl->dense = internal::SampleSurface(mesh, options.icp_model_spacing, kSamplingSeed);
  if (impl->dense.size() < 100) {
    return Status::InvalidArgument("pose estimator: mesh has (almost) no surface area at spacing " +
                                   std::to_string(options.icp_model_spacing) + " m");
  }
  impl->diameter = internal::PointSetDiameter(impl->dense.points);
  if (!(impl->diameter > 0) || !std::isfinite(impl->diameter)) {
    return Status::InvalidArgument("pose estimator: degenerate mesh (zero or non-finite diameter)");
  }
  impl->step = static_cast<float>(options.ppf_relative_sampling * impl->diameter);
  for (const auto& p : impl->dense.points) impl->centroid_O += p;
  impl->centroid_O /= static_cast<float>(impl->dense.size());

  impl->rests = RestingPoses(mesh, impl->dense.points, impl->centroid_O, symmetry,
                                  static_cast<float>(2 * options.icp_model_spacing));
  impl->verify = internal::VoxelDownsample(impl->dense, options.verify_model_spacing, 45.0);
  impl->ppf_points = internal::VoxelDownsample(impl->dense, impl->step, 30.0);
  impl->faces = PlanarFaces(mesh, impl->dense, static_cast<float>(options.hole_margin), &impl->holes);
  impl->ppf_extreme = ExtremePoints(impl->ppf_points.points);
  impl->verify_extreme = ExtremePoints(impl->verify.points);
  const float cos_face = static_cast<float>(std::cos(kTiltedFaceDeg * kDeg));
  for (RestingPose& rest : impl->rests) {
    // Top: samples within kRestTopBand of the highest (heights along -down).
    // Upward faces: normals within kTiltedFaceDeg of -down.
    const OrientedPoints& s = impl->ppf_points;
    float highest = std::numeric_limits<float>::infinity();
    for (const auto& p : s.points) highest = std::min(highest, rest.down.dot(p));
    int top = 0, up = 0;
    for (size_t i = 0; i < s.size(); ++i) {
      if (rest.down.dot(s.points[i]) <= highest + kRestTopBand) {
        rest.top_O += s.points[i];
        ++top;
      }
      if (-s.normals[i].dot(rest.down) > cos_face) {
        rest.up_O += s.points[i];
        ++up;
      }
    }
    rest.top_O /= static_cast<float>(std::max(1, top));
    rest.up_O /= static_cast<float>(std::max(1, up));
  }
  // The ICP structures below (field, edge planes) index the dense samples in this order.
  SortByMortonCode(impl->dense);
  const float band = std::max(static_cast<float>(options.icp_initial_relative_distance) * impl->step,
                              static_cast<float>(2 * options.icp_final_distance));
  impl->field.Build(impl->dense.points, std::max(0.001f, static_cast<float>(options.icp_model_spacing)), band);
  {
    // Hole points on or next to other parts of the surface (the bore's wall
    // where it meets the face's plane) say nothing.
    const float margin = static_cast<float>(options.hole_margin);
    std::erase_if(impl->holes, [&](const HolePoint& h) { return impl->OnSurface(h.p, margin); });
  }

  {
    // Convex sharp edges: neighbours whose normal is > 30 deg off and that lie
    // below this sample's tangent plane belong to the face across the edge;
    // their mean normal and offset give that face's plane.
    internal::PointHash dense_hash;
    const float r = 2.5f * static_cast<float>(options.icp_model_spacing);
    dense_hash.Build(impl->dense.points, r);
    const float cos30 = std::cos(static_cast<float>(30.0 * M_PI / 180.0));
    impl->edge_planes.assign(impl->dense.size(), internal::EdgePlane{});
    for (size_t i = 0; i < impl->dense.size(); ++i) {
      const Eigen::Vector3f& p = impl->dense.points[i];
      const Eigen::Vector3f& n = impl->dense.normals[i];
      Eigen::Vector3f n_sum = Eigen::Vector3f::Zero(), p_sum = Eigen::Vector3f::Zero();
      int k = 0;
      dense_hash.ForEachWithin(p, r, [&](int j, float d2) {
        if (d2 <= 0.f) return;
        if (n.dot(impl->dense.normals[j]) < cos30 && (impl->dense.points[j] - p).dot(n) < -0.1f * std::sqrt(d2)) {
          n_sum += impl->dense.normals[j];
          p_sum += impl->dense.points[j];
          ++k;
        }
      });
      if (k > 0 && n_sum.norm() > 1e-3f) {
        const Eigen::Vector3f no = n_sum.normalized();
        impl->edge_planes[i] = internal::EdgePlane{no, no.dot(p_sum / static_cast<float>(k))};
      }
    }
  }

  impl->near_symmetries = impl->NearSymmetries();

  internal::PpfParams params;
  params.distance_step = impl->step;
  params.angle_bins = static_cast<int>(std::lround(180.0 / options.ppf_angle_step_deg));
  params.alpha_bins = 2 * params.angle_bins;
  params.max_bucket_entries = options.ppf_max_bucket_entries;
  if (Status s = impl->ppf.Build(impl->ppf_points.points, impl->ppf_points.normals, params,
                                 static_cast<float>(impl->diameter * 1.001));
      !s.ok()) {
    return Status::InvalidArgument("pose estimator: " + s.message() + " (ppf_relative_sampling too small?)");
  }
  return std::unique_ptr<PoseEstimator>(new PoseEstimator(std::move(impl)));
}

VerifyStats PoseEstimator::Impl::Verify(const Pose& X_BO, const SceneView& view,
                                        const SceneSupport& scene,
                                        const SegmentDepth& segment_depth, int stride,
                                        bool unmeasured_is_no_evidence) const {
  VerifyStats s;
  const Eigen::Matrix3f R = X_BO.linear().cast<float>();
  const Eigen::Vector3f t = X_BO.translation().cast<float>();
  if (view.support_plane_B) {
    const Eigen::Vector3f n = view.support_plane_B->head<3>().cast<float>();
    const float d = static_cast<float>((*view.support_plane_B)[3]);
    const float limit = -static_cast<float>(options.max_support_penetration);
    for (const auto& p : verify_extreme) {
      if (n.dot(R * p + t) + d < limit) {
        s.below_support = true;
        return s;
      }
    }
  }
  const Eigen::Vector3f c = view.X_BC.translation().cast<float>();
  const float min_cos = static_cast<float>(options.visible_min_cos);

  // 1. Camera-facing points.
  struct Cand {
    Eigen::Vector3f p;
    float cos;
  };
  std::vector<Cand> cands;
  cands.reserve(verify.size() / 2 + 1);
  // Most samples that face away are rejected in O first, without the
  // transform, the root or the division; the margin leaves every sample near
  // the limit to the exact test in B below, so the result is the same.
  const Eigen::Vector3f c_O = R.transpose() * (c - t);
  const bool prefilter = min_cos > 0.01f;
  const float lo = min_cos - 1e-3f, lo2 = lo * lo;
  for (size_t i = 0; i < verify.size(); i += static_cast<size_t>(std::max(1, stride))) {
    if (prefilter) {
      const Eigen::Vector3f v = c_O - verify.points[i];
      const float dot = verify.normals[i].dot(v);
      if (dot <= 0.f || dot * dot < lo2 * v.squaredNorm()) continue;
    }
    const Eigen::Vector3f p = R * verify.points[i] + t;
    const Eigen::Vector3f n = R * verify.normals[i];
    const Eigen::Vector3f to_cam = c - p;
    const float dist = to_cam.norm();
    const float cs = n.dot(to_cam) / std::max(dist, 1e-9f);
    if (cs >= min_cos) cands.push_back({p, cs});
  }
  if (cands.empty()) return s;

  // 2. Self-occlusion: splat into a small angular depth buffer seen from the camera.
  const Eigen::Vector3f o = R * centroid_O + t;
  const Eigen::Vector3f z = (o - c).normalized();
  const Eigen::Vector3f x = z.unitOrthogonal();
  const Eigen::Vector3f y = z.cross(x);
  const float range = std::max((o - c).norm(), 1e-3f);
  const float cell_m = 1.5f * static_cast<float>(options.verify_model_spacing) * std::sqrt(static_cast<float>(std::max(1, stride)));
  const float cell_ang = cell_m / range;
  const int half = static_cast<int>(std::ceil(1.2 * diameter / cell_m)) + 2;
  const int N = 2 * half + 1;
  std::vector<float> zbuf(static_cast<size_t>(N) * N, std::numeric_limits<float>::infinity());
  std::vector<int> cell_of(cands.size(), -1);
  for (size_t i = 0; i < cands.size(); ++i) {
    const Eigen::Vector3f v = cands[i].p - c;
    const float d = v.dot(z);
    if (d <= 0) continue;
    const int u = internal::FloorToInt(v.dot(x) / d / cell_ang) + half;
    const int w = internal::FloorToInt(v.dot(y) / d / cell_ang) + half;
    if (u < 0 || w < 0 || u >= N || w >= N) continue;
    cell_of[i] = w * N + u;
    zbuf[cell_of[i]] = std::min(zbuf[cell_of[i]], d);
  }

  const bool have_depth = view.depth != nullptr && !view.depth->empty() && view.intrinsics.valid();
  const Pose X_CB = view.X_BC.inverse();
  const Eigen::Matrix3f R_CB = X_CB.linear().cast<float>();
  const Eigen::Vector3f t_CB = X_CB.translation().cast<float>();
  const float support = static_cast<float>(options.support_distance);
  const float free_thr = static_cast<float>(options.free_space_distance);
  for (size_t i = 0; i < cands.size(); ++i) {
    if (cell_of[i] < 0) continue;
    const float cs = cands[i].cos;
    const float tan_theta = std::sqrt(std::max(0.f, 1 - cs * cs)) / cs;
    const float d = (cands[i].p - c).dot(z);
    if (d > zbuf[cell_of[i]] + cell_m * (0.5f + tan_theta)) continue;  // hidden by the part itself
    ++s.visible;
    bool supported = false;
    if (have_depth) {
      // O(1) through the depth image first; the segment's points only when
      // the pixel disagrees.
      const Eigen::Vector3f pc = R_CB * cands[i].p + t_CB;
      const Intrinsics& K = view.intrinsics;
      int u = 0, v = 0;
      if (PixelOf(K, *view.depth, pc, &u, &v)) {
        const float zm = view.depth->at(u, v);
        if (std::isfinite(zm) && zm > 0) {
          // Slanted surfaces change depth by about a pixel footprint * tan(theta).
          const float slack = static_cast<float>(pc.z() / K.fx) * tan_theta;
          supported = std::abs(zm - pc.z()) < support + slack;
          if (!supported) supported = scene.AnyWithin(cands[i].p, support, pc, u, v, view);
          if (!supported) {
            if (zm < pc.z() - free_thr - slack) {
              ++s.occluded;
            } else if (zm > pc.z() + free_thr + slack && FreeAround(*view.depth, u, v, pc.z() + free_thr + slack,
                                                                     kFreeSpaceReach * K.fx / pc.z())) {
              ++s.free_space;
            }
          }
        } else {
          supported = scene.AnyWithin(cands[i].p, support, pc, u, v, view);
          if (!supported && cs < kGrazingCos) ++s.unmeasured;
        }
      }
    } else {
      supported = scene.hash.AnyWithin(cands[i].p, support);
    }
    if (!have_depth && !supported && !segment_depth.empty()) {
      // The segment's nearest surface along the ray: in front of it by more
      // than the threshold is free space; behind it, occluded by the segment.
      float dp = 0;
      const float zm = segment_depth.At(cands[i].p, &dp);
      if (std::isfinite(zm)) {
        const float slack = segment_depth.cell_ang * dp * tan_theta;
        if (dp < zm - free_thr) ++s.free_space;
        else if (dp > zm + free_thr + slack) ++s.occluded;
      }
    }
    if (supported) ++s.supported;
  }
  const int denom = s.visible - s.occluded - (unmeasured_is_no_evidence ? s.unmeasured : 0);
  if (denom > 0) {
    s.score = (s.supported - options.free_space_weight * s.free_space) / static_cast<double>(denom);
  }
  return s;
}

std::pair<int, int> PoseEstimator::Impl::HoleStats(const Pose& X_BO, const SceneView& view) const {
  int in_view = 0, filled = 0;
  if (holes.empty() || view.depth == nullptr || view.depth->empty() || !view.intrinsics.valid()) return {0, 0};
  const Eigen::Matrix3f R = X_BO.linear().cast<float>();
  const Eigen::Vector3f t = X_BO.translation().cast<float>();
  const Eigen::Vector3f c = view.X_BC.translation().cast<float>();
  const Pose X_CB = view.X_BC.inverse();
  const Eigen::Matrix3f R_CB = X_CB.linear().cast<float>();
  const Eigen::Vector3f t_CB = X_CB.translation().cast<float>();
  // Measured points back to O: p_O = R^T (X_BC p_C - t).
  const Eigen::Matrix3f R_OC = R.transpose() * view.X_BC.linear().cast<float>();
  const Eigen::Vector3f t_OC = R.transpose() * (view.X_BC.translation().cast<float>() - t);
  const Intrinsics& K = view.intrinsics;
  const float support = static_cast<float>(options.support_distance);
  const float free_thr = static_cast<float>(options.free_space_distance);
  const float margin = static_cast<float>(options.hole_margin);
  for (const HolePoint& h : holes) {
    const Eigen::Vector3f p = R * h.p + t;
    const Eigen::Vector3f to_cam = c - p;
    const float dist = to_cam.norm();
    const float cs = (R * h.n).dot(to_cam) / std::max(dist, 1e-9f);
    if (cs < kHoleMinCos) continue;
    const Eigen::Vector3f pc = R_CB * p + t_CB;
    int u = 0, v = 0;
    if (!PixelOf(K, *view.depth, pc, &u, &v)) continue;
    const float zm = view.depth->at(u, v);
    if (!std::isfinite(zm) || !(zm > 0)) continue;
    const float slack = static_cast<float>(pc.z() / K.fx) * std::sqrt(std::max(0.f, 1 - cs * cs)) / cs;
    if (zm < pc.z() - free_thr - slack) continue;  // something in front: no evidence
    ++in_view;
    if (std::abs(zm - pc.z()) >= support + slack) continue;
    const Eigen::Vector3f m_C = Deproject(K, static_cast<float>(u), static_cast<float>(v), zm);
    if (!OnSurface(R_OC * m_C + t_OC, margin)) ++filled;
  }
  return {in_view, filled};
}

Result<PoseHypothesis> PoseEstimator::Score(const SceneView& view, const Pose& X_BO) const {
  const Impl& m = *impl_;
  if (!X_BO.matrix().allFinite()) return Status::InvalidArgument("Score: X_BO is not finite");
  std::vector<Eigen::Vector3f> pts;
  for (const Eigen::Vector3f& p : view.points_B) {
    if (p.allFinite()) pts.push_back(p);
  }
  SceneSupport support;
  support.Build(pts, 2.f * static_cast<float>(m.options.support_distance), view);
  const bool have_depth = view.depth != nullptr && !view.depth->empty() && view.intrinsics.valid();
  const SegmentDepth segment_depth =
      have_depth || pts.empty()
          ? SegmentDepth{}
          : BuildSegmentDepth(pts, view.X_BC.translation().cast<float>(), 1.5f * static_cast<float>(m.options.verify_model_spacing));
  const VerifyStats st = m.Verify(X_BO, view, support, segment_depth, 1, false);
  PoseHypothesis h;
  h.X_BO = X_BO;
  h.score = st.below_support ? -1.0 : st.score;
  h.visible_points = st.visible;
  h.occluded_points = st.occluded;
  h.supported_points = st.supported;
  h.free_space_points = st.free_space;
  h.unmeasured_points = st.unmeasured;
  std::tie(h.hole_points, h.filled_hole_points) = m.HoleStats(X_BO, view);
  return h;
}

bool PoseEstimator::Impl::Prepare(const SceneView& view, PreparedView& w, PoseEstimates& out) const {
  const Impl& m = *this;
  const PoseEstimatorOptions& opt = options;
  w.owner = this;
  w.input_points = view.points_B.size();
  const auto t0 = Clock::now();

  // Finite points only; keep their original indices for supporting_indices.
  std::vector<Eigen::Vector3f>& pts = w.pts;
  std::vector<int>& index = w.index;
  pts.reserve(view.points_B.size());
  index.reserve(view.points_B.size());
  for (size_t i = 0; i < view.points_B.size(); ++i) {
    if (view.points_B[i].allFinite()) {
      pts.push_back(view.points_B[i]);
      index.push_back(static_cast<int>(i));
    }
  }
  out.scene_points = static_cast<int>(pts.size());
  if (static_cast<int>(pts.size()) < kMinScenePoints) {
    out.no_result_reason = "too few finite points in the segment (" + std::to_string(pts.size()) + ", need " +
                           std::to_string(kMinScenePoints) + ")";
    return false;
  }
  // Degenerate geometry: spread along fewer than two directions. A view
  // that is one plane (its normal towards the camera in view_plane) gets face
  // seeds (PoseSearch::face_seeds).
  std::optional<Eigen::Vector3f>& view_plane = w.view_plane;
  {
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const auto& p : pts) mean += p.cast<double>();
    mean /= static_cast<double>(pts.size());
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    for (const auto& p : pts) {
      const Eigen::Vector3d d = p.cast<double>() - mean;
      C += d * d.transpose();
    }
    C /= static_cast<double>(pts.size());
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C);
    const Eigen::Vector3d ev = es.eigenvalues().cwiseMax(0.0);  // ascending
    if (std::sqrt(ev[0]) < kPlanarViewRms) {
      Eigen::Vector3f n = es.eigenvectors().col(0).cast<float>();
      if (n.dot(view.X_BC.translation().cast<float>() - mean.cast<float>()) < 0) n = -n;
      view_plane = n;
    }
    const double min_spread = 0.05 * m.step;
    if (std::sqrt(ev[1]) < min_spread) {
      out.no_result_reason = "degenerate segment: points are (nearly) collinear";
      return false;
    }
    if (std::sqrt(ev[2]) < 0.05 * m.diameter) {
      out.no_result_reason = "segment is much smaller than the part";
      return false;
    }
  }

  // Scene hash (PCA normals, when the view has none), voxel subsampling at the PPF distance step.
  internal::PointHash hash;  // normal estimation: radius step visits 2 x 2 x 2 cells
  if (view.normals_B.empty()) hash.Build(pts, 2.f * m.step);
  const Eigen::Vector3f cam = view.X_BC.translation().cast<float>();
  std::vector<Eigen::Vector3f>& sub_p = w.sub_p;
  std::vector<Eigen::Vector3f>& sub_n = w.sub_n;
  // Per finite point: index of its voxel's subsampled point, -1 if none.
  std::vector<int> sub_of(pts.size(), -1);
  {
    // The points per voxel of the PPF step, voxels in key order, points in index order.
    internal::PointHash voxels;
    voxels.Build(pts, m.step);
    const std::span<const uint32_t> order = voxels.order();
    for (const auto& [k, e] : voxels.CellRunsByKey()) {
      Eigen::Vector3f sum = Eigen::Vector3f::Zero();
      Eigen::Vector3f nsum = Eigen::Vector3f::Zero();
      for (uint32_t j = k; j < e; ++j) {
        const uint32_t i = order[j];
        sum += pts[i];
        if (!view.normals_B.empty()) {
          Eigen::Vector3f n = view.normals_B[index[i]];
          if (n.allFinite()) nsum += (n.dot(cam - pts[i]) < 0 ? -n : n);
        }
      }
      const Eigen::Vector3f centre = sum / static_cast<float>(e - k);
      Eigen::Vector3f normal;
      if (!view.normals_B.empty()) {
        if (nsum.norm() < 1e-6f) continue;
        normal = nsum.normalized();
      } else {
        // PCA over full-resolution neighbours within one step.
        Eigen::Vector3d mean = Eigen::Vector3d::Zero();
        Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
        int n = 0;
        hash.ForEachWithin(centre, m.step, [&](int j, float) {
          const Eigen::Vector3d p = pts[j].cast<double>();
          mean += p;
          S += p * p.transpose();
          ++n;
        });
        if (n < 5) continue;
        mean /= n;
        S = S / n - mean * mean.transpose();
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(S);
        if (es.info() != Eigen::Success) continue;
        // Flat enough to carry a normal: smallest eigenvalue well below the middle one.
        if (!(es.eigenvalues()[1] > 0) || es.eigenvalues()[0] > 0.5 * es.eigenvalues()[1]) continue;
        normal = es.eigenvectors().col(0).cast<float>();
        if (normal.dot(cam - centre) < 0) normal = -normal;
      }
      if (!normal.allFinite() || !centre.allFinite()) continue;
      for (uint32_t j = k; j < e; ++j) sub_of[order[j]] = static_cast<int>(sub_p.size());
      sub_p.push_back(centre);
      sub_n.push_back(normal);
    }
  }
  out.sampled_points = static_cast<int>(sub_p.size());
  out.timings.prepare_ms = Ms(t0, Clock::now());
  if (static_cast<int>(sub_p.size()) < kMinSampledPoints) {
    out.no_result_reason = "too few subsampled points with a normal (" + std::to_string(sub_p.size()) + ")";
    return false;
  }

  const auto t_aux = Clock::now();
  const bool have_depth = view.depth != nullptr && !view.depth->empty() && view.intrinsics.valid();
  if (!have_depth) w.segment_depth = BuildSegmentDepth(pts, cam, 1.5f * static_cast<float>(opt.verify_model_spacing));
  // Support queries (radius support_distance) visit 2 x 2 x 2 cells of this.
  w.support.Build(pts, 2.f * static_cast<float>(opt.support_distance), view);
  // Boundary flags on the subsampled points; a full-resolution point takes its
  // voxel's flag (the ICP boundary term is one-sided, so flagging a few
  // millimetres of interior next to an edge costs nothing).
  internal::PointHash sub_hash;
  sub_hash.Build(sub_p, 4.f * m.step);
  std::vector<uint8_t>& sub_boundary = w.sub_boundary;
  sub_boundary = BoundaryFlags(sub_p, sub_p, sub_hash, 2.f * m.step);
  // Fine ICP points: every boundary point (they carry the in-plane
  // constraints) plus the rest strided to about icp_max_points in all.
  std::vector<Eigen::Vector3f>& fine = w.fine;
  std::vector<uint8_t>& fine_boundary = w.fine_boundary;
  {
    size_t n_boundary = 0;
    for (size_t i = 0; i < pts.size(); ++i) n_boundary += sub_of[i] < 0 || sub_boundary[sub_of[i]];
    const size_t budget = std::max<size_t>(static_cast<size_t>(opt.icp_max_points), n_boundary + 1) - n_boundary;
    const size_t interior = pts.size() - n_boundary;
    const size_t stride = std::max<size_t>(1, (interior + budget - 1) / budget);
    size_t seen = 0;
    for (size_t i = 0; i < pts.size(); ++i) {
      const bool b = sub_of[i] < 0 || sub_boundary[sub_of[i]];
      if (b || (seen++ % stride) == 0) {
        fine.push_back(pts[i]);
        fine_boundary.push_back(b ? 1 : 0);
      }
    }
  }
  out.timings.prepare_ms += Ms(t_aux, Clock::now());
  return true;
}

PoseSearch PoseEstimator::default_search() const {
  PoseSearch search;
  search.max_reference_points = impl_->options.max_reference_points;
  search.max_coarse_poses = impl_->options.max_coarse_poses;
  search.stop_score = impl_->options.coarse_stop_score;
  return search;
}

Result<PoseEstimates> PoseEstimator::Estimate(const SceneView& view) const {
  return Estimate(view, default_search());
}

Result<PoseEstimates> PoseEstimator::Estimate(const SceneView& view, const PoseSearch& search) const {
  const Impl& m = *impl_;
  const PoseEstimatorOptions& opt = m.options;
  PoseEstimates out;
  if (!search.IsValid()) {
    return Status::InvalidArgument(
        "PoseSearch: counts must be >= 1, peaks_examined >= peaks_per_reference and stop_score in [0, 1]");
  }
  if (!view.normals_B.empty() && view.normals_B.size() != view.points_B.size()) {
    return Status::InvalidArgument("SceneView: normals_B has " + std::to_string(view.normals_B.size()) +
                                   " entries for " + std::to_string(view.points_B.size()) + " points");
  }
  if (!view.X_BC.matrix().allFinite()) return Status::InvalidArgument("SceneView: X_BC is not finite");
  if (view.support_plane_B &&
      (!view.support_plane_B->allFinite() || std::abs(view.support_plane_B->head<3>().norm() - 1.0) > 1e-3)) {
    return Status::InvalidArgument("SceneView: support_plane_B needs a finite unit normal");
  }
  // What the view gives before the search (PreparedView): derived here, or
  // an earlier estimate's of the same view (PoseSearch::prepared).
  std::shared_ptr<PreparedView> owned;
  const PreparedView* prepared = search.prepared.get();
  if (prepared != nullptr) {
    if (prepared->owner != impl_.get() || prepared->input_points != view.points_B.size()) {
      return Status::InvalidArgument("PoseSearch: prepared comes from another estimator or view");
    }
  } else {
    owned = std::make_shared<PreparedView>();
    if (!m.Prepare(view, *owned, out)) return out;
    prepared = owned.get();
  }
  if (search.keep_prepared) out.prepared = owned ? std::shared_ptr<const PreparedView>(owned) : search.prepared;
  const std::vector<Eigen::Vector3f>& pts = prepared->pts;
  const std::vector<int>& index = prepared->index;
  const std::optional<Eigen::Vector3f>& view_plane = prepared->view_plane;
  const std::vector<Eigen::Vector3f>& sub_p = prepared->sub_p;
  const std::vector<Eigen::Vector3f>& sub_n = prepared->sub_n;
  const SceneSupport& scene_support = prepared->support;
  const SegmentDepth& segment_depth = prepared->segment_depth;
  const std::vector<uint8_t>& sub_boundary = prepared->sub_boundary;
  const std::vector<Eigen::Vector3f>& fine = prepared->fine;
  const std::vector<uint8_t>& fine_boundary = prepared->fine_boundary;
  out.scene_points = static_cast<int>(pts.size());
  out.sampled_points = static_cast<int>(sub_p.size());
  const auto t1 = Clock::now();

  // Coarse: PPF voting and pose clustering.
  internal::PpfMatchOptions mo;
  mo.reference_stride = std::max(1, static_cast<int>(std::lround(1.0 / opt.reference_fraction)));
  mo.max_reference_points = search.max_reference_points;
  mo.max_partners = opt.ppf_max_partners;
  mo.cluster_translation = opt.cluster_relative_translation * m.diameter;
  mo.cluster_rotation = opt.cluster_rotation_deg * M_PI / 180.0;
  mo.max_poses = 3 * search.max_coarse_poses;
  // With a support plane: points on it are not reference points (the floor
  // would otherwise dominate the votes), and coarse poses that sink the part
  // into it are dropped before refinement.
  std::vector<uint8_t> reference_ok;
  if (view.support_plane_B) {
    const Eigen::Vector3f n = view.support_plane_B->head<3>().cast<float>();
    const float d = static_cast<float>((*view.support_plane_B)[3]);
    reference_ok.resize(sub_p.size());
    for (size_t i = 0; i < sub_p.size(); ++i) reference_ok[i] = n.dot(sub_p[i]) + d > 0.5f * m.step;
  }
  std::function<bool(const Pose&)> above_support;
  if (view.support_plane_B) {
    const Eigen::Vector3f n = view.support_plane_B->head<3>().cast<float>();
    const float d = static_cast<float>((*view.support_plane_B)[3]);
    const float limit = -static_cast<float>(opt.max_support_penetration) - 1.5f * m.step;
    above_support = [&m, n, d, limit](const Pose& X_BO) {
      const Eigen::Matrix3f R = X_BO.linear().cast<float>();
      const Eigen::Vector3f t = X_BO.translation().cast<float>();
      for (const auto& p : m.ppf_extreme) {
        if (n.dot(R * p + t) + d < limit) return false;
      }
      return true;
    };
    mo.accept = above_support;
    mo.peaks_per_reference = search.peaks_per_reference;
    mo.peaks_examined = search.peaks_examined;
  }
  if (owned != nullptr && search.keep_prepared) {
    mo.record = &owned->votes;
    mo.record_peaks = kRecordedPeaks;
  } else if (owned == nullptr) {
    mo.replay = &prepared->votes;
  }
  std::vector<internal::CoarsePose> coarse = m.ppf.Match(sub_p, sub_n, reference_ok, mo, m.symmetry);
  if (above_support) {
    std::erase_if(coarse, [&](const internal::CoarsePose& cp) { return !above_support(cp.X_BO); });
  }
  if (static_cast<int>(coarse.size()) > search.max_coarse_poses) coarse.resize(search.max_coarse_poses);
  if (search.resting_seeds && view.support_plane_B) m.AppendRestingSeeds(pts, sub_p, sub_n, *view.support_plane_B, coarse);
  const auto t2 = Clock::now();
  out.timings.coarse_ms = Ms(t1, t2);
  if (coarse.empty()) {
    out.no_result_reason = "no pose received enough votes";
    return out;
  }

  // Refinement in two passes. Every coarse pose: ICP on the subsampled points,
  // then a quick verification and NMS; the survivors: ICP on the
  // full-resolution points (strided to at most icp_max_points) and the final check.
  const Vec3 camera_B = view.X_BC.translation();
  const float gate0 = static_cast<float>(opt.icp_initial_relative_distance) * m.step;
  const float gate1 = static_cast<float>(opt.icp_final_distance);
  const bool have_depth = view.depth != nullptr && !view.depth->empty() && view.intrinsics.valid();
  struct Candidate {
    Pose X_BO;
    VerifyStats stats;
    internal::IcpResult icp;
    int votes = 0;
    std::pair<int, int> holes{0, 0};  // in view, filled
  };
  double refine_ms = 0, verify_ms = 0;
  auto timed = [](double& acc, auto&& f) {
    const auto a = Clock::now();
    f();
    acc += Ms(a, Clock::now());
  };
  auto by_score = [](const Candidate& a, const Candidate& b) { return a.stats.score > b.stats.score; };
  const double min_score = have_depth ? opt.min_score : opt.min_score_without_depth;
  auto passes = [&](const VerifyStats& st, double min_score) {
    return st.visible - st.occluded - (search.unmeasured_is_no_evidence ? st.unmeasured : 0) >= opt.min_visible_points &&
           st.score >= min_score;
  };
  const double nms = opt.nms_relative_distance * m.diameter;
  auto duplicate_of = [&](const Pose& X, const std::vector<Candidate>& kept) {
    const Eigen::Vector3d centre = X * m.centroid_O.cast<double>();
    for (const Candidate& k : kept) {
      if ((k.X_BO * m.centroid_O.cast<double>() - centre).norm() < nms) return true;
    }
    return false;
  };

  // Coarse poses an earlier estimate of this view refined are left out
  // (PoseSearch::skip_coarse).
  const auto drop_tried = [&](std::vector<internal::CoarsePose>& list) {
    if (search.skip_coarse.empty()) return;
    const double skip_t = opt.cluster_relative_translation * m.diameter;
    const double skip_r = opt.cluster_rotation_deg * M_PI / 180.0;
    const size_t before = list.size();
    std::erase_if(list, [&](const internal::CoarsePose& cp) {
      return std::any_of(search.skip_coarse.begin(), search.skip_coarse.end(), [&](const Pose& X) {
        return (X.translation() - cp.X_BO.translation()).norm() < skip_t &&
               SymmetricRotationError(X, cp.X_BO, m.symmetry) < skip_r;
      });
    });
    out.coarse_skipped += static_cast<int>(before - list.size());
  };
  std::vector<Candidate> first;
  bool stopped = false;
  // The first pass over `list`, in order: ICP on the subsampled points, then
  // a quick verification.
  const auto refine_first = [&](const std::vector<internal::CoarsePose>& list) {
    for (const internal::CoarsePose& cp : list) {
      out.coarse_poses.push_back(cp.X_BO);
      internal::IcpResult icp;
      timed(refine_ms, [&] {
        icp = m.Refine(sub_p, sub_boundary, cp.X_BO, camera_B, gate0, std::max(gate1, 0.5f * m.step),
                       opt.icp_coarse_iterations, opt.icp_coarse_convergence);
      });
      if (!icp.ok) continue;
      Candidate c{icp.X_BO, {}, icp, cp.votes};
      // A screen on fewer samples first (quick_screen_stride): most refined
      // coarse poses are wrong and score far below the pass's bar.
      // The screen's bar is never above the pass's own.
      const double screen_bar = std::min(opt.quick_screen_min_score, kFirstPassScoreFraction * min_score);
      if (screen_bar > 0.0) {
        timed(verify_ms, [&] { c.stats = m.Verify(icp.X_BO, view, scene_support, segment_depth,
                                                       opt.quick_screen_stride, search.unmeasured_is_no_evidence); });
        if (c.stats.score < screen_bar) {
          ++out.screened_out;
          first.push_back(c);
          continue;
        }
      }
      timed(verify_ms, [&] { c.stats = m.Verify(icp.X_BO, view, scene_support, segment_depth, 3,
                                                     search.unmeasured_is_no_evidence); });
      first.push_back(c);
      // A pose this good at a quick look that also explains most of the
      // view ends the first pass (PoseSearch::stop_score): the coarse poses
      // after it have fewer votes and converge to it or fail. A view of two
      // touching parts goes on to the other part.
      if (search.stop_score > 0.0 && c.stats.score >= search.stop_score && passes(c.stats, min_score) &&
          m.ExplainedFraction(c.X_BO, sub_p) >= kStopExplainedFraction) {
        stopped = true;
        return;
      }
    }
  };
  drop_tried(coarse);
  refine_first(coarse);
  // Face seeds come last, and only when no coarse pose ended the pass:
  // each costs a quick verification of its own.
  if (!stopped && search.face_seeds > 0 && view_plane && !m.faces.empty()) {
    std::vector<internal::CoarsePose> seeds;
    timed(verify_ms, [&] { m.AppendFaceSeeds(pts, *view_plane, view, scene_support, segment_depth, search.face_seeds, seeds); });
    drop_tried(seeds);
    refine_first(seeds);
  }
  if (out.coarse_poses.empty()) {
    out.no_result_reason = "every coarse pose was refined by an earlier estimate (PoseSearch::skip_coarse)";
    return out;
  }
  std::stable_sort(first.begin(), first.end(), by_score);
  double best_rejected = -1;
  int below_support = 0, holes_filled = 0;
  std::vector<Candidate> survivors;
  for (const Candidate& c : first) {
    // Loose threshold here: the fine pass usually raises the score.
    if (!passes(c.stats, kFirstPassScoreFraction * min_score)) {
      below_support += c.stats.below_support;
      best_rejected = std::max(best_rejected, c.stats.score);
      continue;
    }
    if (duplicate_of(c.X_BO, survivors)) continue;
    survivors.push_back(c);
    if (static_cast<int>(survivors.size()) >= opt.max_hypotheses) break;
  }
  std::vector<Candidate> finals;
  for (Candidate c : survivors) {
    internal::IcpResult icp;
    timed(refine_ms, [&] {
      icp = m.Refine(fine, fine_boundary, c.X_BO, camera_B, std::max(gate1, 0.75f * m.step), gate1,
                     opt.icp_iterations, opt.icp_convergence);
    });
    if (!icp.ok || !icp.X_BO.matrix().allFinite()) continue;
    const Candidate before = c;
    c.X_BO = icp.X_BO;
    c.icp = icp;
    timed(verify_ms, [&] { c.stats = m.Verify(icp.X_BO, view, scene_support, segment_depth, 1,
                                                   search.unmeasured_is_no_evidence); });
    if (search.keep_better_than_fine && c.stats.score < 0.9) {
      VerifyStats st;
      timed(verify_ms, [&] { st = m.Verify(before.X_BO, view, scene_support, segment_depth, 1,
                                        search.unmeasured_is_no_evidence); });
      if (st.score > c.stats.score) {
        c = before;
        c.stats = st;
      }
    }
    if (!passes(c.stats, min_score)) {
      below_support += c.stats.below_support;
      best_rejected = std::max(best_rejected, c.stats.score);
      continue;
    }
    if (search.near_symmetries && !m.near_symmetries.empty()) {
      // The part turned by a near symmetry may explain the view better (an
      // L-bracket turned over about its upright): a turn that explains
      // nearly as much at a quick look (kNearSymmetryScreen) is refined
      // and replaces the pose when it explains more of the view (supported
      // minus free-space model points) and scores at most
      // near_symmetry_score_slack lower. By score alone the turn that hides
      // more of the part (its denominator) wins: precision fell.
      const auto net = [](const VerifyStats& v) { return v.supported - v.free_space; };
      const Pose X = c.X_BO;
      VerifyStats quick;
      timed(verify_ms, [&] { quick = m.Verify(X, view, scene_support, segment_depth, 3, search.unmeasured_is_no_evidence); });
      for (const Pose& F : m.near_symmetries) {
        VerifyStats q;
        timed(verify_ms, [&] { q = m.Verify(X * F, view, scene_support, segment_depth, 3, search.unmeasured_is_no_evidence); });
        if (net(q) < kNearSymmetryScreen * net(quick)) continue;
        internal::IcpResult alt;
        timed(refine_ms, [&] {
          alt = m.Refine(fine, fine_boundary, X * F, camera_B, std::max(gate1, 0.75f * m.step), gate1,
                         opt.icp_iterations, opt.icp_convergence);
        });
        if (!alt.ok || !alt.X_BO.matrix().allFinite()) continue;
        VerifyStats st;
        timed(verify_ms, [&] { st = m.Verify(alt.X_BO, view, scene_support, segment_depth, 1,
                                          search.unmeasured_is_no_evidence); });
        if (passes(st, min_score) && net(st) > net(c.stats) &&
            st.score >= c.stats.score - opt.near_symmetry_score_slack) {
          c.X_BO = alt.X_BO;
          c.icp = alt;
          c.stats = st;
        }
      }
    }
    if (opt.hole_max_filled < 1 && have_depth) {
      timed(verify_ms, [&] { c.holes = m.HoleStats(c.X_BO, view); });
      if (c.holes.first >= opt.hole_min_visible && c.holes.second > opt.hole_max_filled * c.holes.first) {
        ++holes_filled;
        continue;
      }
    }
    finals.push_back(c);
  }
  std::stable_sort(finals.begin(), finals.end(), by_score);
  std::vector<Candidate> kept;
  for (const Candidate& c : finals) {
    if (duplicate_of(c.X_BO, kept)) continue;
    kept.push_back(c);
    PoseHypothesis h;
    h.X_BO = c.X_BO;
    h.score = c.stats.score;
    h.visible_points = c.stats.visible;
    h.occluded_points = c.stats.occluded;
    h.supported_points = c.stats.supported;
    h.free_space_points = c.stats.free_space;
    h.unmeasured_points = c.stats.unmeasured;
    h.hole_points = c.holes.first;
    h.filled_hole_points = c.holes.second;
    h.rms_residual = c.icp.rms;
    h.coarse_votes = c.votes;
    out.hypotheses.push_back(std::move(h));
  }
  const auto t3 = Clock::now();
  // Supporting scene points of the kept hypotheses.
  const float sup = m.SupportTolerance();
  for (PoseHypothesis& h : out.hypotheses) {
    const Pose X_OB = h.X_BO.inverse();
    const Eigen::Matrix3f R = X_OB.linear().cast<float>();
    const Eigen::Vector3f t = X_OB.translation().cast<float>();
    for (size_t i = 0; i < pts.size(); ++i) {
      if (m.OnSurface(R * pts[i] + t, sup)) h.supporting_indices.push_back(index[i]);
    }
  }
  verify_ms += Ms(t3, Clock::now());
  out.timings.refine_ms = refine_ms;
  out.timings.verify_ms = verify_ms;
  if (out.hypotheses.empty()) {
    std::ostringstream os;
    os << "no hypothesis passed verification (best score " << best_rejected << ", need " << min_score;
    if (below_support > 0) os << "; " << below_support << " below the support plane";
    if (holes_filled > 0) os << "; " << holes_filled << " with the view's surface through their holes";
    os << ")";
    out.no_result_reason = os.str();
  }
  return out;
}

}  // namespace bp
