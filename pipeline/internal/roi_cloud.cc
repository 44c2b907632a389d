#include "pipeline/internal/roi_cloud.h"

#include <algorithm>
#include <cmath>
#include <numeric>
#include <unordered_map>

#include <Eigen/Geometry>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "pipeline/internal/point_hash.h"

namespace bp::internal {
namespace {
// CropToRoi: row bands of at least this many rows, at most this many bands.
constexpr int kRoiBandRows = 32;
constexpr int kMaxRoiBands = 64;
// SpreadLabels: points per task.
constexpr size_t kSpreadGrain = 16384;
// GridNormals: rows per task (640x480: 15 tasks).
constexpr int kNormalRowsGrain = 32;
}  // namespace

RoiBox MakeRoiBox(const Cell& cell) {
  const Vec3 half = 0.5 * cell.bin.inner_size;
  const double m = cell.roi.wall_margin;
  RoiBox box;
  box.min_W = Eigen::Vector3f(static_cast<float>(-half.x() + m), static_cast<float>(-half.y() + m),
                              static_cast<float>(cell.roi.floor_margin));
  box.max_W = Eigen::Vector3f(static_cast<float>(half.x() - m), static_cast<float>(half.y() - m),
                              static_cast<float>(cell.roi.height));
  return box;
}

void CropToRoi(const Frame& frame, const Pose& X_BW, const RoiBox& box, RoiCloud* out) {
  out->points_B.clear();
  out->pixel_of_point.clear();
  out->point_of_pixel.clear();
  out->valid_points = 0;
  const Pose X_WC = X_BW.inverse() * frame.X_BC;
  const Eigen::Matrix3f R_WC = X_WC.linear().cast<float>();
  const Eigen::Vector3f t_WC = X_WC.translation().cast<float>();
  const Eigen::Matrix3f R_BC = frame.X_BC.linear().cast<float>();
  const Eigen::Vector3f t_BC = frame.X_BC.translation().cast<float>();
  const auto inside = [&](const Eigen::Vector3f& p_W) {
    return (p_W.array() >= box.min_W.array()).all() && (p_W.array() <= box.max_W.array()).all();
  };

  if (!frame.organized()) {
    out->width = out->height = 0;
    out->points_B.reserve(frame.points_C.size());
    for (const Eigen::Vector3f& p_C : frame.points_C) {
      if (!p_C.allFinite()) continue;
      ++out->valid_points;
      if (inside(R_WC * p_C + t_WC)) out->points_B.push_back(R_BC * p_C + t_BC);
    }
    return;
  }

  const int w = frame.depth.width, h = frame.depth.height;
  out->width = w;
  out->height = h;
  out->point_of_pixel.assign(static_cast<size_t>(w) * h, -1);
  // p_C = z * (x_u, y_v, 1), so p_W = z * (x_u * R_WC.col(0) + y_v * R_WC.col(1) + R_WC.col(2)) + t_WC:
  // the ray direction in W is a per-column term plus a per-row term (same in B).
  const Intrinsics& K = frame.intrinsics;
  std::vector<Eigen::Vector3f> col_W(static_cast<size_t>(w)), col_B(static_cast<size_t>(w));
  for (int u = 0; u < w; ++u) {
    const float x = static_cast<float>((u - K.cx) / K.fx);
    col_W[static_cast<size_t>(u)] = x * R_WC.col(0);
    col_B[static_cast<size_t>(u)] = x * R_BC.col(0);
  }
  // Bands of rows in parallel (on the caller's arena), each into buffers of
  // its own, joined in row order: the same points in the same order as one
  // pass over the image.
  struct Band {
    std::vector<Eigen::Vector3f> points_B;
    std::vector<int32_t> pixels;
    int64_t valid = 0;
  };
  const int n_bands = std::clamp(h / kRoiBandRows, 1, kMaxRoiBands);
  std::vector<Band> bands(static_cast<size_t>(n_bands));
  tbb::parallel_for(0, n_bands, [&](int b) {
    Band& band = bands[static_cast<size_t>(b)];
    const int v0 = static_cast<int>(static_cast<int64_t>(h) * b / n_bands);
    const int v1 = static_cast<int>(static_cast<int64_t>(h) * (b + 1) / n_bands);
    band.points_B.reserve(static_cast<size_t>(v1 - v0) * w / 2);
    band.pixels.reserve(static_cast<size_t>(v1 - v0) * w / 2);
    for (int v = v0; v < v1; ++v) {
      const float* row = frame.depth.data.data() + static_cast<size_t>(v) * w;
      const float y = static_cast<float>((v - K.cy) / K.fy);
      const Eigen::Vector3f row_W = y * R_WC.col(1) + R_WC.col(2);
      const Eigen::Vector3f row_B = y * R_BC.col(1) + R_BC.col(2);
      for (int u = 0; u < w; ++u) {
        const float z = row[u];
        if (!(z > 0.f) || !std::isfinite(z)) continue;  // NaN fails z > 0
        ++band.valid;
        const Eigen::Vector3f p_W = z * (col_W[static_cast<size_t>(u)] + row_W) + t_WC;
        if (!inside(p_W)) continue;
        band.pixels.push_back(v * w + u);
        band.points_B.push_back(z * (col_B[static_cast<size_t>(u)] + row_B) + t_BC);
      }
    }
  });
  std::vector<size_t> offset(static_cast<size_t>(n_bands) + 1, 0);
  int64_t valid = 0;
  for (size_t b = 0; b < bands.size(); ++b) {
    offset[b + 1] = offset[b] + bands[b].pixels.size();
    valid += bands[b].valid;
  }
  out->points_B.resize(offset.back());
  out->pixel_of_point.resize(offset.back());
  tbb::parallel_for(size_t{0}, bands.size(), [&](size_t b) {
    const Band& band = bands[b];
    const size_t base = offset[b];
    std::copy(band.points_B.begin(), band.points_B.end(), out->points_B.begin() + static_cast<std::ptrdiff_t>(base));
    std::copy(band.pixels.begin(), band.pixels.end(), out->pixel_of_point.begin() + static_cast<std::ptrdiff_t>(base));
    for (size_t k = 0; k < band.pixels.size(); ++k) {
      out->point_of_pixel[static_cast<size_t>(band.pixels[k])] = static_cast<int32_t>(base + k);
    }
  });
  out->valid_points = valid;
}

int64_t DropPointsNear(const std::vector<Eigen::Vector3f>& near_B, float margin, RoiCloud* roi) {
  if (near_B.empty() || roi->points_B.empty()) return 0;
  PointHash hash;
  hash.Build(near_B, margin);
  size_t kept = 0;
  for (size_t i = 0; i < roi->points_B.size(); ++i) {
    const bool drop = hash.AnyWithin(roi->points_B[i], margin);
    if (roi->organized()) {
      const auto pixel = static_cast<size_t>(roi->pixel_of_point[i]);
      roi->point_of_pixel[pixel] = drop ? -1 : static_cast<int32_t>(kept);
      if (!drop) roi->pixel_of_point[kept] = roi->pixel_of_point[i];
    }
    if (!drop) roi->points_B[kept++] = roi->points_B[i];
  }
  const auto dropped = static_cast<int64_t>(roi->points_B.size() - kept);
  roi->points_B.resize(kept);
  if (roi->organized()) roi->pixel_of_point.resize(kept);
  return dropped;
}

SampleGrid MakeSampleGrid(const RoiCloud& roi, int stride) {
  SampleGrid g;
  g.stride = std::max(1, stride);
  g.width = (roi.width + g.stride - 1) / g.stride;
  g.height = (roi.height + g.stride - 1) / g.stride;
  if (g.stride == 1) {
    // Every pixel is a cell, and the ROI points are in row-major pixel order
    // (CropToRoi): the grid is the pixel map, its occupied cells every point.
    g.point_of_cell = roi.point_of_pixel;
    g.cell_points.resize(roi.points_B.size());
    std::iota(g.cell_points.begin(), g.cell_points.end(), 0);
    return g;
  }
  g.point_of_cell.assign(static_cast<size_t>(g.width) * g.height, -1);
  g.cell_points.reserve(g.point_of_cell.size());
  for (int gv = 0; gv < g.height; ++gv) {
    for (int gu = 0; gu < g.width; ++gu) {
      const int32_t i = roi.point_of_pixel[static_cast<size_t>(gv * g.stride) * roi.width + gu * g.stride];
      g.point_of_cell[static_cast<size_t>(gv) * g.width + gu] = i;
      if (i >= 0) g.cell_points.push_back(i);
    }
  }
  return g;
}

void GridNormals(const RoiCloud& roi, const SampleGrid& grid, int radius, float max_jump,
                 const Eigen::Vector3f& viewpoint_B, std::vector<Eigen::Vector3f>* normals) {
  const Eigen::Vector3f kNaN = Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN());
  // A neighbour k cells away is continuous when closer than k * max_jump
  // (compared squared: no square root per neighbour).
  std::vector<float> jump2(static_cast<size_t>(std::max(radius, 0)) + 1);
  for (size_t k = 0; k < jump2.size(); ++k) jump2[k] = (max_jump * static_cast<float>(k)) * (max_jump * static_cast<float>(k));
  // Every cell is written once below, NaN included, in the parallel loop
  // (a serial fill of the 640x480 grid's 3.7 MB came first).
  normals->resize(grid.point_of_cell.size());
  const int W = grid.width, H = grid.height;
  const auto at = [&](int u, int v) -> int32_t {
    if (u < 0 || v < 0 || u >= W || v >= H) return -1;
    return grid.point_of_cell[static_cast<size_t>(v) * W + u];
  };
  // Each cell writes only its own normal: bands of rows are tasks on the
  // caller's arena (the perception runs this on both threads before the
  // connected regions and the segments' growing).
  tbb::parallel_for(tbb::blocked_range<int>(0, H, kNormalRowsGrain), [&](const tbb::blocked_range<int>& rows) {
    for (int v = rows.begin(); v != rows.end(); ++v) {
      for (int u = 0; u < W; ++u) {
        Eigen::Vector3f& out = (*normals)[static_cast<size_t>(v) * W + u];
        out = kNaN;
        const int32_t c = at(u, v);
        if (c < 0) continue;
        const Eigen::Vector3f& p = roi.points_B[static_cast<size_t>(c)];
        // A neighbour at offset k along an axis, searching inwards from `radius`
        // so that a missing or discontinuous far neighbour falls back to a nearer one.
        const auto tangent = [&](int du, int dv) -> Eigen::Vector3f {
          Eigen::Vector3f fwd = Eigen::Vector3f::Zero(), bwd = Eigen::Vector3f::Zero();
          bool has_f = false, has_b = false;
          for (int k = radius; k >= 1 && !has_f; --k) {
            const int32_t n = at(u + k * du, v + k * dv);
            if (n >= 0 && (roi.points_B[static_cast<size_t>(n)] - p).squaredNorm() < jump2[k]) {
              fwd = roi.points_B[static_cast<size_t>(n)];
              has_f = true;
            }
          }
          for (int k = radius; k >= 1 && !has_b; --k) {
            const int32_t n = at(u - k * du, v - k * dv);
            if (n >= 0 && (roi.points_B[static_cast<size_t>(n)] - p).squaredNorm() < jump2[k]) {
              bwd = roi.points_B[static_cast<size_t>(n)];
              has_b = true;
            }
          }
          if (has_f && has_b) return fwd - bwd;
          if (has_f) return fwd - p;
          if (has_b) return p - bwd;
          return Eigen::Vector3f::Zero();
        };
        const Eigen::Vector3f tu = tangent(1, 0), tv = tangent(0, 1);
        Eigen::Vector3f n = tu.cross(tv);
        const float len = n.norm();
        if (!(len > 1e-12f)) continue;
        n /= len;
        if (n.dot(viewpoint_B - p) < 0.f) n = -n;
        out = n;
      }
    }
  });
}

int GrowRegions(const RoiCloud& roi, const SampleGrid& grid, const std::vector<Eigen::Vector3f>& normals,
                float max_jump, float max_normal_angle_rad, const std::vector<uint8_t>& excluded,
                std::vector<int32_t>* region_of_cell, float convex_tolerance) {
  // Connected components of the graph whose edges join 4-neighbours that pass
  // the test below (symmetric in the two cells, bit for bit), in one raster
  // pass over each cell's left and upper neighbour with a union-find whose
  // root is a component's first cell; then ids in the order of those first
  // cells, as a flood fill seeded in raster order numbers them.
  const int W = grid.width, H = grid.height;
  const size_t n_cells = grid.point_of_cell.size();
  const bool use_normals = max_normal_angle_rad > 0.f;
  const float min_cos = std::cos(max_normal_angle_rad);
  const float jump2 = max_jump * max_jump;
  // parent: -1 for a cell that never joins; else the union-find parent.
  std::vector<int32_t>& parent = *region_of_cell;
  parent.assign(n_cells, -1);
  const auto find = [&parent](int32_t x) {
    while (parent[static_cast<size_t>(x)] != x) {
      const int32_t up = parent[static_cast<size_t>(parent[static_cast<size_t>(x)])];
      parent[static_cast<size_t>(x)] = up;
      x = up;
    }
    return x;
  };
  const auto joins = [&](size_t c, size_t n) {
    const Eigen::Vector3f& p = roi.points_B[static_cast<size_t>(grid.point_of_cell[c])];
    const Eigen::Vector3f& q = roi.points_B[static_cast<size_t>(grid.point_of_cell[n])];
    if ((q - p).squaredNorm() > jump2) return false;
    if (!use_normals) return true;
    const Eigen::Vector3f& a = normals[c];
    const Eigen::Vector3f& b = normals[n];
    if (a.dot(b) >= min_cos) return true;
    // A convex crease (the surfaces bend away from the camera, as at a
    // part's own edge) may join; concave ones (where parts meet) not.
    return convex_tolerance >= 0.f && !((a - b).dot(p - q) < convex_tolerance * (p - q).norm());
  };
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      const size_t c = static_cast<size_t>(v) * W + u;
      if (grid.point_of_cell[c] < 0 || (!excluded.empty() && excluded[c])) continue;
      if (use_normals && !normals[c].allFinite()) continue;
      int32_t root = static_cast<int32_t>(c);
      parent[c] = root;
      if (u > 0 && parent[c - 1] >= 0 && joins(c, c - 1)) {
        root = find(static_cast<int32_t>(c - 1));
        parent[c] = root;
      }
      if (v > 0 && parent[c - W] >= 0 && joins(c, c - W)) {
        const int32_t other = find(static_cast<int32_t>(c - W));
        if (other != root) {
          // Both roots come before c: the smaller stays the root.
          const int32_t lo = std::min(root, other), hi = std::max(root, other);
          parent[static_cast<size_t>(hi)] = lo;
          root = lo;
        }
        parent[c] = root;
      }
    }
  }
  // Ids: a root (parent[c] == c) is its component's first cell; every other
  // cell's root comes before it, so one raster pass numbers and labels.
  int regions = 0;
  for (size_t c = 0; c < n_cells; ++c) {
    const int32_t pc = parent[c];
    if (pc < 0) continue;
    if (pc == static_cast<int32_t>(c)) {
      parent[c] = -2 - regions++;  // a root: its id, encoded below -1
    } else {
      // The root's id: follow the chain of cells before c (already labelled).
      int32_t r = pc;
      while (parent[static_cast<size_t>(r)] >= 0) r = parent[static_cast<size_t>(r)];
      parent[c] = parent[static_cast<size_t>(r)];
    }
  }
  for (size_t c = 0; c < n_cells; ++c) {
    if (parent[c] != -1) parent[c] = -2 - parent[c];
  }
  return regions;
}

namespace {
struct UnionFind {
  std::vector<int32_t> parent;
  explicit UnionFind(size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0); }
  int32_t Find(int32_t x) {
    while (parent[static_cast<size_t>(x)] != x) {
      parent[static_cast<size_t>(x)] = parent[static_cast<size_t>(parent[static_cast<size_t>(x)])];
      x = parent[static_cast<size_t>(x)];
    }
    return x;
  }
  void Union(int32_t a, int32_t b) {
    a = Find(a);
    b = Find(b);
    if (a != b) parent[static_cast<size_t>(std::max(a, b))] = std::min(a, b);
  }
};

int64_t VoxelKey(int x, int y, int z) {
  constexpr int64_t kOff = 1 << 20;
  return ((static_cast<int64_t>(x) + kOff) << 42) | ((static_cast<int64_t>(y) + kOff) << 21) |
         (static_cast<int64_t>(z) + kOff);
}
}  // namespace

int VoxelRegions(const std::vector<Eigen::Vector3f>& points, float voxel, std::vector<int32_t>* region_of_point) {
  region_of_point->assign(points.size(), -1);
  if (points.empty()) return 0;
  std::unordered_map<int64_t, int32_t> voxel_id;
  voxel_id.reserve(points.size());
  std::vector<Eigen::Vector3i> coords;
  std::vector<int32_t> voxel_of_point(points.size());
  const float inv = 1.f / voxel;
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3i c = (points[i] * inv).array().floor().cast<int>();
    auto [it, inserted] = voxel_id.try_emplace(VoxelKey(c.x(), c.y(), c.z()), static_cast<int32_t>(coords.size()));
    if (inserted) coords.push_back(c);
    voxel_of_point[i] = it->second;
  }
  UnionFind uf(coords.size());
  for (size_t v = 0; v < coords.size(); ++v) {
    const Eigen::Vector3i& c = coords[v];
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz) {
          const auto it = voxel_id.find(VoxelKey(c.x() + dx, c.y() + dy, c.z() + dz));
          if (it != voxel_id.end()) uf.Union(static_cast<int32_t>(v), it->second);
        }
  }
  std::vector<int32_t> compact(coords.size(), -1);
  int regions = 0;
  for (size_t i = 0; i < points.size(); ++i) {
    const int32_t root = uf.Find(voxel_of_point[i]);
    if (compact[static_cast<size_t>(root)] < 0) compact[static_cast<size_t>(root)] = regions++;
    (*region_of_point)[i] = compact[static_cast<size_t>(root)];
  }
  return regions;
}

void SpreadLabels(const RoiCloud& roi, const SampleGrid& grid, const std::vector<int32_t>& a_of_cell,
                  const std::vector<int32_t>& b_of_cell, float max_jump, std::vector<int32_t>* a_of_point,
                  std::vector<int32_t>* b_of_point) {
  a_of_point->assign(roi.points_B.size(), -1);
  if (b_of_point != nullptr) b_of_point->assign(roi.points_B.size(), -1);
  const float jump2 = max_jump * max_jump;
  const int s = grid.stride;
  // Each point writes only its own labels: in parallel on the caller's arena.
  const auto spread = [&](const tbb::blocked_range<size_t>& range) {
    for (size_t i = range.begin(); i != range.end(); ++i) {
      const int32_t pixel = roi.pixel_of_point[i];
      const int u = pixel % roi.width, v = pixel / roi.width;
      // The nearest grid cell (rounded), then the cell the pixel's block starts at.
      const int cands[2][2] = {{(u + s / 2) / s, (v + s / 2) / s}, {u / s, v / s}};
      for (const auto& cand : cands) {
        if (cand[0] >= grid.width || cand[1] >= grid.height) continue;
        const size_t cell = static_cast<size_t>(cand[1]) * grid.width + cand[0];
        const int32_t q = grid.point_of_cell[cell];
        if (q < 0 || (a_of_cell[cell] < 0 && (b_of_point == nullptr || b_of_cell[cell] < 0))) continue;
        if ((roi.points_B[static_cast<size_t>(q)] - roi.points_B[i]).squaredNorm() <= jump2) {
          (*a_of_point)[i] = a_of_cell[cell];
          if (b_of_point != nullptr) (*b_of_point)[i] = b_of_cell[cell];
          break;
        }
      }
    }
  };
  tbb::parallel_for(tbb::blocked_range<size_t>(0, roi.points_B.size(), kSpreadGrain), spread);
}

void SpreadLabels(const RoiCloud& roi, const SampleGrid& grid, const std::vector<int32_t>& label_of_cell,
                  float max_jump, std::vector<int32_t>* label_of_point) {
  SpreadLabels(roi, grid, label_of_cell, label_of_cell, max_jump, label_of_point, nullptr);
}

}  // namespace bp::internal
