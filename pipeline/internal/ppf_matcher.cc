#include "pipeline/internal/ppf_matcher.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <numeric>
#include <string>
#include <utility>

#include "pipeline/internal/table_memo.h"
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
  if (!ModelTableMemoOn()) return Compute(points, normals, params, max_distance);
  static TableMemo<PpfModel> memo;
  // Every field of PpfParams is in the key: one added needs adding here.
  static_assert(sizeof(PpfParams) == sizeof(float) + 3 * sizeof(int));
  static_assert(sizeof(Eigen::Vector3f) == 3 * sizeof(float));  // no padding in the key
  TableMemoKey key;
  key.AddSpan(points).AddSpan(normals).Add(params.distance_step).Add(params.angle_bins).Add(params.alpha_bins);
  key.Add(params.max_bucket_entries).Add(max_distance);
  if (memo.Find(key, this)) return Status::Ok();
  Status s = Compute(points, normals, params, max_distance);
  if (s.ok()) memo.Store(key, *this);
  return s;
}

Status PpfModel::Compute(std::span<const Eigen::Vector3f> points, std::span<const Eigen::Vector3f> normals,
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

namespace {

// The vote accumulator of a Match: per thread, one vector of (model point,
// alpha) cells kept from call to call, all zero in between (a fresh one per
// call was a memset of 60-250 KB, several hundred times per frame). A Match
// takes it for its duration and gives it back zeroed (Return); a Match that
// ends with an exception drops it, and one called from inside another (from
// `accept`) finds none and makes its own: both leave only zeros behind.
class VoteAccumulator {
 public:
  explicit VoteAccumulator(size_t cells) : acc_(std::exchange(Slot(), {})) {
    if (acc_.size() < cells) acc_.resize(cells, 0);
  }
  uint16_t* data() { return acc_.data(); }
  // Every cell must be zero again.
  void Return() { Slot() = std::move(acc_); }

 private:
  static std::vector<uint16_t>& Slot() {
    thread_local std::vector<uint16_t> slot;
    return slot;
  }
  std::vector<uint16_t> acc_;
};

// Merges the candidates (most votes first) into clusters within the
// translation and symmetry-aware rotation thresholds; the max_poses most
// voted clusters.
std::vector<CoarsePose> Cluster(std::vector<CoarsePose> candidates, const PpfMatchOptions& options,
                                const Symmetry& symmetry) {
  std::vector<CoarsePose> out;
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

// A replay is used only when it was recorded for the same points and
// reference selection with at least as many peaks as examined.
bool ReplayFits(const PpfVotes& replay, size_t points, const PpfMatchOptions& options) {
  return replay.points == points && replay.reference_stride == options.reference_stride &&
         replay.max_reference_points == options.max_reference_points && replay.max_partners == options.max_partners &&
         replay.min_peak_fraction == options.min_peak_fraction &&
         replay.recorded_peaks >= static_cast<size_t>(std::max(1, options.peaks_examined));
}

}  // namespace

// One Match: the scene, the options and the buffers its reference points
// reuse.
struct PpfModel::MatchRun {
  MatchRun(std::span<const Eigen::Vector3f> p, std::span<const Eigen::Vector3f> n, const PpfMatchOptions& o)
      : points(p), normals(n), options(o) {}
  std::span<const Eigen::Vector3f> points, normals;
  const PpfMatchOptions& options;
  int NA = 0;
  float alpha_scale = 0.f;
  std::vector<uint32_t> cells;    // per entry of one pair's bucket: its accumulator cell
  std::vector<uint32_t> touched;  // the cells one reference point voted for (each once)
  std::vector<std::pair<uint16_t, uint32_t>> peaks;  // (votes, accumulator cell)
  // Per partner: its key's entry range and its alpha in bins.
  struct Pair {
    uint32_t begin, end;
    float alpha;
  };
  std::vector<Pair> pairs;
  std::vector<uint32_t> in_range;
  std::vector<std::pair<uint32_t, int>> keyed;  // (partner, key)
  std::vector<CoarsePose> candidates;
};

// Poses from reference point r's peaks (most votes first, then lowest cell;
// at least the first peaks_examined of those above the floor): the first
// peaks_per_reference that `accept` takes.
void PpfModel::Emit(MatchRun& run, size_t r, int best, size_t best_bin,
                    std::span<const std::pair<uint16_t, uint32_t>> sorted) const {
  const PpfMatchOptions& options = run.options;
  const int NA = run.NA;
  const Eigen::Vector3f& sr = run.points[r];
  const Eigen::Matrix3f Rs = AlignToX(run.normals[r]);
  // X_BO: x -> s_r + Rs^T * Rx(alpha) * Rm * (x - m_r)
  const auto pose_of = [&](size_t bin) {
    const size_t mr = bin / NA;
    const float alpha = (static_cast<float>(bin % NA) + 0.5f) / run.alpha_scale;
    const Eigen::Matrix3f R =
        Rs.transpose() * Eigen::AngleAxisf(alpha, Eigen::Vector3f::UnitX()).toRotationMatrix() * to_canonical_[mr];
    const Eigen::Vector3f t = sr - R * points_[mr];
    return MakePose(R.cast<double>(), t.cast<double>());
  };
  if (options.peaks_examined <= 1 && !options.accept) {
    run.candidates.push_back(CoarsePose{pose_of(best_bin), best});
    return;
  }
  const size_t examine = std::min(sorted.size(), static_cast<size_t>(std::max(1, options.peaks_examined)));
  int kept = 0;
  for (size_t p = 0; p < examine && kept < options.peaks_per_reference; ++p) {
    const Pose X = pose_of(sorted[p].second);
    if (options.accept && !options.accept(X)) continue;
    run.candidates.push_back(CoarsePose{X, sorted[p].first});
    ++kept;
  }
}

// Reference point r's votes into acc: of the points within the model's
// diameter of it (no pair farther apart is in the table), every
// partner_stride-th pairs with it (offset by the reference point, so that
// the references together use every point: a view of two parts spends the
// partners on the reference point's own neighbourhood). Lists the cells
// voted for in run.touched; @returns the most votes of any cell.
int PpfModel::Vote(MatchRun& run, size_t r, uint16_t* acc) const {
  const std::span<const Eigen::Vector3f> points = run.points, normals = run.normals;
  const size_t ns = points.size();
  const int NA = run.NA;
  const float fNA = static_cast<float>(NA);
  const size_t max_partners = static_cast<size_t>(std::max(1, run.options.max_partners));
  const float max_d2 = max_distance_ * max_distance_;
  const Eigen::Vector3f& sr = points[r];
  const Eigen::Vector3f& nr = normals[r];
  const Eigen::Matrix3f Rs = AlignToX(nr);
  run.pairs.clear();
  size_t votes = 0;
  run.in_range.clear();
  for (size_t i = 0; i < ns; ++i) {
    if (i != r && (points[i] - sr).squaredNorm() < max_d2) run.in_range.push_back(static_cast<uint32_t>(i));
  }
  const size_t partner_stride = std::max<size_t>(1, (run.in_range.size() + max_partners - 1) / max_partners);
  // The partners' keys first, their table offsets prefetched (the offsets
  // and the entries are cache misses; one loop per step lets many be in
  // flight at once), then their entry ranges, whose first entries are
  // prefetched for the vote.
  run.keyed.clear();
  for (size_t j = r % partner_stride; j < run.in_range.size(); j += partner_stride) {
    const uint32_t i = run.in_range[j];
    const int k = Key(sr, nr, points[i], normals[i]);
    if (k < 0) continue;
    __builtin_prefetch(offsets_.data() + k);
    run.keyed.emplace_back(i, k);
  }
  for (const auto& [i, k] : run.keyed) {
    const uint32_t begin = offsets_[k], end = offsets_[k + 1];
    if (begin == end) continue;
    __builtin_prefetch(entries_.data() + begin);
    // alpha_s in [0, NA] bins, as the table's alpha_m: their difference
    // mod NA is the rotation's bin.
    const float alpha_s = Alpha(Rs, points[i] - sr) * run.alpha_scale;
    run.pairs.push_back(MatchRun::Pair{begin, end, alpha_s < 0.f ? alpha_s + fNA : alpha_s});
    votes += end - begin;
  }
  // The accumulator is zero between reference points: only the cells a
  // reference point touched (listed in `touched`, appended without a branch:
  // a cell's first vote is about every other one, which a branch mispredicts)
  // are read for its peaks and reset after it.
  std::vector<uint32_t>& touched = run.touched;
  touched.resize(votes + 1);
  size_t n_touched = 0;
  uint32_t* const cells = run.cells.data();
  const Entry* const entries = entries_.data();
  const float alpha_unit = 1.f / static_cast<float>(alpha_units_);  // a power of two: exact
  uint16_t most = 0;  // the most votes of any cell
  for (const MatchRun::Pair& pr : run.pairs) {
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
      const uint16_t v = ++acc[cell];
      touched[n_touched] = cell;
      n_touched += v == 1;
      most = std::max(most, v);
    }
  }
  touched.resize(n_touched);
  return most;
}

std::vector<CoarsePose> PpfModel::Match(std::span<const Eigen::Vector3f> points,
                                        std::span<const Eigen::Vector3f> normals,
                                        std::span<const uint8_t> reference_ok, const PpfMatchOptions& options,
                                        const Symmetry& symmetry) const {
  const size_t ns = points.size();
  const size_t nm = points_.size();
  if (ns < 3 || nm == 0) return {};
  MatchRun run(points, normals, options);
  run.NA = params_.alpha_bins;
  run.alpha_scale = static_cast<float>(run.NA) / kTwoPi;
  run.cells.resize(static_cast<size_t>(std::max(1, params_.max_bucket_entries)));
  run.pairs.reserve(ns);
  run.in_range.reserve(ns);
  run.keyed.reserve(std::min(ns, static_cast<size_t>(std::max(1, options.max_partners)) + 1));
  if (options.record != nullptr) {
    *options.record = PpfVotes{};
    options.record->points = ns;
    options.record->reference_stride = options.reference_stride;
    options.record->max_reference_points = options.max_reference_points;
    options.record->max_partners = options.max_partners;
    options.record->min_peak_fraction = options.min_peak_fraction;
    options.record->recorded_peaks = std::max(options.record_peaks, static_cast<size_t>(std::max(1, options.peaks_examined)));
  }
  // Replayed peaks are read instead of voting again.
  if (options.replay != nullptr && ReplayFits(*options.replay, ns, options)) {
    for (const PpfVotes::Reference& ref : options.replay->references) Emit(run, ref.point, ref.best, ref.best_bin, ref.peaks);
    return Cluster(std::move(run.candidates), options, symmetry);
  }
  // Reference points: every stride-th eligible point, at most max_reference_points.
  std::vector<uint32_t> refs;
  for (size_t i = 0; i < ns; ++i) {
    if (reference_ok.size() != ns || reference_ok[i]) refs.push_back(static_cast<uint32_t>(i));
  }
  size_t stride = static_cast<size_t>(std::max(1, options.reference_stride));
  stride = std::max(stride, (refs.size() + options.max_reference_points - 1) / std::max(1, options.max_reference_points));
  VoteAccumulator acc(nm * static_cast<size_t>(run.NA));
  for (size_t ri = 0; ri < refs.size(); ri += stride) {
    const size_t r = refs[ri];
    const int best = Vote(run, r, acc.data());
    Peaks(run, r, best, acc.data());
  }
  acc.Return();
  return Cluster(std::move(run.candidates), options, symmetry);
}

// One pass over reference point r's touched cells (the most votes, best, are
// known from the vote): each back to zero for the next reference point, and
// the peaks above the floor collected; the lowest cell with the most votes is
// then the first peak in peak order (with no peaks wanted, the floor is the
// most votes and that cell the lowest peak). Then the poses (Emit) and the
// record.
void PpfModel::Peaks(MatchRun& run, size_t r, int best, uint16_t* acc) const {
  const PpfMatchOptions& options = run.options;
  const bool want_peaks = !(options.peaks_examined <= 1 && !options.accept && options.record == nullptr);
  const int floor_votes =
      best < 3 ? std::numeric_limits<int>::max()
      : want_peaks
          ? std::clamp(static_cast<int>(std::ceil(options.min_peak_fraction * static_cast<float>(best))), 3, best)
          : best;
  std::vector<std::pair<uint16_t, uint32_t>>& peaks = run.peaks;
  peaks.clear();
  for (const uint32_t cell : run.touched) {
    const int v = acc[cell];
    acc[cell] = 0;
    if (v >= floor_votes) peaks.emplace_back(static_cast<uint16_t>(v), cell);
  }
  if (best < 3) return;
  if (!want_peaks) {
    uint32_t best_bin = peaks.front().second;
    for (const auto& pk : peaks) best_bin = std::min(best_bin, pk.second);
    Emit(run, r, best, best_bin, {});
    return;
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
  Emit(run, r, best, best_bin, top);
}

}  // namespace bp::internal
