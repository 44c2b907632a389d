// A precomputed closest-point lookup for a fixed point set (the model's dense
// surface samples, in O): a dense voxel grid over the bounding box plus a band,
// each voxel holding the index of the sample nearest its centre (or -1 beyond
// the band). A lookup is O(1), which is what makes ICP cheap: the table is
// built once per part at start-up. Immutable after Build (thread-safe reads).
#pragma once

#include <cstdint>
#include <limits>
#include <span>
#include <vector>

#include <Eigen/Core>

namespace bp::internal {

class ClosestPointField {
 public:
  // REQUIRES: voxel > 0, band >= voxel. With the model table memo on
  // (internal/table_memo.h), a copy of an earlier build from the same inputs.
  void Build(std::span<const Eigen::Vector3f> points, float voxel, float band);

  // Index of the sample nearest to the voxel containing q, or -1 outside the band.
  int Lookup(const Eigen::Vector3f& q) const {
    const Eigen::Vector3f g = (q - origin_) * inv_voxel_;
    const int x = static_cast<int>(g.x()), y = static_cast<int>(g.y()), z = static_cast<int>(g.z());
    if (g.x() < 0 || g.y() < 0 || g.z() < 0 || x >= dims_.x() || y >= dims_.y() || z >= dims_.z()) return -1;
    return Cell(AxisOffset(x, 0) + AxisOffset(y, 1) + AxisOffset(z, 2));
  }
  // Nearer to exact: the best, measured from q itself, of the samples stored
  // in the 8 voxels whose centres surround q. -1 if none.
  int Nearest(const Eigen::Vector3f& q, std::span<const Eigen::Vector3f> points) const {
    const Eigen::Vector3f g = (q - origin_) * inv_voxel_ - Eigen::Vector3f::Constant(0.5f);
    if (g.x() < 0 || g.y() < 0 || g.z() < 0) return -1;
    const int x0 = static_cast<int>(g.x()), y0 = static_cast<int>(g.y()), z0 = static_cast<int>(g.z());
    if (x0 + 1 >= dims_.x() || y0 + 1 >= dims_.y() || z0 + 1 >= dims_.z()) return -1;
    // Without branches on the data (which voxels are empty, which sample is
    // nearer): those were mispredicted about half the time and cost more
    // than the arithmetic. The first strictly nearest sample wins, as before
    // (x fastest, then y, then z).
    const size_t ox[2] = {AxisOffset(x0, 0), AxisOffset(x0 + 1, 0)};
    const size_t oy[2] = {AxisOffset(y0, 1), AxisOffset(y0 + 1, 1)};
    const size_t oz[2] = {AxisOffset(z0, 2), AxisOffset(z0 + 1, 2)};
    int best = -1;
    float best_d2 = std::numeric_limits<float>::infinity();
    for (int k = 0; k < 8; ++k) {
      const int idx = Cell(oz[k >> 2] + oy[(k >> 1) & 1] + ox[k & 1]);
      const Eigen::Vector3f& p = points[static_cast<size_t>(idx < 0 ? 0 : idx)];
      const float d2 = idx < 0 ? std::numeric_limits<float>::infinity() : (p - q).squaredNorm();
      const bool nearer = d2 < best_d2;
      best = nearer ? idx : best;
      best_d2 = nearer ? d2 : best_d2;
    }
    return best;
  }
  float band() const { return band_; }
  // A sphere around the whole grid: Lookup and Nearest give -1 for every
  // point outside it (they do outside the grid), so a caller that holds the
  // sphere in its own frame can skip such points before transforming them.
  Eigen::Vector3f grid_centre() const { return origin_ + 0.5f * extent(); }
  float grid_radius() const { return 0.5f * extent().norm() * (1.f + 1e-5f); }
  size_t memory_bytes() const { return cells16_.size() * sizeof(uint16_t) + cells_.size() * sizeof(int32_t); }

 private:
  // Build without the memo.
  void Compute(std::span<const Eigen::Vector3f> points, float voxel, float band);
  Eigen::Vector3f extent() const { return dims_.cast<float>() / inv_voxel_; }
  // Voxels are stored in bricks of kBrick^3 (brick after brick, x fastest
  // within and between bricks): the 8 voxels around a point, and the voxels
  // of the neighbouring points ICP looks up next, mostly lie in one brick
  // (1 KB of 16-bit indices) where row-major order put them in four cache
  // lines on pages about 30 KB apart. ICP's lookups are cache misses; the
  // bricks made `BM_PerceptionRun` 640x480 about 7% faster (4^3 bricks
  // about 6%), with the same lookups (docs/perception.md, "ICP").
  static constexpr int kBrickBits = 3, kBrick = 1 << kBrickBits;
  // The part of a voxel's storage index that its coordinate c along axis a
  // gives: brick stride times c / kBrick plus the within-brick stride times
  // c % kBrick; a voxel's index is the sum over its three axes.
  size_t AxisOffset(int c, int a) const {
    return static_cast<size_t>(c >> kBrickBits) * brick_stride_[a] +
           (static_cast<size_t>(c & (kBrick - 1)) << (kBrickBits * a));
  }
  // Sample index of a voxel, -1 for none.
  int Cell(size_t i) const {
    if (!cells16_.empty()) return cells16_[i] == kNone16 ? -1 : static_cast<int>(cells16_[i]);
    return cells_[i];
  }
  static constexpr uint16_t kNone16 = 0xFFFF;
  Eigen::Vector3f origin_ = Eigen::Vector3f::Zero();
  float inv_voxel_ = 1.f, band_ = 0.f;
  Eigen::Vector3i dims_ = Eigen::Vector3i::Zero();
  size_t brick_stride_[3] = {0, 0, 0};  // storage distance between bricks along x, y, z
  std::vector<int32_t> cells_;
  std::vector<uint16_t> cells16_;
};

}  // namespace bp::internal
