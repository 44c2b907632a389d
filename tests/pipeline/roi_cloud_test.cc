// The ROI crop and the label spreading (both run in parallel on a oneTBB
// arena) against one-pass references: the same points in the same order,
// the same pixel maps, the same labels, whatever the band and task split.
#include "pipeline/internal/roi_cloud.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <tuple>
#include <utility>
#include <vector>

#include <Eigen/Geometry>
#include <tbb/task_arena.h>

namespace bp::internal {
namespace {

constexpr float kNaN = std::numeric_limits<float>::quiet_NaN();

// A camera 1 m above a bin floor, looking down, with depths scattered around
// the ROI's top and bottom, NaNs and zeros among them.
Frame RandomFrame(int w, int h, uint32_t seed) {
  Frame f;
  f.intrinsics.width = w;
  f.intrinsics.height = h;
  f.intrinsics.fx = f.intrinsics.fy = 2.0 * w;
  f.intrinsics.cx = 0.5 * w;
  f.intrinsics.cy = 0.5 * h;
  f.depth = DepthImage(w, h, kNaN);
  f.X_BC = MakePose(Eigen::AngleAxisd(M_PI, Vec3::UnitX()).toRotationMatrix(), Vec3(0.02, -0.01, 1.0));
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> z(0.7f, 1.1f);
  std::uniform_int_distribution<int> kind(0, 9);
  for (float& d : f.depth.data) {
    const int k = kind(rng);
    d = k == 0 ? kNaN : k == 1 ? 0.f : z(rng);
  }
  return f;
}

RoiBox Box() {
  RoiBox box;
  box.min_W = Eigen::Vector3f(-0.2f, -0.15f, 0.01f);
  box.max_W = Eigen::Vector3f(0.2f, 0.15f, 0.25f);
  return box;
}

TEST(RoiCloud, ParallelCropEqualsOnePassInRowOrder) {
  const Pose X_BW = MakePose(Mat3::Identity(), Vec3(0.0, 0.0, 0.0));
  const RoiBox box = Box();
  for (const auto& [w, h] : {std::pair{64, 48}, std::pair{320, 31}, std::pair{640, 480}, std::pair{333, 1201}}) {
    const Frame f = RandomFrame(w, h, static_cast<uint32_t>(w * h));
    RoiCloud roi;
    tbb::task_arena arena(2);
    arena.execute([&] { CropToRoi(f, X_BW, box, &roi); });

    // One pass, as written before the crop ran in bands.
    std::vector<Eigen::Vector3f> points;
    std::vector<int32_t> pixels;
    int64_t valid = 0;
    const Pose X_WC = X_BW.inverse() * f.X_BC;
    for (int v = 0; v < h; ++v) {
      for (int u = 0; u < w; ++u) {
        const float z = f.depth.at(u, v);
        if (!(z > 0.f) || !std::isfinite(z)) continue;
        ++valid;
        const Eigen::Vector3f p_C = Deproject(f.intrinsics, static_cast<float>(u), static_cast<float>(v), z);
        const Eigen::Vector3f p_W = (X_WC.cast<float>() * p_C);
        // Inside with a margin either way: the crop computes p_W in another
        // order of operations; points within float rounding of a face are
        // left out of the comparison below.
        if ((p_W.array() < box.min_W.array()).any() || (p_W.array() > box.max_W.array()).any()) continue;
        pixels.push_back(v * w + u);
        points.push_back((f.X_BC.cast<float>() * p_C));
      }
    }
    EXPECT_EQ(roi.valid_points, valid) << w << "x" << h;
    ASSERT_EQ(roi.pixel_of_point.size(), roi.points_B.size());
    ASSERT_EQ(roi.point_of_pixel.size(), static_cast<size_t>(w) * h);
    // Row order, and the pixel map is the inverse of pixel_of_point.
    for (size_t i = 1; i < roi.pixel_of_point.size(); ++i) ASSERT_LT(roi.pixel_of_point[i - 1], roi.pixel_of_point[i]);
    size_t mapped = 0;
    for (size_t p = 0; p < roi.point_of_pixel.size(); ++p) {
      const int32_t i = roi.point_of_pixel[p];
      if (i < 0) continue;
      ++mapped;
      ASSERT_EQ(roi.pixel_of_point[static_cast<size_t>(i)], static_cast<int32_t>(p));
    }
    EXPECT_EQ(mapped, roi.points_B.size());
    // The same pixels (up to points on a face of the box) and the same points.
    size_t j = 0, differing = 0;
    for (size_t i = 0; i < roi.pixel_of_point.size(); ++i) {
      while (j < pixels.size() && pixels[j] < roi.pixel_of_point[i]) ++j, ++differing;
      if (j < pixels.size() && pixels[j] == roi.pixel_of_point[i]) {
        EXPECT_LT((roi.points_B[i] - points[j]).norm(), 1e-5f);
        ++j;
      } else {
        ++differing;
      }
    }
    EXPECT_LE(differing + (pixels.size() - j), pixels.size() / 1000 + 1) << w << "x" << h;
    EXPECT_GT(roi.points_B.size(), static_cast<size_t>(w) * h / 20) << "the frame should put many points in the ROI";
  }
}

// A 640x480 random frame cropped to Box().
RoiCloud CroppedRandomFrame(uint32_t seed) {
  RoiCloud roi;
  CropToRoi(RandomFrame(640, 480, seed), Pose::Identity(), Box(), &roi);
  return roi;
}

TEST(RoiCloud, SampleGridHoldsEveryStrideThPixelsPoint) {
  const RoiCloud roi = CroppedRandomFrame(11);
  ASSERT_GT(roi.points_B.size(), 10000u);
  for (int stride : {1, 2, 3}) {
    const SampleGrid grid = MakeSampleGrid(roi, stride);
    ASSERT_EQ(grid.width, (roi.width + stride - 1) / stride);
    ASSERT_EQ(grid.height, (roi.height + stride - 1) / stride);
    ASSERT_EQ(grid.point_of_cell.size(), static_cast<size_t>(grid.width) * grid.height);
    std::vector<int32_t> occupied;
    for (int gv = 0; gv < grid.height; ++gv) {
      for (int gu = 0; gu < grid.width; ++gu) {
        const int32_t i = roi.point_of_pixel[static_cast<size_t>(gv * stride) * roi.width + gu * stride];
        ASSERT_EQ(grid.point_of_cell[static_cast<size_t>(gv) * grid.width + gu], i) << "stride " << stride;
        if (i >= 0) occupied.push_back(i);
      }
    }
    EXPECT_EQ(grid.cell_points, occupied) << "stride " << stride;
    if (stride == 1) {
      EXPECT_EQ(occupied.size(), roi.points_B.size());
    }
  }
}

TEST(RoiCloud, ParallelLabelSpreadingEqualsOnePass) {
  const RoiCloud roi = CroppedRandomFrame(7);
  ASSERT_GT(roi.points_B.size(), 10000u);
  for (int stride : {1, 2, 3}) {
    const SampleGrid grid = MakeSampleGrid(roi, stride);
    std::vector<int32_t> a(grid.point_of_cell.size()), b(grid.point_of_cell.size());
    for (size_t c = 0; c < a.size(); ++c) {
      a[c] = static_cast<int32_t>(c % 7) - 1;   // -1 on some cells
      b[c] = static_cast<int32_t>(c % 5) - 1;
    }
    const float jump = 0.05f;
    std::vector<int32_t> got_a, got_b;
    tbb::task_arena arena(2);
    arena.execute([&] { SpreadLabels(roi, grid, a, b, jump, &got_a, &got_b); });
    ASSERT_EQ(got_a.size(), roi.points_B.size());
    size_t labelled = 0;
    for (size_t i = 0; i < roi.points_B.size(); ++i) {
      int32_t ea = -1, eb = -1;
      const int u = roi.pixel_of_point[i] % roi.width, v = roi.pixel_of_point[i] / roi.width;
      const int cands[2][2] = {{(u + stride / 2) / stride, (v + stride / 2) / stride}, {u / stride, v / stride}};
      for (const auto& cand : cands) {
        if (cand[0] >= grid.width || cand[1] >= grid.height) continue;
        const size_t cell = static_cast<size_t>(cand[1]) * grid.width + cand[0];
        const int32_t q = grid.point_of_cell[cell];
        if (q < 0 || (a[cell] < 0 && b[cell] < 0)) continue;
        if ((roi.points_B[static_cast<size_t>(q)] - roi.points_B[i]).squaredNorm() <= jump * jump) {
          ea = a[cell];
          eb = b[cell];
          break;
        }
      }
      ASSERT_EQ(got_a[i], ea) << "stride " << stride << " point " << i;
      ASSERT_EQ(got_b[i], eb) << "stride " << stride << " point " << i;
      labelled += ea >= 0 ? 1 : 0;
    }
    EXPECT_GT(labelled, roi.points_B.size() / 4) << "stride " << stride;
  }
}

// Region growing as a flood fill seeded in raster order: the definition
// GrowRegions must reproduce, ids included.
std::vector<int32_t> FloodFillRegions(const RoiCloud& roi, const SampleGrid& grid,
                                      const std::vector<Eigen::Vector3f>& normals, float max_jump, float angle,
                                      const std::vector<uint8_t>& excluded, float convex_tolerance) {
  const int W = grid.width, H = grid.height;
  std::vector<int32_t> label(grid.point_of_cell.size(), -1);
  const auto usable = [&](size_t c) {
    return grid.point_of_cell[c] >= 0 && (excluded.empty() || !excluded[c]) &&
           (angle <= 0.f || normals[c].allFinite());
  };
  const auto point = [&](size_t c) { return roi.points_B[static_cast<size_t>(grid.point_of_cell[c])]; };
  int regions = 0;
  for (size_t seed = 0; seed < label.size(); ++seed) {
    if (!usable(seed) || label[seed] >= 0) continue;
    label[seed] = regions;
    std::vector<size_t> stack{seed};
    while (!stack.empty()) {
      const size_t c = stack.back();
      stack.pop_back();
      const int u = static_cast<int>(c % W), v = static_cast<int>(c / W);
      for (const auto& [du, dv] : {std::pair{1, 0}, {-1, 0}, {0, 1}, {0, -1}}) {
        if (u + du < 0 || v + dv < 0 || u + du >= W || v + dv >= H) continue;
        const size_t n = static_cast<size_t>(v + dv) * W + (u + du);
        if (!usable(n) || label[n] >= 0) continue;
        const Eigen::Vector3f p = point(c), q = point(n);
        if ((q - p).norm() > max_jump) continue;
        if (angle > 0.f && normals[c].dot(normals[n]) < std::cos(angle) &&
            !(convex_tolerance >= 0.f && (normals[c] - normals[n]).dot(p - q) >= convex_tolerance * (p - q).norm())) {
          continue;
        }
        label[n] = regions;
        stack.push_back(n);
      }
    }
    ++regions;
  }
  return label;
}

// GridNormals on a synthetic grid: two parallel tilted planes (a 20 mm step
// between them along a column), a hole, an isolated point. A neighbour is
// used only when closer than k * max_jump (k cells away): every cell of
// either plane, the cells beside the step and the hole included, gets the
// planes' normal towards the viewpoint; the isolated point and the empty
// cells get NaN.
TEST(RoiCloud, GridNormalsFollowThePlaneAndStopAtDepthJumps) {
  const int W = 120, H = 80;
  const float pitch = 0.0013f;  // metres per cell
  RoiCloud roi;
  roi.width = W;
  roi.height = H;
  roi.point_of_pixel.assign(static_cast<size_t>(W) * H, -1);
  const Eigen::Vector3f n_true = Eigen::Vector3f(0.3f, -0.2f, 1.f).normalized();
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      if (u >= 30 && u < 34 && v >= 30 && v < 34) continue;  // a hole
      if (u == 100 && v == 10) continue;                       // room around the lone point
      const float x = u * pitch, y = v * pitch;
      // On the plane n_true . p = d, the right part 20 mm higher.
      const float d = u >= 60 ? 0.02f : 0.f;
      const float z = (d - n_true.x() * x - n_true.y() * y) / n_true.z();
      roi.point_of_pixel[static_cast<size_t>(v) * W + u] = static_cast<int32_t>(roi.points_B.size());
      roi.points_B.emplace_back(x, y, z);
      roi.pixel_of_point.push_back(v * W + u);
    }
  }
  // An isolated point: its neighbours within 2 cells are all missing.
  for (int v = 8; v <= 12; ++v) {
    for (int u = 98; u <= 102; ++u) {
      const int32_t i = roi.point_of_pixel[static_cast<size_t>(v) * W + u];
      if (i >= 0) roi.points_B[static_cast<size_t>(i)] = Eigen::Vector3f::Constant(std::numeric_limits<float>::quiet_NaN());
      roi.point_of_pixel[static_cast<size_t>(v) * W + u] = -1;
    }
  }
  roi.point_of_pixel[static_cast<size_t>(10) * W + 100] = static_cast<int32_t>(roi.points_B.size());
  roi.points_B.emplace_back(100 * pitch, 10 * pitch, 0.5f);
  roi.pixel_of_point.push_back(10 * W + 100);

  const SampleGrid grid = MakeSampleGrid(roi, 1);
  std::vector<Eigen::Vector3f> normals;
  const Eigen::Vector3f viewpoint(0.05f, 0.05f, 1.f);
  GridNormals(roi, grid, 2, 0.005f, viewpoint, &normals);
  ASSERT_EQ(normals.size(), grid.point_of_cell.size());
  int checked = 0;
  for (int v = 0; v < H; ++v) {
    for (int u = 0; u < W; ++u) {
      const size_t c = static_cast<size_t>(v) * W + u;
      const int32_t i = grid.point_of_cell[c];
      if (i < 0 || (u == 100 && v == 10)) {
        EXPECT_FALSE(normals[c].allFinite()) << u << ", " << v;
        continue;
      }
      ASSERT_TRUE(normals[c].allFinite()) << u << ", " << v;
      EXPECT_GT(normals[c].dot(n_true), 0.99999f) << u << ", " << v;
      ++checked;
    }
  }
  EXPECT_GT(checked, W * H - 60);
}

TEST(RoiCloud, GrowRegionsEqualsAFloodFillSeededInRasterOrder) {
  // Smooth depth in tiles 3 cm apart in depth, 5% of the pixels missing.
  Frame frame = RandomFrame(640, 480, 5);
  std::mt19937 holes(9);
  for (int v = 0; v < 480; ++v) {
    for (int u = 0; u < 640; ++u) {
      const bool missing = std::uniform_int_distribution<int>(0, 19)(holes) == 0;
      frame.depth.at(u, v) = missing ? kNaN : 0.9f + 0.01f * std::sin(u / 40.f) + 0.03f * static_cast<float>((u / 90 + v / 70) % 3);
    }
  }
  RoiCloud roi;
  CropToRoi(frame, Pose::Identity(), Box(), &roi);
  ASSERT_GT(roi.points_B.size(), 10000u);
  std::mt19937 rng(3);
  std::normal_distribution<float> g(0.f, 1.f);
  std::uniform_int_distribution<int> kind(0, 19);
  for (int stride : {1, 2}) {
    const SampleGrid grid = MakeSampleGrid(roi, stride);
    // Normals near +z or near +x (so that both the angle and the crease
    // test decide), a few NaN; a few cells excluded.
    std::vector<Eigen::Vector3f> normals(grid.point_of_cell.size());
    std::vector<uint8_t> excluded(grid.point_of_cell.size(), 0);
    for (size_t c = 0; c < normals.size(); ++c) {
      const int k = kind(rng);
      const Eigen::Vector3f axis = k < 10 ? Eigen::Vector3f::UnitZ() : Eigen::Vector3f::UnitX();
      normals[c] = k == 0 ? Eigen::Vector3f::Constant(kNaN) : (axis + 0.3f * Eigen::Vector3f(g(rng), g(rng), g(rng))).normalized();
      excluded[c] = k == 1 ? 1 : 0;
    }
    struct Case {
      float jump, angle, convex;
      bool with_excluded;
    };
    for (const Case& k : {Case{0.01f, 0.f, -1.f, false}, Case{0.01f, 0.8f, -1.f, true}, Case{0.01f, 0.6f, 0.f, true},
                          Case{0.01f, 0.6f, 0.05f, false}}) {
      const std::vector<uint8_t>& ex = k.with_excluded ? excluded : std::vector<uint8_t>{};
      std::vector<int32_t> got;
      const int n = GrowRegions(roi, grid, k.angle > 0.f ? normals : std::vector<Eigen::Vector3f>{}, k.jump, k.angle,
                                ex, &got, k.convex);
      const std::vector<int32_t> want = FloodFillRegions(roi, grid, normals, k.jump, k.angle, ex, k.convex);
      ASSERT_EQ(got, want) << "stride " << stride << " jump " << k.jump << " angle " << k.angle;
      const int32_t most = *std::max_element(want.begin(), want.end());
      EXPECT_EQ(n, most + 1);
      // Neither one region nor all singletons.
      std::vector<int> size(static_cast<size_t>(n), 0);
      for (int32_t r : want) size[static_cast<size_t>(std::max(r, 0))] += r >= 0 ? 1 : 0;
      EXPECT_GT(n, 10);
      EXPECT_GE(*std::max_element(size.begin(), size.end()), 50) << "stride " << stride << " jump " << k.jump;
    }
  }
}

// The segment stage counts, per connected region, its kept and fragment
// samples and whether it holds two kept segments, over ranges of cells in
// parallel: merging the ranges' counts in order gives the count of all cells
// in one pass, wherever the ranges split (regions whose only two segments
// fall one into each range included).
TEST(RegionSegmentCounts, MergedRangesCountLikeOnePass) {
  std::mt19937 rng(5);
  for (int trial = 0; trial < 200; ++trial) {
    const int regions = 1 + trial % 7;
    const int cells = 1 + static_cast<int>(rng() % 60);
    std::vector<std::tuple<int32_t, int32_t, bool>> seq;
    for (int c = 0; c < cells; ++c) {
      const auto r = static_cast<int32_t>(rng() % regions);
      // Few segments per region, so that runs of one segment are common.
      const int32_t s = rng() % 4 == 0 ? -1 : static_cast<int32_t>(r * 3 + rng() % (1 + trial % 3));
      seq.emplace_back(r, s, s < 0 && rng() % 2 == 0);
    }
    RegionSegmentCounts whole(static_cast<size_t>(regions));
    for (const auto& [r, s, f] : seq) whole.Add(r, s, f);
    // Two to four ranges at random cuts.
    std::vector<int> cuts = {0, cells};
    for (int k = 0; k < 1 + trial % 3; ++k) cuts.push_back(static_cast<int>(rng() % (cells + 1)));
    std::sort(cuts.begin(), cuts.end());
    RegionSegmentCounts merged(static_cast<size_t>(regions));
    for (size_t k = 0; k + 1 < cuts.size(); ++k) {
      RegionSegmentCounts part(static_cast<size_t>(regions));
      for (int c = cuts[k]; c < cuts[k + 1]; ++c) {
        const auto& [r, s, f] = seq[static_cast<size_t>(c)];
        part.Add(r, s, f);
      }
      if (k == 0) merged = part;
      else merged.Merge(part);
    }
    EXPECT_EQ(merged.first_segment, whole.first_segment) << "trial " << trial;
    EXPECT_EQ(merged.kept_samples, whole.kept_samples) << "trial " << trial;
    EXPECT_EQ(merged.fragment_samples, whole.fragment_samples) << "trial " << trial;
    EXPECT_EQ(merged.multi, whole.multi) << "trial " << trial;
  }
  // One segment per range of the same region: two segments in all.
  RegionSegmentCounts a(1), b(1);
  a.Add(0, 4, false);
  b.Add(0, 7, false);
  a.Merge(b);
  EXPECT_EQ(a.multi[0], 1);
  EXPECT_EQ(a.first_segment[0], 4);
}

}  // namespace
}  // namespace bp::internal
