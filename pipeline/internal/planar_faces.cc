#include "pipeline/internal/planar_faces.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "pipeline/internal/model_geometry.h"

namespace bp::internal {

namespace {

constexpr double kDeg = M_PI / 180.0;
// Faces are triangles whose normals agree within this and whose planes within kFacePlaneTol.
constexpr double kFaceNormalDeg = 2.0;
constexpr float kFacePlaneTol = 0.0006f;
// Hole points are laid on a grid of this pitch (metres) in the face's plane.
constexpr float kHolePitch = 0.001f;
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

}  // namespace

double ThinnestPlate(const std::vector<PlanarFace>& faces) {
  double thinnest = std::numeric_limits<double>::infinity();
  for (const PlanarFace& f : faces) {
    for (const PlanarFace& g : faces) {
      if (f.n.dot(g.n) > -0.99f) continue;
      const float t = f.n.dot(f.c - g.c);
      if (!(t > 0.f)) continue;
      const Eigen::Vector3f d = g.c - f.c;
      const Eigen::Vector2f gc(d.dot(f.u), d.dot(f.v));
      if ((gc.array() < f.lo.array()).any() || (gc.array() > f.hi.array()).any()) continue;
      thinnest = std::min(thinnest, static_cast<double>(t));
    }
  }
  return thinnest;
}

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


}  // namespace bp::internal
