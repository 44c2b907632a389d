#include "pipeline/internal/model_sampling.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <unordered_map>

#include "pipeline/internal/table_memo.h"

namespace bp::internal {

double SurfaceArea(const TriangleMesh& mesh) {
  double total = 0;
  const int nv = static_cast<int>(mesh.vertices.size());
  for (const Eigen::Vector3i& f : mesh.triangles) {
    if (f.minCoeff() < 0 || f.maxCoeff() >= nv) continue;
    const Eigen::Vector3f& a = mesh.vertices[f[0]];
    const Eigen::Vector3f cross = (mesh.vertices[f[1]] - a).cross(mesh.vertices[f[2]] - a);
    const double area = 0.5 * cross.norm();
    if (area > 0 && cross.allFinite()) total += area;
  }
  return total;
}

namespace {

OrientedPoints ComputeSampleSurface(const TriangleMesh& mesh, double spacing, uint64_t seed) {
  OrientedPoints out;
  const size_t nt = mesh.triangles.size();
  std::vector<double> cumulative(nt, 0.0);
  std::vector<Eigen::Vector3f> face_normals(nt, Eigen::Vector3f::Zero());
  double total = 0;
  const int nv = static_cast<int>(mesh.vertices.size());
  for (size_t t = 0; t < nt; ++t) {
    const Eigen::Vector3i& f = mesh.triangles[t];
    double area = 0;
    if (f.minCoeff() >= 0 && f.maxCoeff() < nv) {
      const Eigen::Vector3f& a = mesh.vertices[f[0]];
      const Eigen::Vector3f cross = (mesh.vertices[f[1]] - a).cross(mesh.vertices[f[2]] - a);
      area = 0.5 * cross.norm();
      if (area > 0 && cross.allFinite()) face_normals[t] = cross.normalized();
      else area = 0;
    }
    total += area;
    cumulative[t] = total;
  }
  if (!(total > 0) || !(spacing > 0)) return out;
  const size_t n = static_cast<size_t>(std::ceil(total / (spacing * spacing)));
  out.points.reserve(n);
  out.normals.reserve(n);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> uni(0.0, 1.0);
  for (size_t i = 0; i < n; ++i) {
    const double pick = uni(rng) * total;
    size_t t = static_cast<size_t>(std::upper_bound(cumulative.begin(), cumulative.end(), pick) - cumulative.begin());
    t = std::min(t, nt - 1);
    while (t > 0 && face_normals[t].isZero()) --t;
    const Eigen::Vector3i& f = mesh.triangles[t];
    double u = uni(rng), v = uni(rng);
    if (u + v > 1) {
      u = 1 - u;
      v = 1 - v;
    }
    const Eigen::Vector3f& a = mesh.vertices[f[0]];
    const Eigen::Vector3f p = a + static_cast<float>(u) * (mesh.vertices[f[1]] - a) +
                              static_cast<float>(v) * (mesh.vertices[f[2]] - a);
    out.points.push_back(p);
    out.normals.push_back(face_normals[t]);
  }
  return out;
}

}  // namespace

OrientedPoints VoxelDownsample(const OrientedPoints& in, double voxel, double max_normal_angle_deg) {
  struct Cluster {
    Eigen::Vector3f seed_normal, sum_p, sum_n;
    int count;
  };
  const float inv = static_cast<float>(1.0 / voxel);
  const float cos_max = static_cast<float>(std::cos(max_normal_angle_deg * M_PI / 180.0));
  std::unordered_map<uint64_t, std::vector<int>> voxels;  // voxel -> cluster ids
  std::vector<Cluster> clusters;
  std::vector<uint64_t> voxel_order;
  for (size_t i = 0; i < in.size(); ++i) {
    const Eigen::Vector3f& p = in.points[i];
    const Eigen::Vector3f& n = in.normals[i];
    const auto c = [&](float x) { return static_cast<uint64_t>(static_cast<int64_t>(std::floor(x * inv)) + (1 << 20)) & 0x1FFFFF; };
    const uint64_t key = c(p.x()) | (c(p.y()) << 21) | (c(p.z()) << 42);
    auto [it, inserted] = voxels.try_emplace(key);
    if (inserted) voxel_order.push_back(key);
    bool placed = false;
    for (int id : it->second) {
      if (clusters[id].seed_normal.dot(n) >= cos_max) {
        clusters[id].sum_p += p;
        clusters[id].sum_n += n;
        ++clusters[id].count;
        placed = true;
        break;
      }
    }
    if (!placed) {
      it->second.push_back(static_cast<int>(clusters.size()));
      clusters.push_back(Cluster{n, p, n, 1});
    }
  }
  OrientedPoints out;
  out.points.reserve(clusters.size());
  out.normals.reserve(clusters.size());
  for (uint64_t key : voxel_order) {  // deterministic order (first-seen voxel)
    for (int id : voxels[key]) {
      const Cluster& c = clusters[id];
      if (c.sum_n.norm() < 1e-6f) continue;
      out.points.push_back(c.sum_p / static_cast<float>(c.count));
      out.normals.push_back(c.sum_n.normalized());
    }
  }
  return out;
}

namespace {

double ComputePointSetDiameter(std::span<const Eigen::Vector3f> points) {
  const size_t n = points.size();
  const size_t stride = std::max<size_t>(1, n / 4000);
  double best2 = 0;
  for (size_t i = 0; i < n; i += stride) {
    for (size_t j = i + stride; j < n; j += stride) {
      best2 = std::max(best2, static_cast<double>((points[i] - points[j]).squaredNorm()));
    }
  }
  return std::sqrt(best2);
}

}  // namespace

// The memo's keys: every input's bytes (Vector3f and Vector3i have no padding).
static_assert(sizeof(Eigen::Vector3f) == 3 * sizeof(float) && sizeof(Eigen::Vector3i) == 3 * sizeof(int));

OrientedPoints SampleSurface(const TriangleMesh& mesh, double spacing, uint64_t seed) {
  if (!ModelTableMemoOn()) return ComputeSampleSurface(mesh, spacing, seed);
  static TableMemo<OrientedPoints> memo;
  TableMemoKey key;
  key.AddSpan(std::span<const Eigen::Vector3f>(mesh.vertices));
  key.AddSpan(std::span<const Eigen::Vector3i>(mesh.triangles)).Add(spacing).Add(seed);
  return Memoised(memo, key, [&] { return ComputeSampleSurface(mesh, spacing, seed); });
}

double PointSetDiameter(std::span<const Eigen::Vector3f> points) {
  if (!ModelTableMemoOn()) return ComputePointSetDiameter(points);
  static TableMemo<double> memo;
  TableMemoKey key;
  key.AddSpan(points);
  return Memoised(memo, key, [&] { return ComputePointSetDiameter(points); });
}

}  // namespace bp::internal
