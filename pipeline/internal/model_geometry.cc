#include "pipeline/internal/model_geometry.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include "pipeline/internal/point_hash.h"
#include "pipeline/internal/table_memo.h"

namespace bp::internal {

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

std::pair<Eigen::Vector3f, Eigen::Vector3f> PlaneBasis(const Eigen::Vector3f& d) {
  const Eigen::Vector3f u = d.unitOrthogonal();
  return {u, d.cross(u)};
}

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

namespace {

std::vector<Eigen::Vector3f> ComputeExtremePoints(std::span<const Eigen::Vector3f> pts) {
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

}  // namespace

std::vector<Eigen::Vector3f> ExtremePoints(std::span<const Eigen::Vector3f> pts) {
  if (!ModelTableMemoOn()) return ComputeExtremePoints(pts);
  static TableMemo<std::vector<Eigen::Vector3f>> memo;
  static_assert(sizeof(Eigen::Vector3f) == 3 * sizeof(float));  // no padding in the key
  TableMemoKey key;
  key.AddSpan(pts);
  return Memoised(memo, key, [&] { return ComputeExtremePoints(pts); });
}

void SortByMortonCode(OrientedPoints& s) {
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
  OrientedPoints sorted;
  sorted.points.reserve(s.size());
  sorted.normals.reserve(s.size());
  for (const auto& [key, i] : keys) {
    sorted.points.push_back(s.points[i]);
    sorted.normals.push_back(s.normals[i]);
  }
  s = std::move(sorted);
}

Pose HalfTurn(const Eigen::Vector3f& a, const Eigen::Vector3f& c) {
  const Eigen::Vector3d ad = a.cast<double>().normalized();
  const Eigen::Matrix3d R = 2.0 * ad * ad.transpose() - Eigen::Matrix3d::Identity();
  const Eigen::Vector3d cd = c.cast<double>();
  return MakePose(R, cd - R * cd);
}

namespace {

std::vector<EdgePlane> ComputeEdgePlanes(const OrientedPoints& dense, double spacing) {
  PointHash dense_hash;
  const float r = 2.5f * static_cast<float>(spacing);
  dense_hash.Build(dense.points, r);
  const float cos30 = std::cos(static_cast<float>(30.0 * M_PI / 180.0));
  std::vector<EdgePlane> planes(dense.size(), EdgePlane{});
  for (size_t i = 0; i < dense.size(); ++i) {
    const Eigen::Vector3f& p = dense.points[i];
    const Eigen::Vector3f& n = dense.normals[i];
    Eigen::Vector3f n_sum = Eigen::Vector3f::Zero(), p_sum = Eigen::Vector3f::Zero();
    int k = 0;
    dense_hash.ForEachWithin(p, r, [&](int j, float d2) {
      if (d2 <= 0.f) return;
      if (n.dot(dense.normals[j]) < cos30 && (dense.points[j] - p).dot(n) < -0.1f * std::sqrt(d2)) {
        n_sum += dense.normals[j];
        p_sum += dense.points[j];
        ++k;
      }
    });
    if (k > 0 && n_sum.norm() > 1e-3f) {
      const Eigen::Vector3f no = n_sum.normalized();
      planes[i] = EdgePlane{no, no.dot(p_sum / static_cast<float>(k))};
    }
  }
  return planes;
}

}  // namespace

std::vector<EdgePlane> BuildEdgePlanes(const OrientedPoints& dense, double spacing) {
  if (!ModelTableMemoOn()) return ComputeEdgePlanes(dense, spacing);
  static TableMemo<std::vector<EdgePlane>> memo;
  TableMemoKey key;
  key.AddSpan(std::span<const Eigen::Vector3f>(dense.points));
  key.AddSpan(std::span<const Eigen::Vector3f>(dense.normals)).Add(spacing);
  return Memoised(memo, key, [&] { return ComputeEdgePlanes(dense, spacing); });
}

}  // namespace bp::internal
