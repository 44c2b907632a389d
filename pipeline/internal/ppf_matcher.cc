#include "pipeline/internal/ppf_matcher.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <numeric>
#include <string>

#include "pipeline/pose_estimator.h"

namespace bp::internal {
namespace {

constexpr float kTwoPi = static_cast<float>(2.0 * M_PI);

// atan2 to ~1e-5 rad (polynomial on [0, 1]); far below the 12 deg alpha bins.
inline float FastAtan2(float y, float x) {
  const float ax = std::abs(x), ay = std::abs(y);
  const float mx = std::max(ax, ay);
  if (mx == 0.f) return 0.f;
  const float a = std::min(ax, ay) / mx;
  const float s = a * a;
  float r = ((-0.0464964749f * s + 0.15931422f) * s - 0.327622764f) * s * a + a;
  if (ay > ax) r = 1.57079637f - r;
  if (x < 0) r = 3.14159274f - r;
  return y < 0 ? -r : r;
}

inline float Alpha(const Eigen::Matrix3f& R, const Eigen::Vector3f& d) {
  const Eigen::Vector3f p = R * d;
  return FastAtan2(p.z(), p.y());
}

}  // namespace

Eigen::Matrix3f AlignToX(const Eigen::Vector3f& n) {
  const Eigen::Vector3f x = Eigen::Vector3f::UnitX();
  const Eigen::Vector3f axis = n.cross(x);
  const float s = axis.norm();
  const float c = n.dot(x);
  if (s < 1e-6f) {
    if (c > 0) return Eigen::Matrix3f::Identity();
    return Eigen::AngleAxisf(static_cast<float>(M_PI), Eigen::Vector3f::UnitY()).toRotationMatrix();
  }
  return Eigen::AngleAxisf(std::atan2(s, c), axis / s).toRotationMatrix();
}

int PpfModel::Key(const Eigen::Vector3f& p1, const Eigen::Vector3f& n1, const Eigen::Vector3f& p2,
                  const Eigen::Vector3f& n2) const {
  const Eigen::Vector3f d = p2 - p1;
  const float dist = d.norm();
  if (!(dist < max_distance_) || dist <= 0.f) return -1;
  const int db = static_cast<int>(dist / params_.distance_step);
  const int A = params_.angle_bins;
  const float inv = 1.f / dist;
  const int a1 = AngleBin(n1.dot(d) * inv);
  const int a2 = AngleBin(n2.dot(d) * inv);
  const int a3 = AngleBin(n1.dot(n2));
  return ((db * A + a1) * A + a2) * A + a3;
}

Status PpfModel::Build(std::span<const Eigen::Vector3f> points, std::span<const Eigen::Vector3f> normals,
                       const PpfParams& params, float max_distance) {
  if (points.size() > kMaxModelPoints || normals.size() != points.size()) {
    return Status::InvalidArgument("PPF model: " + std::to_string(points.size()) + " points and " +
                                   std::to_string(normals.size()) + " normals; at most " +
                                   std::to_string(kMaxModelPoints) + " points, one normal each");
  }
  if (params.alpha_bins < 1 || params.alpha_bins > 0xFFFF || params.angle_bins < 1 || params.angle_bins > 255) {
    return Status::InvalidArgument("PPF model: alpha_bins must be in [1, 65535] and angle_bins in [1, 255]");
  }
  params_ = params;
  alpha_units_ = static_cast<int>(std::bit_floor(static_cast<unsigned>(0xFFFF / params.alpha_bins)));
  max_distance_ = max_distance;
  points_.assign(points.begin(), points.end());
  normals_.assign(normals.begin(), normals.end());
  const size_t n = points_.size();
  to_canonical_.resize(n);
  for (size_t i = 0; i < n; ++i) to_canonical_[i] = AlignToX(normals_[i]);
  n_dist_ = static_cast<int>(max_distance / params.distance_step) + 1;
  for (int i = 0; i < kCosTable; ++i) {
    const double c = -1.0 + 2.0 * i / (kCosTable - 1);
    cos_to_bin_[i] = static_cast<uint8_t>(
        std::min(params.angle_bins - 1, static_cast<int>(std::acos(c) * params.angle_bins / M_PI)));
  }
  const int A = params.angle_bins;
  const size_t keys = static_cast<size_t>(n_dist_) * A * A * A;
  offsets_.assign(keys + 1, 0);
  // Two passes: count per key, then fill.
  for (size_t r = 0; r < n; ++r) {
    for (size_t i = 0; i < n; ++i) {
      if (i == r) continue;
      const int k = Key(points_[r], normals_[r], points_[i], normals_[i]);
      if (k >= 0) ++offsets_[k + 1];
    }
  }
  std::partial_sum(offsets_.begin(), offsets_.end(), offsets_.begin());
  entries_.resize(offsets_.back());
  const float alpha_scale = static_cast<float>(params.alpha_bins) / kTwoPi;
  std::vector<uint32_t> fill(offsets_.begin(), offsets_.end() - 1);
  for (size_t r = 0; r < n; ++r) {
    for (size_t i = 0; i < n; ++i) {
      if (i == r) continue;
      const int k = Key(points_[r], normals_[r], points_[i], normals_[i]);
      if (k < 0) continue;
      // alpha_m in [0, alpha_bins) bins, to fixed point.
      float alpha_bins = Alpha(to_canonical_[r], points_[i] - points_[r]) * alpha_scale;
      if (alpha_bins < 0.f) alpha_bins += static_cast<float>(params.alpha_bins);
      const int units = params.alpha_bins * alpha_units_;
      int q = static_cast<int>(std::lround(alpha_bins * static_cast<float>(alpha_units_)));
      if (q >= units) q -= units;
      entries_[fill[k]++] = Entry{static_cast<uint16_t>(r), static_cast<uint16_t>(q)};
    }
  }
  // Cap bucket sizes (evenly spread subset), compacting in place.
  const size_t cap = static_cast<size_t>(std::max(1, params.max_bucket_entries));
  size_t write = 0;
  uint32_t begin = offsets_[0];
  for (size_t k = 0; k < keys; ++k) {
    const uint32_t end = offsets_[k + 1];
    const size_t count = end - begin;
    offsets_[k] = static_cast<uint32_t>(write);
    if (count <= cap) {
      for (uint32_t e = begin; e < end; ++e) entries_[write++] = entries_[e];
    } else {
      for (size_t j = 0; j < cap; ++j) entries_[write++] = entries_[begin + (j * count) / cap];
    }
    begin = end;
  }
  offsets_[keys] = static_cast<uint32_t>(write);
  entries_.resize(write);
  entries_.shrink_to_fit();
  return Status::Ok();
}

std::vector<CoarsePose> PpfModel::Match(std::span<const Eigen::Vector3f> points,
                                        std::span<const Eigen::Vector3f> normals,
                                        std::span<const uint8_t> reference_ok, const PpfMatchOptions& options,
                                        const Symmetry& symmetry) const {
  std::vector<CoarsePose> out;
  const size_t ns = points.size();
  const size_t nm = points_.size();
  if (ns < 3 || nm == 0) return out;
  const int NA = params_.alpha_bins;
  const float alpha_scale = static_cast<float>(NA) / kTwoPi;
  // The accumulator is zero between reference points: only the cells a
  // reference point touched (listed in `touched`, appended without a branch:
  // a cell's first vote is about every other one, which a branch mispredicts)
  // are read for its peaks and reset after it. So it is zero between calls
  // too, and each thread keeps one: a fresh one per call was a memset of
  // 60-250 KB, several hundred times per frame. A call that ends early (an
  // exception) leaves it marked dirty, and the next call clears it.
  thread_local std::vector<uint16_t> acc;
  thread_local bool acc_dirty = false;
  if (acc_dirty) std::fill(acc.begin(), acc.end(), uint16_t{0});
  if (acc.size() < nm * NA) acc.resize(nm * NA, 0);
  acc_dirty = true;
  std::vector<uint32_t> cells_buffer(static_cast<size_t>(std::max(1, params_.max_bucket_entries)));
  uint32_t* const cells = cells_buffer.data();
  std::vector<uint32_t> touched;
  std::vector<CoarsePose> candidates;
  std::vector<std::pair<uint16_t, uint32_t>> peaks;  // (votes, accumulator cell)

  // Reference points: every stride-th eligible point, at most max_reference_points.
  std::vector<uint32_t> refs;
  for (size_t i = 0; i < ns; ++i) {
    if (reference_ok.size() != ns || reference_ok[i]) refs.push_back(static_cast<uint32_t>(i));
  }
  size_t stride = static_cast<size_t>(std::max(1, options.reference_stride));
  stride = std::max(stride, (refs.size() + options.max_reference_points - 1) / std::max(1, options.max_reference_points));
  // Per partner: its key's entry range and its alpha in bins.
  struct Pair {
    uint32_t begin, end;
    float alpha;
  };
  std::vector<Pair> pairs;
  pairs.reserve(ns);
  const float fNA = static_cast<float>(NA);
  // Of the points within the model's diameter of a reference point (no pair
  // farther apart is in the table), every partner_stride-th pairs with it
  // (offset by the reference point, so that the references together use
  // every point): a view of two parts spends the partners on the reference
  // point's own neighbourhood.
  const size_t max_partners = static_cast<size_t>(std::max(1, options.max_partners));
  const float max_d2 = max_distance_ * max_distance_;
  std::vector<uint32_t> in_range;
  in_range.reserve(ns);
  std::vector<std::pair<uint32_t, int>> keyed;  // (partner, key)
  keyed.reserve(std::min(ns, max_partners + 1));
  // Poses from reference point r's peaks (most votes first, then lowest cell;
  // at least the first peaks_examined of those above the floor).
  const auto emit = [&](size_t r, int best, size_t best_bin, std::span<const std::pair<uint16_t, uint32_t>> sorted) {
    const Eigen::Vector3f& sr = points[r];
    const Eigen::Matrix3f Rs = AlignToX(normals[r]);
    // X_BO: x -> s_r + Rs^T * Rx(alpha) * Rm * (x - m_r)
    const auto pose_of = [&](size_t bin) {
      const size_t mr = bin / NA;
      const float alpha = (static_cast<float>(bin % NA) + 0.5f) / alpha_scale;
      const Eigen::Matrix3f R =
          Rs.transpose() * Eigen::AngleAxisf(alpha, Eigen::Vector3f::UnitX()).toRotationMatrix() * to_canonical_[mr];
      const Eigen::Vector3f t = sr - R * points_[mr];
      return MakePose(R.cast<double>(), t.cast<double>());
    };
    if (options.peaks_examined <= 1 && !options.accept) {
      candidates.push_back(CoarsePose{pose_of(best_bin), best});
      return;
    }
    const size_t examine = std::min(sorted.size(), static_cast<size_t>(std::max(1, options.peaks_examined)));
    int kept = 0;
    for (size_t p = 0; p < examine && kept < options.peaks_per_reference; ++p) {
      const Pose X = pose_of(sorted[p].second);
      if (options.accept && !options.accept(X)) continue;
      candidates.push_back(CoarsePose{X, sorted[p].first});
      ++kept;
    }
  };
  const PpfVotes* replay = options.replay;
  if (replay != nullptr &&
      (replay->points != ns || replay->reference_stride != options.reference_stride ||
       replay->max_reference_points != options.max_reference_points || replay->max_partners != options.max_partners ||
       replay->min_peak_fraction != options.min_peak_fraction ||
       replay->recorded_peaks < static_cast<size_t>(std::max(1, options.peaks_examined)))) {
    replay = nullptr;
  }
  if (replay != nullptr) {
    for (const PpfVotes::Reference& ref : replay->references) emit(ref.point, ref.best, ref.best_bin, ref.peaks);
    refs.clear();  // no voting
  }
  if (options.record != nullptr) {
    *options.record = PpfVotes{};
    options.record->points = ns;
    options.record->reference_stride = options.reference_stride;
    options.record->max_reference_points = options.max_reference_points;
    options.record->max_partners = options.max_partners;
    options.record->min_peak_fraction = options.min_peak_fraction;
    options.record->recorded_peaks = std::max(options.record_peaks, static_cast<size_t>(std::max(1, options.peaks_examined)));
  }
  for (size_t ri = 0; ri < refs.size(); ri += stride) {
    const size_t r = refs[ri];
    const Eigen::Vector3f& sr = points[r];
    const Eigen::Vector3f& nr = normals[r];
    const Eigen::Matrix3f Rs = AlignToX(nr);
    pairs.clear();
    size_t votes = 0;
    in_range.clear();
    for (size_t i = 0; i < ns; ++i) {
      if (i != r && (points[i] - sr).squaredNorm() < max_d2) in_range.push_back(static_cast<uint32_t>(i));
    }
    const size_t partner_stride = std::max<size_t>(1, (in_range.size() + max_partners - 1) / max_partners);
    // The partners' keys first, their table offsets prefetched (the offsets
    // and the entries are cache misses; one loop per step lets many be in
    // flight at once), then their entry ranges, whose first entries are
    // prefetched for the vote.
    keyed.clear();
    for (size_t j = r % partner_stride; j < in_range.size(); j += partner_stride) {
      const uint32_t i = in_range[j];
      const int k = Key(sr, nr, points[i], normals[i]);
      if (k < 0) continue;
      __builtin_prefetch(offsets_.data() + k);
      keyed.emplace_back(i, k);
    }
    for (const auto& [i, k] : keyed) {
      const uint32_t begin = offsets_[k], end = offsets_[k + 1];
      if (begin == end) continue;
      __builtin_prefetch(entries_.data() + begin);
      // alpha_s in [0, NA] bins, as the table's alpha_m: their difference
      // mod NA is the rotation's bin.
      const float alpha_s = Alpha(Rs, points[i] - sr) * alpha_scale;
      pairs.push_back(Pair{begin, end, alpha_s < 0.f ? alpha_s + fNA : alpha_s});
      votes += end - begin;
    }
    touched.resize(votes + 1);
    size_t n_touched = 0;
    uint16_t* const a_cells = acc.data();
    const Entry* const entries = entries_.data();
    const float alpha_unit = 1.f / static_cast<float>(alpha_units_);  // a power of two: exact
    uint16_t most = 0;  // the most votes of any cell
    for (const Pair& pr : pairs) {
      // The cells first (a loop the compiler vectorizes), then the votes.
      const uint32_t n = pr.end - pr.begin;
      const Entry* const pe = entries + pr.begin;
      for (uint32_t j = 0; j < n; ++j) {
        float a = pr.alpha - static_cast<float>(pe[j].alpha) * alpha_unit;
        a += a < 0.f ? fNA : 0.f;
        int b = static_cast<int>(a);
        b -= b >= NA ? NA : 0;
        cells[j] = static_cast<uint32_t>(pe[j].ref) * static_cast<uint32_t>(NA) + static_cast<uint32_t>(b);
      }
      for (uint32_t j = 0; j < n; ++j) {
        const uint32_t cell = cells[j];
        const uint16_t v = ++a_cells[cell];
        touched[n_touched] = cell;
        n_touched += v == 1;
        most = std::max(most, v);
      }
    }
    touched.resize(n_touched);
    // One pass over the touched cells (the most votes are known from the
    // vote loop): each back to zero for the next reference point, and the
    // peaks above the floor collected; the lowest cell with the most votes
    // is then the first peak in peak order (with no peaks wanted, the floor
    // is the most votes and that cell the lowest peak).
    const int best = most;
    const bool want_peaks = !(options.peaks_examined <= 1 && !options.accept && options.record == nullptr);
    const int floor_votes =
        best < 3 ? std::numeric_limits<int>::max()
        : want_peaks
            ? std::clamp(static_cast<int>(std::ceil(options.min_peak_fraction * static_cast<float>(best))), 3, best)
            : best;
    peaks.clear();
    for (const uint32_t cell : touched) {
      const int v = a_cells[cell];
      a_cells[cell] = 0;
      if (v >= floor_votes) peaks.emplace_back(static_cast<uint16_t>(v), cell);
    }
    if (best < 3) continue;
    if (!want_peaks) {
      uint32_t best_bin = peaks.front().second;
      for (const auto& pk : peaks) best_bin = std::min(best_bin, pk.second);
      emit(r, best, best_bin, {});
      continue;
    }
    size_t sorted = static_cast<size_t>(std::max(1, options.peaks_examined));
    if (options.record != nullptr) sorted = std::max(sorted, options.record->recorded_peaks);
    sorted = std::min(peaks.size(), sorted);
    std::partial_sort(peaks.begin(), peaks.begin() + static_cast<std::ptrdiff_t>(sorted), peaks.end(),
                      [](const auto& a, const auto& b) { return a.first > b.first || (a.first == b.first && a.second < b.second); });
    const std::span<const std::pair<uint16_t, uint32_t>> top(peaks.data(), sorted);
    const uint32_t best_bin = top.front().second;
    if (options.record != nullptr) {
      options.record->references.push_back(PpfVotes::Reference{static_cast<uint32_t>(r), best,
                                                               static_cast<uint32_t>(best_bin), {top.begin(), top.end()}});
    }
    emit(r, best, best_bin, top);
  }
  acc_dirty = false;

  std::stable_sort(candidates.begin(), candidates.end(),
                   [](const CoarsePose& a, const CoarsePose& b) { return a.votes > b.votes; });
  for (const CoarsePose& c : candidates) {
    bool merged = false;
    for (CoarsePose& cluster : out) {
      if ((cluster.X_BO.translation() - c.X_BO.translation()).norm() < options.cluster_translation &&
          SymmetricRotationError(cluster.X_BO, c.X_BO, symmetry) < options.cluster_rotation) {
        cluster.votes += c.votes;
        merged = true;
        break;
      }
    }
    if (!merged) out.push_back(c);
  }
  std::stable_sort(out.begin(), out.end(), [](const CoarsePose& a, const CoarsePose& b) { return a.votes > b.votes; });
  if (static_cast<int>(out.size()) > options.max_poses) out.resize(options.max_poses);
  return out;
}

}  // namespace bp::internal
