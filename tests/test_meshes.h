// Small in-memory meshes for tests (no files, no core/mesh.cc needed).
#pragma once

#include <Eigen/Geometry>
#include <cmath>

#include "core/mesh.h"

namespace bp::testing {

// Closed box of the given size centred at `center`, outward CCW triangles.
inline void AppendBox(TriangleMesh& m, const Eigen::Vector3f& size, const Eigen::Vector3f& center) {
  const int base = static_cast<int>(m.vertices.size());
  const Eigen::Vector3f h = size / 2;
  for (int i = 0; i < 8; ++i) {
    m.vertices.push_back(center + Eigen::Vector3f((i & 1) ? h.x() : -h.x(),
                                                  (i & 2) ? h.y() : -h.y(),
                                                  (i & 4) ? h.z() : -h.z()));
  }
  const int f[12][3] = {{0, 2, 1}, {1, 2, 3}, {4, 5, 6}, {5, 7, 6}, {0, 1, 4}, {1, 5, 4},
                        {2, 6, 3}, {3, 6, 7}, {0, 4, 2}, {2, 4, 6}, {1, 3, 5}, {3, 7, 5}};
  for (const auto& t : f) m.triangles.emplace_back(base + t[0], base + t[1], base + t[2]);
}

inline TriangleMesh BoxMesh(const Eigen::Vector3f& size,
                            const Eigen::Vector3f& center = Eigen::Vector3f::Zero()) {
  TriangleMesh m;
  AppendBox(m, size, center);
  return m;
}

// Open bin, frame W at the centre of the inner floor surface, z up.
inline TriangleMesh OpenBinMesh(const Eigen::Vector3f& inner, float wall) {
  TriangleMesh m;
  const float X = inner.x(), Y = inner.y(), Z = inner.z();
  AppendBox(m, {X + 2 * wall, Y + 2 * wall, wall}, {0, 0, -wall / 2});
  AppendBox(m, {wall, Y + 2 * wall, Z}, {X / 2 + wall / 2, 0, Z / 2});
  AppendBox(m, {wall, Y + 2 * wall, Z}, {-X / 2 - wall / 2, 0, Z / 2});
  AppendBox(m, {X, wall, Z}, {0, Y / 2 + wall / 2, Z / 2});
  AppendBox(m, {X, wall, Z}, {0, -Y / 2 - wall / 2, Z / 2});
  return m;
}

// Closed cylinder along z, centred at the origin.
inline TriangleMesh CylinderMesh(float radius, float height, int segments = 24) {
  TriangleMesh m;
  const float h = height / 2;
  for (int i = 0; i < segments; ++i) {
    const float a = 2.f * static_cast<float>(M_PI) * i / segments;
    m.vertices.emplace_back(radius * std::cos(a), radius * std::sin(a), -h);
    m.vertices.emplace_back(radius * std::cos(a), radius * std::sin(a), h);
  }
  const int bottom = static_cast<int>(m.vertices.size());
  m.vertices.emplace_back(0, 0, -h);
  m.vertices.emplace_back(0, 0, h);
  for (int i = 0; i < segments; ++i) {
    const int j = (i + 1) % segments;
    const int b0 = 2 * i, t0 = 2 * i + 1, b1 = 2 * j, t1 = 2 * j + 1;
    m.triangles.emplace_back(b0, b1, t1);
    m.triangles.emplace_back(b0, t1, t0);
    m.triangles.emplace_back(bottom, b1, b0);
    m.triangles.emplace_back(bottom + 1, t0, t1);
  }
  return m;
}

}  // namespace bp::testing
