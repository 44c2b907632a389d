// Point-pair-feature voting (Drost, Ulrich, Navab, Ilic, CVPR 2010).
//
// Model table: every ordered pair (r, i) of sampled model points gives the
// feature F = (|d|, angle(n_r, d), angle(n_i, d), angle(n_r, n_i)), quantised
// by the distance step and the angle step into a dense key (no hashing: the
// key space is n_dist * n_angle^3). Entries are stored CSR-style: offsets by
// key, then (r, alpha_m) with alpha_m the angle of m_i about the x axis after
// moving m_r to the origin and n_r onto +x. An entry is 4 bytes (16-bit r,
// alpha_m in 16-bit fixed point): voting reads the table at random, and the
// shipped parts' tables (3.3 MB in all, 6.6 MB with a 32-bit r and a float
// alpha_m) share the caches with the closest-point fields ICP reads.
//
// Matching: for each scene reference point s_r and partner s_i, the entries of
// the pair's key vote for (r, alpha = alpha_s - alpha_m) in a 2D accumulator;
// the peak gives X_BO = T_s^-1 * Rx(alpha) * T_m. Poses from all reference
// points are clustered (translation + symmetry-aware rotation thresholds).
#pragma once

#include <algorithm>
#include <array>
#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include <Eigen/Core>
#include <Eigen/Geometry>

#include "core/cell.h"
#include "core/pose.h"
#include "core/status.h"

namespace bp::internal {

struct PpfParams {
  float distance_step = 0.003f;  // metres
  int angle_bins = 15;           // feature angles over [0, pi]; at most 255
  int alpha_bins = 30;           // alpha over [0, 2 pi)
  // Keys with more entries keep an evenly spread subset of this size. Large
  // buckets are the non-discriminative pairs (mostly coplanar ones); capping
  // them bounds the voting cost and acts as inverse-frequency weighting.
  int max_bucket_entries = 100;
};

struct CoarsePose {
  Pose X_BO = Pose::Identity();
  int votes = 0;
};

// Per reference point, the accumulator's best cells a Match found, so that a
// later Match of the same points with the same reference points and
// partners (the perception's second look, with more peaks per reference
// point) reads them instead of voting again.
struct PpfVotes {
  struct Reference {
    uint32_t point = 0;     // scene point index
    int best = 0;           // votes of the best cell
    uint32_t best_bin = 0;  // the best cell (lowest index among ties)
    std::vector<std::pair<uint16_t, uint32_t>> peaks;  // (votes, cell), most first, then lowest cell
  };
  std::vector<Reference> references;  // those with >= 3 votes, in order
  // What the votes depend on besides the points and the model.
  size_t points = 0;
  int reference_stride = 0, max_reference_points = 0, max_partners = 0;
  float min_peak_fraction = 0;
  size_t recorded_peaks = 0;  // per reference point, at most
  bool empty() const { return points == 0; }
};

struct PpfMatchOptions {
  int reference_stride = 5;          // every k-th scene point is a reference point
  int max_reference_points = 80;
  // Each reference point pairs with at most about this many scene points
  // (evenly strided); large segments vote on a subset.
  int max_partners = 1 << 30;
  double cluster_translation = 0.01; // metres
  double cluster_rotation = 0.4;     // radians
  int max_poses = 4;
  // Per reference point, the accumulator's highest cells (with at least
  // min_peak_fraction of its best count) are turned into poses in order and
  // the first peaks_per_reference that `accept` takes are kept (Drost keeps
  // every peak near the best). Several peaks matter for planar views, where
  // many placements of the model's faces tie; `accept` (e.g. "does not sink
  // into the bin floor") lets a physically possible placement win over a
  // better-voted impossible one. Unset: every pose is accepted.
  int peaks_per_reference = 1;
  int peaks_examined = 1;
  float min_peak_fraction = 0.5f;
  std::function<bool(const Pose&)> accept;
  // record: filled with the peaks (at most record_peaks per reference
  // point). replay: read instead of voting when it was recorded for the
  // same points and options with at least peaks_examined peaks (else
  // ignored).
  PpfVotes* record = nullptr;
  size_t record_peaks = 16;
  const PpfVotes* replay = nullptr;
};

class PpfModel {
 public:
  // points / normals: the sampled model in O (unit normals). At most
  // kMaxModelPoints points (InvalidArgument beyond). With the model table
  // memo on (internal/table_memo.h), a copy of an earlier build from the same
  // inputs.
  static constexpr size_t kMaxModelPoints = 65536;
  Status Build(std::span<const Eigen::Vector3f> points, std::span<const Eigen::Vector3f> normals,
               const PpfParams& params, float max_distance);

  // Clustered coarse poses, most votes first. scene points / normals in B,
  // subsampled at about the model's distance step. Thread-safe: the vote
  // accumulator is per thread (kept between calls, all zero in between), and
  // a Match called from `accept` gets its own.
  // reference_ok (optional, one per point): 0 excludes a point as a reference
  // point (it still votes as a partner).
  std::vector<CoarsePose> Match(std::span<const Eigen::Vector3f> points, std::span<const Eigen::Vector3f> normals,
                                std::span<const uint8_t> reference_ok, const PpfMatchOptions& options,
                                const Symmetry& symmetry) const;

  size_t size() const { return points_.size(); }
  size_t pair_count() const { return entries_.size(); }

 private:
  // Build without the memo.
  Status Compute(std::span<const Eigen::Vector3f> points, std::span<const Eigen::Vector3f> normals,
                 const PpfParams& params, float max_distance);
  struct MatchRun;
  int Vote(MatchRun& run, size_t r, uint16_t* acc) const;
  void Peaks(MatchRun& run, size_t r, int best, uint16_t* acc) const;
  void Emit(MatchRun& run, size_t r, int best, size_t best_bin,
            std::span<const std::pair<uint16_t, uint32_t>> sorted) const;
  // Dense feature key, or -1 if the pair is out of range.
  int Key(const Eigen::Vector3f& p1, const Eigen::Vector3f& n1, const Eigen::Vector3f& p2,
          const Eigen::Vector3f& n2) const;

  // Angle bin of the angle whose cosine is c, by table (no acos per pair).
  int AngleBin(float c) const {
    const int i = static_cast<int>((std::clamp(c, -1.f, 1.f) + 1.f) * (0.5f * (kCosTable - 1)) + 0.5f);
    return cos_to_bin_[i];
  }
  static constexpr int kCosTable = 4096;
  std::array<uint8_t, kCosTable> cos_to_bin_{};

  struct Entry {
    uint16_t ref;    // model reference point
    uint16_t alpha;  // alpha_m in [0, 2 pi), in alpha bins times alpha_units_
  };
  // Fixed-point units per alpha bin: the largest power of two that keeps
  // alpha_bins * units within 16 bits (2048 for 30 bins: 0.006 deg), so
  // that units^-1 scales exactly.
  int alpha_units_ = 1;
  PpfParams params_;
  float max_distance_ = 0;
  int n_dist_ = 0;
  std::vector<Eigen::Vector3f> points_, normals_;
  std::vector<Eigen::Matrix3f> to_canonical_;  // R with R * n_r = +x
  std::vector<uint32_t> offsets_;              // size = keys + 1
  std::vector<Entry> entries_;
};

// Rotation taking unit vector n onto +x.
Eigen::Matrix3f AlignToX(const Eigen::Vector3f& n);

}  // namespace bp::internal
