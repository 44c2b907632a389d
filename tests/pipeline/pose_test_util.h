// Test and bench helpers for the pose estimator: small procedural meshes and a
// z-buffer rasteriser that samples scenes the way a depth camera sees them
// (one point per pixel on the nearest surface, Gaussian noise along z).
#pragma once

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <utility>
#include <vector>

#include <Eigen/Geometry>  // before core/mesh.h, which needs it

#include "core/cell.h"
#include "core/image.h"
#include "core/mesh.h"
#include "core/pose.h"

namespace bp::testing {

inline void AddQuad(TriangleMesh& m, const Eigen::Vector3f& a, const Eigen::Vector3f& b, const Eigen::Vector3f& c,
                    const Eigen::Vector3f& d) {  // counter-clockwise seen from outside
  const int i = static_cast<int>(m.vertices.size());
  m.vertices.insert(m.vertices.end(), {a, b, c, d});
  m.triangles.emplace_back(i, i + 1, i + 2);
  m.triangles.emplace_back(i, i + 2, i + 3);
}

// TriangleMesh::Append lives in core/mesh.cc (another engineer's); keep the
// helpers independent of it.
inline void AppendMesh(TriangleMesh& m, const TriangleMesh& other) {
  const int off = static_cast<int>(m.vertices.size());
  m.vertices.insert(m.vertices.end(), other.vertices.begin(), other.vertices.end());
  for (const auto& t : other.triangles) m.triangles.push_back(t + Eigen::Vector3i::Constant(off));
}

// Axis-aligned box [lo, hi].
inline TriangleMesh MakeBox(const Eigen::Vector3f& lo, const Eigen::Vector3f& hi) {
  TriangleMesh m;
  const auto P = [&](int x, int y, int z) {
    return Eigen::Vector3f(x ? hi.x() : lo.x(), y ? hi.y() : lo.y(), z ? hi.z() : lo.z());
  };
  AddQuad(m, P(0, 0, 0), P(0, 1, 0), P(1, 1, 0), P(1, 0, 0));  // -z
  AddQuad(m, P(0, 0, 1), P(1, 0, 1), P(1, 1, 1), P(0, 1, 1));  // +z
  AddQuad(m, P(0, 0, 0), P(1, 0, 0), P(1, 0, 1), P(0, 0, 1));  // -y
  AddQuad(m, P(0, 1, 0), P(0, 1, 1), P(1, 1, 1), P(1, 1, 0));  // +y
  AddQuad(m, P(0, 0, 0), P(0, 0, 1), P(0, 1, 1), P(0, 1, 0));  // -x
  AddQuad(m, P(1, 0, 0), P(1, 1, 0), P(1, 1, 1), P(1, 0, 1));  // +x
  return m;
}

// Closed cylinder about z from z0 to z1.
inline TriangleMesh MakeCylinder(float r, float z0, float z1, int segments = 48) {
  TriangleMesh m;
  const int base = 0;
  for (int i = 0; i < segments; ++i) {
    const float a = 2.f * static_cast<float>(M_PI) * i / segments;
    m.vertices.emplace_back(r * std::cos(a), r * std::sin(a), z0);
    m.vertices.emplace_back(r * std::cos(a), r * std::sin(a), z1);
  }
  const int c0 = static_cast<int>(m.vertices.size());
  m.vertices.emplace_back(0, 0, z0);
  m.vertices.emplace_back(0, 0, z1);
  for (int i = 0; i < segments; ++i) {
    const int j = (i + 1) % segments;
    const int a0 = base + 2 * i, a1 = a0 + 1, b0 = base + 2 * j, b1 = b0 + 1;
    m.triangles.emplace_back(a0, b0, b1);
    m.triangles.emplace_back(a0, b1, a1);
    m.triangles.emplace_back(c0, b0, a0);
    m.triangles.emplace_back(c0 + 1, a1, b1);
  }
  return m;
}

// Solid of revolution about z from a profile of (r, z) points (metres),
// ordered so that the outside is on the right (e.g. bottom centre outwards,
// up the side, back in at the top). Ends at r = 0 close the solid.
inline TriangleMesh MakeRevolved(const std::vector<Eigen::Vector2f>& profile, int segments = 64) {
  TriangleMesh m;
  const auto P = [&](const Eigen::Vector2f& rz, int j) {
    const float a = 2.f * static_cast<float>(M_PI) * static_cast<float>(j % segments) / static_cast<float>(segments);
    return Eigen::Vector3f(rz.x() * std::cos(a), rz.x() * std::sin(a), rz.y());
  };
  for (size_t i = 0; i + 1 < profile.size(); ++i) {
    for (int j = 0; j < segments; ++j) {
      const Eigen::Vector3f A = P(profile[i], j), B = P(profile[i + 1], j);
      const Eigen::Vector3f C = P(profile[i + 1], j + 1), D = P(profile[i], j + 1);
      const int k = static_cast<int>(m.vertices.size());
      m.vertices.insert(m.vertices.end(), {A, D, C, B});
      if (profile[i].x() > 0) m.triangles.emplace_back(k, k + 1, k + 2);
      if (profile[i + 1].x() > 0) m.triangles.emplace_back(k, k + 2, k + 3);
    }
  }
  return m;
}

// L bracket as one solid (no internal faces): base plate 90 x 40 x 6 mm,
// upright 6 x 40 x 50 mm above it at x = 0.
inline TriangleMesh MakeTestLBracket() {
  TriangleMesh m;
  const float y0 = -0.02f, y1 = 0.02f, t = 0.006f, L = 0.09f, H = 0.056f;
  using V = Eigen::Vector3f;
  AddQuad(m, V(0, y0, 0), V(0, y1, 0), V(L, y1, 0), V(L, y0, 0));  // bottom
  AddQuad(m, V(L, y0, 0), V(L, y1, 0), V(L, y1, t), V(L, y0, t));  // base end
  AddQuad(m, V(t, y0, t), V(L, y0, t), V(L, y1, t), V(t, y1, t));  // base top
  AddQuad(m, V(t, y0, t), V(t, y1, t), V(t, y1, H), V(t, y0, H));  // upright inner
  AddQuad(m, V(0, y0, H), V(t, y0, H), V(t, y1, H), V(0, y1, H));  // upright top
  AddQuad(m, V(0, y0, 0), V(0, y0, H), V(0, y1, H), V(0, y1, 0));  // outer
  AddQuad(m, V(0, y0, 0), V(L, y0, 0), V(L, y0, t), V(0, y0, t));  // -y caps
  AddQuad(m, V(0, y0, t), V(t, y0, t), V(t, y0, H), V(0, y0, H));
  AddQuad(m, V(0, y1, 0), V(0, y1, t), V(L, y1, t), V(L, y1, 0));  // +y caps
  AddQuad(m, V(0, y1, t), V(0, y1, H), V(t, y1, H), V(t, y1, t));
  return m;
}

// Revolute about z: flange r = 25 mm, 8 mm thick; hub r = 12 mm up to z = 40 mm.
inline TriangleMesh MakeTestFlangedCylinder() {
  return MakeRevolved({{0.f, 0.f}, {0.025f, 0.f}, {0.025f, 0.008f}, {0.012f, 0.008f}, {0.012f, 0.04f}, {0.f, 0.04f}});
}

// Box 60 x 40 x 20 mm centred at the origin (discrete symmetry).
inline TriangleMesh MakeTestBlock() { return MakeBox({-0.03f, -0.02f, -0.01f}, {0.03f, 0.02f, 0.01f}); }

inline Symmetry RevoluteZ() {
  Symmetry s;
  s.kind = Symmetry::Kind::kRevolute;
  return s;
}

struct TestCamera {
  Intrinsics K;
  Pose X_BC = Pose::Identity();
};

// 640 x 480, fx = 800, 1 m above the B origin looking down (-z of B).
inline TestCamera DefaultCamera() {
  TestCamera c;
  c.K.width = 640;
  c.K.height = 480;
  c.K.fx = c.K.fy = 800;
  c.K.cx = 319.5;
  c.K.cy = 239.5;
  c.X_BC = MakePose(Mat3(Eigen::AngleAxisd(M_PI, Vec3::UnitX())), Vec3(0, 0, 1.0));
  return c;
}

struct RenderedScene {
  DepthImage depth;                    // metres along z of C, NaN = nothing
  Image<int> label;                    // object index + 1, 0 = nothing
  std::vector<Eigen::Vector3f> points_B;
  std::vector<int> point_label;        // per point
};

// Renders meshes at poses X_BO with a z-buffer (exact ray / triangle depths),
// adds N(0, sigma) along z, and deprojects every pixel to B.
inline RenderedScene Render(const std::vector<std::pair<const TriangleMesh*, Pose>>& objects, const TestCamera& cam,
                            double sigma, uint64_t seed) {
  const Intrinsics& K = cam.K;
  RenderedScene s;
  s.depth = DepthImage(K.width, K.height, std::numeric_limits<float>::quiet_NaN());
  s.label = Image<int>(K.width, K.height, 0);
  std::vector<float> zbuf(static_cast<size_t>(K.width) * K.height, std::numeric_limits<float>::infinity());
  const Pose X_CB = cam.X_BC.inverse();
  for (size_t o = 0; o < objects.size(); ++o) {
    const TriangleMesh& mesh = *objects[o].first;
    const Pose X_CO = X_CB * objects[o].second;
    std::vector<Eigen::Vector3d> v(mesh.vertices.size());
    for (size_t i = 0; i < v.size(); ++i) v[i] = X_CO * mesh.vertices[i].cast<double>();
    for (const Eigen::Vector3i& t : mesh.triangles) {
      const Eigen::Vector3d &a = v[t[0]], &b = v[t[1]], &c = v[t[2]];
      if (a.z() <= 0 || b.z() <= 0 || c.z() <= 0) continue;
      double umin = 1e9, umax = -1e9, vmin = 1e9, vmax = -1e9;
      for (const auto* p : {&a, &b, &c}) {
        const double u = K.fx * p->x() / p->z() + K.cx, w = K.fy * p->y() / p->z() + K.cy;
        umin = std::min(umin, u), umax = std::max(umax, u), vmin = std::min(vmin, w), vmax = std::max(vmax, w);
      }
      const int u0 = std::max(0, static_cast<int>(std::floor(umin))), u1 = std::min(K.width - 1, static_cast<int>(std::ceil(umax)));
      const int v0 = std::max(0, static_cast<int>(std::floor(vmin))), v1 = std::min(K.height - 1, static_cast<int>(std::ceil(vmax)));
      const Eigen::Vector3d e1 = b - a, e2 = c - a;
      for (int y = v0; y <= v1; ++y) {
        for (int x = u0; x <= u1; ++x) {
          const Eigen::Vector3d d((x - K.cx) / K.fx, (y - K.cy) / K.fy, 1.0);  // Moller-Trumbore
          const Eigen::Vector3d pv = d.cross(e2);
          const double det = e1.dot(pv);
          if (std::abs(det) < 1e-15) continue;
          const Eigen::Vector3d tv = -a;
          const double uu = tv.dot(pv) / det;
          if (uu < 0 || uu > 1) continue;
          const Eigen::Vector3d qv = tv.cross(e1);
          const double vv = d.dot(qv) / det;
          if (vv < 0 || uu + vv > 1) continue;
          const double z = e2.dot(qv) / det;
          const size_t idx = static_cast<size_t>(y) * K.width + x;
          if (z > 0 && z < zbuf[idx]) {
            zbuf[idx] = static_cast<float>(z);
            s.label.data[idx] = static_cast<int>(o) + 1;
          }
        }
      }
    }
  }
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> noise(0.0, sigma);
  for (int y = 0; y < K.height; ++y) {
    for (int x = 0; x < K.width; ++x) {
      const size_t idx = static_cast<size_t>(y) * K.width + x;
      if (!std::isfinite(zbuf[idx])) continue;
      const double z = zbuf[idx] + (sigma > 0 ? noise(rng) : 0.0);
      s.depth.data[idx] = static_cast<float>(z);
      const Vec3 p_C((x - K.cx) / K.fx * z, (y - K.cy) / K.fy * z, z);
      s.points_B.push_back((cam.X_BC * p_C).cast<float>());
      s.point_label.push_back(s.label.data[idx]);
    }
  }
  return s;
}

// Points of the scene with the given labels (1-based object indices).
inline std::vector<Eigen::Vector3f> PointsWithLabels(const RenderedScene& s, const std::vector<int>& labels) {
  std::vector<Eigen::Vector3f> out;
  for (size_t i = 0; i < s.points_B.size(); ++i) {
    if (std::find(labels.begin(), labels.end(), s.point_label[i]) != labels.end()) out.push_back(s.points_B[i]);
  }
  return out;
}

// A random rotation (seeded) with the part's z axis within max_tilt of +z of B.
inline Mat3 RandomRotation(std::mt19937_64& rng, double max_tilt_rad = M_PI) {
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  const double yaw = 2 * M_PI * uni(rng);
  const double tilt = max_tilt_rad * uni(rng);
  const double dir = 2 * M_PI * uni(rng);
  const Vec3 axis(std::cos(dir), std::sin(dir), 0);
  return Mat3(Eigen::AngleAxisd(tilt, axis) * Eigen::AngleAxisd(yaw, Vec3::UnitZ()));
}

}  // namespace bp::testing
