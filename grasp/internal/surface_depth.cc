#include "grasp/internal/surface_depth.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

namespace bp::internal {

namespace {

// NearestSurfaceDepth (farthest false) or FarthestSurfaceDepth (true).
std::vector<float> SurfaceDepth(const Intrinsics& K, const Pose& X_BC, std::span<const PlacedMesh> meshes,
                                const PixelWindow& window, bool farthest) {
  const float kNone = farthest ? 0.f : std::numeric_limits<float>::infinity();
  std::vector<float> depth(static_cast<size_t>(std::max(0, window.width)) * std::max(0, window.height), kNone);
  if (depth.empty() || window.wanted.size() != depth.size()) return depth;
  const int u_last = window.u0 + window.width - 1, v_last = window.v0 + window.height - 1;
  constexpr double kMinDepth = 0.001;  // m in front of the camera
  const Pose X_CB = X_BC.inverse();
  // The wanted pixels counted over rows and columns: a triangle (or a row
  // of it) over none is skipped in O(1), most of them where rays are few.
  const int W = window.width;
  std::vector<int32_t> sum(static_cast<size_t>(W + 1) * (window.height + 1), 0);
  const auto at = [&sum, W](int x, int y) -> int32_t& { return sum[static_cast<size_t>(y) * (W + 1) + x]; };
  for (int y = 0; y < window.height; ++y) {
    for (int x = 0; x < W; ++x) {
      at(x + 1, y + 1) = window.wanted[static_cast<size_t>(y) * W + x] + at(x + 1, y) + at(x, y + 1) - at(x, y);
    }
  }
  // Wanted pixels in columns a .. b - 1, rows c .. d - 1 (window coordinates).
  const auto count = [&at](int a, int b, int c, int d) { return at(b, d) - at(a, d) - at(b, c) + at(a, c); };
  std::vector<Vec3> p_C;
  for (const PlacedMesh& placed : meshes) {
    if (placed.mesh_O == nullptr) continue;
    const TriangleMesh& mesh = *placed.mesh_O;
    const Pose X_CO = X_CB * placed.X_BO;
    p_C.resize(mesh.vertices.size());
    for (size_t i = 0; i < mesh.vertices.size(); ++i) p_C[i] = X_CO * mesh.vertices[i].cast<double>();
    for (const Eigen::Vector3i& t : mesh.triangles) {
      const std::array<Vec3, 3> c = {p_C[t[0]], p_C[t[1]], p_C[t[2]]};
      if (c[0].z() < kMinDepth || c[1].z() < kMinDepth || c[2].z() < kMinDepth) continue;
      // Facing away (the outward normal of a counter-clockwise triangle
      // away from the camera at C's origin): never the nearest surface of a
      // closed mesh along a ray from outside it; facing the camera: never
      // the farthest (where the ray leaves the mesh).
      const Vec3 n = (c[1] - c[0]).cross(c[2] - c[0]);
      const double n_c0 = n.dot(c[0]);
      if (farthest ? !(n_c0 > 0) : !(n_c0 < 0)) continue;
      // Projected corners (pixel coordinates; pixel (u, v) is the point (u, v)).
      std::array<Eigen::Vector2d, 3> x;
      for (int k = 0; k < 3; ++k) {
        x[k] = Eigen::Vector2d(K.fx * c[k].x() / c[k].z() + K.cx, K.fy * c[k].y() / c[k].z() + K.cy);
      }
      const double area = (x[1] - x[0]).x() * (x[2] - x[0]).y() - (x[1] - x[0]).y() * (x[2] - x[0]).x();
      if (!(std::abs(area) > 1e-12)) continue;  // edge-on (or NaN): no ray meets it inside
      const int a = std::max(window.u0, static_cast<int>(std::ceil(std::min({x[0].x(), x[1].x(), x[2].x()}))));
      const int b = std::min(u_last, static_cast<int>(std::floor(std::max({x[0].x(), x[1].x(), x[2].x()}))));
      const int top = std::max(window.v0, static_cast<int>(std::ceil(std::min({x[0].y(), x[1].y(), x[2].y()}))));
      const int bottom = std::min(v_last, static_cast<int>(std::floor(std::max({x[0].y(), x[1].y(), x[2].y()}))));
      if (a > b || top > bottom) continue;
      const int ca = a - window.u0, cb = b - window.u0 + 1;
      if (count(ca, cb, top - window.v0, bottom - window.v0 + 1) == 0) continue;
      // The ray d = ((u - cx) / fx, (v - cy) / fy, 1) meets the plane
      // n . p = n . c0 at z = n . c0 / n . d.
      const double sign = area > 0 ? 1.0 : -1.0;
      for (int v = top; v <= bottom; ++v) {
        if (count(ca, cb, v - window.v0, v - window.v0 + 1) == 0) continue;
        const size_t row = static_cast<size_t>(v - window.v0) * window.width;
        // The row's span inside the three edges, widened by a pixel each
        // way (rounding); the exact test below decides each pixel.
        double lo = a, hi = b;
        for (int k = 0; k < 3; ++k) {
          const Eigen::Vector2d& p = x[k];
          const Eigen::Vector2d& q = x[(k + 1) % 3];
          // The test below is c - slope * u >= 0.
          const double slope = sign * (q.y() - p.y());
          const double c = sign * ((q.x() - p.x()) * (v - p.y()) + (q.y() - p.y()) * p.x());
          if (slope > 0) {
            hi = std::min(hi, c / slope + 1.0);
          } else if (slope < 0) {
            lo = std::max(lo, c / slope - 1.0);
          }
        }
        if (lo > hi) continue;
        for (int u = static_cast<int>(std::ceil(lo)); u <= static_cast<int>(std::floor(hi)); ++u) {
          if (!window.wanted[row + (u - window.u0)]) continue;
          // Inside (edges included): the pixel on the inner side of each edge.
          bool inside = true;
          for (int k = 0; k < 3 && inside; ++k) {
            const Eigen::Vector2d& p = x[k];
            const Eigen::Vector2d& q = x[(k + 1) % 3];
            inside = sign * ((q.x() - p.x()) * (v - p.y()) - (q.y() - p.y()) * (u - p.x())) >= 0.0;
          }
          if (!inside) continue;
          const double n_d = n.x() * (u - K.cx) / K.fx + n.y() * (v - K.cy) / K.fy + n.z();
          if (!(std::abs(n_d) > 1e-15)) continue;
          const double z = n_c0 / n_d;
          float& out = depth[row + (u - window.u0)];
          if (z > 0 && (farthest ? z > out : z < out)) out = static_cast<float>(z);
        }
      }
    }
  }
  return depth;
}

}  // namespace

std::vector<float> NearestSurfaceDepth(const Intrinsics& K, const Pose& X_BC, std::span<const PlacedMesh> meshes,
                                       const PixelWindow& window) {
  return SurfaceDepth(K, X_BC, meshes, window, /*farthest=*/false);
}

std::vector<float> FarthestSurfaceDepth(const Intrinsics& K, const Pose& X_BC, std::span<const PlacedMesh> meshes,
                                        const PixelWindow& window) {
  return SurfaceDepth(K, X_BC, meshes, window, /*farthest=*/true);
}

}  // namespace bp::internal
