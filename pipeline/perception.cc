#include "pipeline/perception.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <map>
#include <limits>
#include <numeric>
#include <tuple>
#include <utility>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/task_arena.h>

#include "pipeline/internal/class_model.h"
#include "pipeline/internal/roi_cloud.h"

namespace bp {

double PerceptionResult::TotalMs() const {
  double total = 0.0;
  for (const StageTiming& t : timings) total += t.ms;
  return total;
}

namespace {

using internal::ClassModel;
using internal::RoiCloud;
using internal::SampleGrid;
using Clock = std::chrono::steady_clock;

double Ms(Clock::time_point t0, Clock::time_point t1) {
  return std::chrono::duration<double, std::milli>(t1 - t0).count();
}

constexpr double kPi = 3.14159265358979323846;

// Points of the floor band (within this height of the floor and facing up) are
// the bin floor, not parts.
constexpr float kFloorBand = 0.004f;
constexpr float kFloorMinNormalZ = 0.95f;
// Two detections are one physical part when their centres (of the part's
// surface, not its origin: an L-bracket's origin is its corner) are closer than this
// fraction of the larger diameter, or when more than kMaxSharedSupport of the
// later one's support is already claimed.
constexpr double kNmsRelativeDistance = 0.3;
constexpr double kMaxSharedSupport = 0.5;
// ... and the accepted detections that hold at least this fraction of the
// later one's support are the ones it conflicts with.
constexpr double kSharedOwner = 0.1;
// Parts of a pile never interpenetrate: a candidate conflicts when more
// than kMaxInsideFraction of its surface samples lie at least kInsideDepth
// inside an accepted detection's material, or the other way round
// (PoseEstimator::CountInside; below half the L-bracket's 5 mm plate).
constexpr float kInsideDepth = 0.001f;
constexpr double kMaxInsideFraction = 0.03;
// A segment is matched again on its unclaimed points when at least this
// fraction of it is left after the first pass.
constexpr double kResidualFraction = 0.25;
// A connected region with one segment is matched as a whole too when its
// pieces below min_segment_points hold at least this fraction of the
// segment's samples (PerceptionOptions::match_regions).
constexpr double kFragmentShare = 0.25;
// A view of a later wave (PerceptionOptions::view_waves) with at least this
// fraction of its points within kExplainedDistance of an accepted detection's
// surface is a piece of a part already found and is not matched.
constexpr double kExplainedFraction = 0.6;
constexpr float kExplainedDistance = 0.0025f;
// Class ranking by PlanarShare (PerceptionOptions::rank_planar_share_weight):
// a view's share counts against a class only this far outside the class's
// range (the range is of whole parts seen from 64 directions; a fragment is
// flatter or more curved than its part), from at most this many normals.
constexpr double kPlanarShareSlack = 0.1;
constexpr size_t kPlanarShareNormals = 128;
// The depth noise of the camera config that captured a frame (organized: the
// one whose intrinsics it has), else of the default config; nullptr when the
// cell has no config.
const NoiseModel* FrameNoise(const CameraSpec& camera, const Frame& frame) {
  if (frame.organized()) {
    const Intrinsics& k = frame.intrinsics;
    for (const CameraConfig& c : camera.configs) {
      const Intrinsics& i = c.intrinsics;
      if (i.width == k.width && i.height == k.height && i.fx == k.fx && i.fy == k.fy && i.cx == k.cx && i.cy == k.cy) {
        return &c.noise;
      }
    }
  }
  if (const CameraConfig* c = camera.FindConfig(camera.default_config)) return &c->noise;
  return camera.configs.empty() ? nullptr : &camera.configs.front().noise;
}

// Axial noise of an organized frame, measured: the median absolute second
// difference along rows (z[u-1] - 2 z[u] + z[u+1], variance 6 sigma^2 for
// independent noise; edges and curvature are outliers the median ignores)
// over a sparse lattice of pixels. Returns {sigma, median depth}; {0, 0} for
// too few samples.
std::pair<double, double> MeasureDepthNoise(const DepthImage& depth) {
  constexpr int kTargetSamples = 20000;
  constexpr float kMaxStep = 0.004f;  // neighbours farther apart in depth: an edge
  const int64_t pixels = static_cast<int64_t>(depth.width) * depth.height;
  const int step = std::max(1, static_cast<int>(std::sqrt(static_cast<double>(pixels) / kTargetSamples)));
  std::vector<float> second, z;
  second.reserve(kTargetSamples * 2);
  z.reserve(kTargetSamples * 2);
  for (int v = 0; v < depth.height; v += step) {
    for (int u = 1; u + 1 < depth.width; u += step) {
      const float a = depth.at(u - 1, v), b = depth.at(u, v), c = depth.at(u + 1, v);
      if (!std::isfinite(a) || !std::isfinite(b) || !std::isfinite(c)) continue;
      if (std::abs(a - b) > kMaxStep || std::abs(c - b) > kMaxStep) continue;
      second.push_back(std::abs(a - 2.f * b + c));
      z.push_back(b);
    }
  }
  if (second.size() < 1000) return {0.0, 0.0};
  const auto median = [](std::vector<float>& x) {
    std::nth_element(x.begin(), x.begin() + static_cast<std::ptrdiff_t>(x.size() / 2), x.end());
    return static_cast<double>(x[x.size() / 2]);
  };
  // sigma = MAD / (0.6745 sqrt(6)) for a Gaussian of variance 6 sigma^2.
  return {median(second) / (0.67449 * std::sqrt(6.0)), median(z)};
}

// Unorganized clouds are grouped by voxel connectivity at this voxel size
// (fine enough that 5000 points scattered through the bin stay isolated).
constexpr float kUnorganizedVoxel = 0.003f;
// Normals use neighbours this far away (in metres on the bin floor).
constexpr double kNormalBaseline = 0.0025;

// How badly a view's principal extents (largest first) match a model's: the
// differences relative to the model's extents, summed. Measured against
// absolute differences with excess costing 4x (the order before the night
// of 2026-12-03): the first class is the one that finds the part more
// often, estimator calls 1504 -> 1451 and first-pass ICPs 6197 -> 5941 on
// seeds 11-40 (3-4% fewer on every range), the same detections on all 130
// scenes and the held-out 30 (the order decides only which class runs
// alone first).
double ExtentMismatch(const Eigen::Vector3f& view, const Eigen::Vector3f& model) {
  double cost = 0.0;
  for (int i = 0; i < 3; ++i) {
    const double m = std::max(1e-6, static_cast<double>(model[i]));
    cost += std::abs(static_cast<double>(view[i]) - m) / m;
  }
  return cost;
}

// How far a view's PlanarShare lies outside a class's range (plus
// kPlanarShareSlack either side); 0 inside it or for share < 0 (not used).
double PlanarShareMismatch(float share, const ClassModel& model) {
  if (share < 0.f) return 0.0;
  const auto [lo, hi] = model.planar_share_range();
  return std::max(0.0, lo - kPlanarShareSlack - share) + std::max(0.0, share - hi - kPlanarShareSlack);
}

struct Candidate {
  int class_id = 0;
  double diameter = 0.0;
  Eigen::Vector3d centre_B = Eigen::Vector3d::Zero();  // the part's surface centroid at the hypothesis
  int segment = 0;
  internal::ClassHypothesis h;
  std::vector<int32_t> support_roi;  // ROI indices
};

class PerceptionImpl final : public Perception {
 public:
  PerceptionImpl(const Cell& cell, const PerceptionOptions& options,
                 std::vector<std::unique_ptr<ClassModel>> models, std::map<int, std::string> failures)
      : cell_(cell), options_(options), models_(std::move(models)), failures_(std::move(failures)),
        box_(internal::MakeRoiBox(cell)) {}

  Result<PerceptionResult> Run(const Frame& frame, const std::vector<int>& classes,
                               PerceptionEffort effort) const override;

 private:
  Cell cell_;
  PerceptionOptions options_;
  std::vector<std::unique_ptr<ClassModel>> models_;
  std::map<int, std::string> failures_;  // class id -> why it has no model
  internal::RoiBox box_;
};

Result<PerceptionResult> PerceptionImpl::Run(const Frame& frame, const std::vector<int>& classes,
                                             PerceptionEffort effort) const {
  PerceptionResult result;
  const bool thorough = effort == PerceptionEffort::kThorough;
  const auto stage = [&result](const char* name, Clock::time_point t0) {
    const Clock::time_point t1 = Clock::now();
    result.timings.push_back({name, Ms(t0, t1)});
    return t1;
  };

  // Which class models this request uses.
  std::vector<const ClassModel*> models;
  std::string model_problems;
  for (const PartSpec& part : cell_.parts) {
    if (!classes.empty() && std::find(classes.begin(), classes.end(), part.class_id) == classes.end()) continue;
    const auto it = std::find_if(models_.begin(), models_.end(),
                                 [&](const auto& m) { return m->class_id() == part.class_id; });
    if (it != models_.end()) {
      models.push_back(it->get());
    } else if (const auto f = failures_.find(part.class_id); f != failures_.end()) {
      model_problems += (model_problems.empty() ? "" : "; ") + f->second;
    }
  }
  for (int c : classes) {
    if (cell_.FindPart(c) == nullptr) {
      return Status::InvalidArgument("class " + std::to_string(c) + " is not a part of cell '" + cell_.name + "'");
    }
  }

  // 1-2. Deproject, to B, crop to the ROI: one pass.
  Clock::time_point t = Clock::now();
  RoiCloud roi;
  internal::CropToRoi(frame, cell_.bin.X_BW, box_, &roi);
  t = stage("roi", t);
  // The stages read roi.points_B; it moves into the result on every return.
  const std::vector<Eigen::Vector3f>& pts = roi.points_B;
  const auto finish = [&]() -> Result<PerceptionResult> {
    result.roi_points_B = std::move(roi.points_B);
    return std::move(result);
  };
  result.roi_point_count = static_cast<int64_t>(pts.size());
  result.segment_of_point.assign(pts.size(), -1);
  if (roi.valid_points == 0) {
    result.reason = "frame has no valid points";
    return finish();
  }
  if (pts.empty()) {
    result.reason = "ROI is empty: none of the frame's " + std::to_string(roi.valid_points) +
                    " valid points is inside the bin ROI";
    return finish();
  }

  const Eigen::Vector3f z_W_in_B = cell_.bin.X_BW.linear().col(2).cast<float>();
  const float floor_d = static_cast<float>(-cell_.bin.X_BW.translation().dot(cell_.bin.X_BW.linear().col(2)));
  const Eigen::Vector4d floor_plane_B(z_W_in_B.x(), z_W_in_B.y(), z_W_in_B.z(), floor_d);
  // The largest fit residual a hypothesis may leave (max_fit_rms_sigmas),
  // from the depth noise at its surface centroid.
  // sigma_z(z) is the config's model, times measured / modelled noise at the
  // median depth when the frame is noisier than modelled.
  const bool limit_fit = options_.max_fit_rms_sigmas > 0.0;
  const NoiseModel* noise = limit_fit ? FrameNoise(cell_.camera, frame) : nullptr;
  if (limit_fit && frame.organized()) {
    std::tie(result.depth_noise_sigma, result.depth_noise_at) = MeasureDepthNoise(frame.depth);
  }
  const auto model_sigma = [&](double z) {
    return noise == nullptr ? 0.0 : noise->axial_sigma_base + noise->axial_sigma_quadratic * z * z;
  };
  const double at_median = model_sigma(result.depth_noise_at);
  const double noise_scale = at_median > 0.0 ? std::max(1.0, result.depth_noise_sigma / at_median) : 1.0;
  const Pose X_CB = frame.X_BC.inverse();
  const auto fit_rms_limit = [&](const ClassModel& m, const Pose& X_BO) {
    const double z = (X_CB * (X_BO * m.centroid_O().cast<double>())).z();
    const double sigma = at_median > 0.0 ? noise_scale * model_sigma(z) : result.depth_noise_sigma;
    if (!(sigma > 0.0)) return std::numeric_limits<double>::infinity();  // no noise figure: no limit
    return std::max(options_.min_fit_rms_limit, options_.max_fit_rms_sigmas * sigma);
  };
  const Eigen::Vector3f viewpoint_B = frame.X_BC.translation().cast<float>();
  const float max_jump = static_cast<float>(options_.segment_max_jump);

  // 3. Regions, normals, segments.
  std::vector<int32_t> region_of_point;  // connected regions (depth continuity only)
  std::vector<Eigen::Vector3f> seg_points, seg_normals;  // grid samples, grouped by segment
  std::vector<int32_t> seg_roi_index;                     // ROI index of each grid sample
  std::vector<std::pair<int32_t, int32_t>> seg_range;     // [begin, end) per segment
  std::vector<std::vector<int32_t>> region_views;         // see PerceptionOptions::match_regions
  if (roi.organized()) {
    // Grid stride from the pixel footprint on the bin floor.
    const double z_floor = std::abs((frame.X_BC.inverse() * cell_.bin.X_BW.translation()).z());
    const double footprint = z_floor / frame.intrinsics.fx;
    const int stride =
        std::clamp(static_cast<int>(std::lround(options_.grid_spacing / std::max(footprint, 1e-6))), 1, 8);
    const SampleGrid grid = internal::MakeSampleGrid(roi, stride);
    const double spacing = footprint * stride;
    const float grid_jump = std::max(max_jump, static_cast<float>(2.5 * spacing));

    // The normals (bands of rows in parallel), then two tasks (the stage
    // "regions" covers all three): the connected regions (depth continuity
    // only), and the floor band and the segments' region growing, which
    // needs the normals but not the connected regions. Measured (`binpick
    // eval --scenes 10 --seed 1`): the stages regions + segment 15.3-15.4 ->
    // 14.0-14.4 ms median with the two tasks against the growing after both
    // (interleaved runs); the regions stage 8.3-8.7 -> 6.9-7.0 ms with the
    // normals first on both threads, against the normals serial at the head
    // of the second task, whose flood fill then ran alone for 4 of its 7 ms
    // (machine of 2026-12-03, evening).
    std::vector<int32_t> region_of_cell;
    const int radius = std::clamp(static_cast<int>(std::lround(kNormalBaseline / std::max(spacing, 1e-6))), 1, 6);
    std::vector<Eigen::Vector3f> normals;
    std::vector<int32_t> segment_of_cell;
    int n_regions = 0;
    internal::GridNormals(roi, grid, radius, grid_jump, viewpoint_B, &normals);
    const auto segments = [&] {
      // Floor band: near the floor and facing up.
      std::vector<uint8_t> excluded(grid.point_of_cell.size(), 0);
      for (size_t c = 0; c < grid.point_of_cell.size(); ++c) {
        const int32_t i = grid.point_of_cell[c];
        if (i < 0) continue;
        const Eigen::Vector3f& p = roi.points_B[static_cast<size_t>(i)];
        const float height = z_W_in_B.dot(p) + floor_d;
        if (height < kFloorBand && normals[c].allFinite() && std::abs(normals[c].dot(z_W_in_B)) > kFloorMinNormalZ) {
          excluded[c] = 1;
        }
      }
      const float angle = static_cast<float>(options_.segment_normal_angle_deg * kPi / 180.0);
      n_regions = internal::GrowRegions(roi, grid, normals, grid_jump, angle, excluded, &segment_of_cell,
                                        static_cast<float>(options_.segment_convex_tolerance));
    };
    int n_cc = 0;  // connected regions
    tbb::parallel_invoke([&] { n_cc = internal::GrowRegions(roi, grid, {}, grid_jump, 0.f, {}, &region_of_cell); },
                         segments);
    t = stage("regions", t);

    // The bookkeeping below passes over all grid cells as few times as it
    // can (each pass over the 640x480 grid costs about half a millisecond):
    // per-region facts come from per-segment ones. Every segment lies in one
    // connected region (its cells join under the region's condition and
    // more), and segment ids grow with their first cell in row-major order
    // (each region grown from its first cell: the joining condition is
    // symmetric).
    // The passes over all cells run in n_chunks contiguous ranges of cells,
    // one task each, and merge their per-range counts in range order, so
    // that every result is the serial pass's (samples in cell order).
    const size_t n_cells = segment_of_cell.size();
    const size_t n_chunks = std::clamp<size_t>(n_cells / 16384, 1,
                                               static_cast<size_t>(tbb::this_task_arena::max_concurrency()));
    const auto for_chunks = [&](auto&& body) {
      tbb::parallel_for(tbb::blocked_range<size_t>(0, n_chunks, 1),
                        [&](const tbb::blocked_range<size_t>& r) {
                          for (size_t k = r.begin(); k < r.end(); ++k) {
                            body(k, n_cells * k / n_chunks, n_cells * (k + 1) / n_chunks);
                          }
                        },
                        tbb::simple_partitioner());
    };
    std::vector<std::vector<int32_t>> chunk_size(n_chunks), chunk_region(n_chunks);
    for_chunks([&](size_t k, size_t begin, size_t end) {
      chunk_size[k].assign(static_cast<size_t>(n_regions), 0);
      chunk_region[k].assign(static_cast<size_t>(n_regions), -1);
      int32_t* const sz = chunk_size[k].data();
      int32_t* const rg = chunk_region[k].data();
      for (size_t c = begin; c < end; ++c) {
        const int32_t sgm = segment_of_cell[c];
        if (sgm < 0) continue;
        ++sz[sgm];
        rg[sgm] = region_of_cell[c];
      }
    });
    std::vector<int32_t> size = std::move(chunk_size[0]);
    std::vector<int32_t> region_of_segment = std::move(chunk_region[0]);
    for (size_t k = 1; k < n_chunks; ++k) {
      for (size_t sgm = 0; sgm < size.size(); ++sgm) {
        size[sgm] += chunk_size[k][sgm];
        if (region_of_segment[sgm] < 0) region_of_segment[sgm] = chunk_region[k][sgm];
      }
    }
    if (options_.match_fragmented_regions) {
      // A connected region the normal condition cut into pieces all below
      // min_segment_points, but big enough as a whole, becomes one segment
      // (its first piece's label). Measured: an L-bracket lying on its side
      // and tilted, alone in the bin, shows 544 points in 5 mm edge strips
      // and side faces, none of them 150.
      std::vector<int32_t> total(static_cast<size_t>(n_cc), 0), largest(static_cast<size_t>(n_cc), 0),
          label(static_cast<size_t>(n_cc), -1);
      for (int32_t sgm = 0; sgm < n_regions; ++sgm) {
        const int32_t r = region_of_segment[static_cast<size_t>(sgm)];
        if (r < 0) continue;
        total[static_cast<size_t>(r)] += size[static_cast<size_t>(sgm)];
        largest[static_cast<size_t>(r)] = std::max(largest[static_cast<size_t>(r)], size[static_cast<size_t>(sgm)]);
        if (label[static_cast<size_t>(r)] < 0) label[static_cast<size_t>(r)] = sgm;
      }
      std::vector<int32_t> relabel(static_cast<size_t>(n_regions), -1);
      bool any = false;
      for (int32_t sgm = 0; sgm < n_regions; ++sgm) {
        const int32_t r = region_of_segment[static_cast<size_t>(sgm)];
        if (r < 0 || largest[static_cast<size_t>(r)] >= options_.min_segment_points ||
            total[static_cast<size_t>(r)] < options_.min_segment_points || label[static_cast<size_t>(r)] == sgm) {
          continue;
        }
        relabel[static_cast<size_t>(sgm)] = label[static_cast<size_t>(r)];
        size[static_cast<size_t>(label[static_cast<size_t>(r)])] += size[static_cast<size_t>(sgm)];
        size[static_cast<size_t>(sgm)] = 0;
        any = true;
      }
      if (any) {
        for (int32_t& sgm : segment_of_cell) {
          if (sgm >= 0 && relabel[static_cast<size_t>(sgm)] >= 0) sgm = relabel[static_cast<size_t>(sgm)];
        }
      }
    }
    // Keep segments with enough samples, renumbered by size (largest first).
    std::vector<int32_t> order(static_cast<size_t>(n_regions));
    std::iota(order.begin(), order.end(), 0);
    std::stable_sort(order.begin(), order.end(), [&](int32_t a, int32_t b) { return size[a] > size[b]; });
    std::vector<int32_t> renumber(static_cast<size_t>(n_regions), -1);
    int kept = 0;
    for (int32_t s : order) {
      if (size[static_cast<size_t>(s)] < options_.min_segment_points) break;
      renumber[static_cast<size_t>(s)] = kept++;
    }
    // Pieces below min_segment_points are no segment of their own; region
    // views (match_regions) still see them. One pass renumbers the cells,
    // flags those pieces' cells, counts the kept segments' samples and, per
    // connected region, its kept and fragment samples and whether it holds
    // more than one segment (match_regions); a second groups the grid
    // samples by segment (the kept segments' sizes are their sample counts).
    std::vector<uint8_t> fragment_cell(options_.match_regions ? n_cells : 0, 0);
    std::vector<std::vector<int32_t>> chunk_count(n_chunks);
    std::vector<internal::RegionSegmentCounts> chunk_rc(n_chunks);
    for_chunks([&](size_t k, size_t begin, size_t end) {
      std::vector<int32_t>& count = chunk_count[k];
      count.assign(static_cast<size_t>(kept), 0);
      internal::RegionSegmentCounts& rc = chunk_rc[k];
      if (options_.match_regions) rc = internal::RegionSegmentCounts(static_cast<size_t>(n_cc));
      for (size_t c = begin; c < end; ++c) {
        int32_t& sgm = segment_of_cell[c];
        if (sgm >= 0) {
          sgm = renumber[static_cast<size_t>(sgm)];
          if (sgm >= 0) ++count[static_cast<size_t>(sgm)];
          else if (options_.match_regions) fragment_cell[c] = 1;
        }
        if (!options_.match_regions) continue;
        const int32_t r = region_of_cell[c];
        if (r >= 0) rc.Add(r, sgm, fragment_cell[c] != 0);
      }
    });
    internal::RegionSegmentCounts& region_counts = chunk_rc[0];
    for (size_t k = 1; k < n_chunks && options_.match_regions; ++k) region_counts.Merge(chunk_rc[k]);
    std::vector<int32_t>& kept_samples = region_counts.kept_samples;
    std::vector<int32_t>& fragment_samples = region_counts.fragment_samples;
    std::vector<uint8_t>& multi = region_counts.multi;
    std::vector<int32_t> start(static_cast<size_t>(kept) + 1, 0);
    for (int32_t s = 0; s < n_regions; ++s) {
      if (renumber[static_cast<size_t>(s)] >= 0) start[static_cast<size_t>(renumber[static_cast<size_t>(s)]) + 1] = size[static_cast<size_t>(s)];
    }
    std::partial_sum(start.begin(), start.end(), start.begin());
    seg_points.resize(static_cast<size_t>(start.back()));
    seg_normals.resize(seg_points.size());
    seg_roi_index.resize(seg_points.size());
    std::vector<int32_t> cell_of_sample(seg_points.size());
    // Each range writes its samples of a segment after the earlier ranges'.
    std::vector<std::vector<int32_t>> chunk_fill(n_chunks);
    chunk_fill[0].assign(start.begin(), start.end() - 1);
    for (size_t k = 1; k < n_chunks; ++k) {
      chunk_fill[k] = chunk_fill[k - 1];
      for (size_t sgm = 0; sgm < static_cast<size_t>(kept); ++sgm) chunk_fill[k][sgm] += chunk_count[k - 1][sgm];
    }
    for_chunks([&](size_t k, size_t begin, size_t end) {
      int32_t* const fill = chunk_fill[k].data();
      for (size_t c = begin; c < end; ++c) {
        const int32_t sgm = segment_of_cell[c];
        if (sgm < 0) continue;
        const auto j = static_cast<size_t>(fill[sgm]++);
        const int32_t i = grid.point_of_cell[c];
        seg_points[j] = roi.points_B[static_cast<size_t>(i)];
        seg_normals[j] = normals[c];
        seg_roi_index[j] = i;
        cell_of_sample[j] = static_cast<int32_t>(c);
      }
    });
    for (int s = 0; s < kept; ++s) seg_range.emplace_back(start[static_cast<size_t>(s)], start[static_cast<size_t>(s) + 1]);
    if (options_.match_regions) {
      // Connected regions that hold two or more segments, or one segment and
      // pieces too small to be segments (kFragmentShare of its samples or
      // more), as extra views of all their non-floor samples. The pieces
      // follow the segments' samples in seg_points, in no seg_range.
      bool any_fragments = false;
      for (int32_t r = 0; r < n_cc; ++r) {
        const auto i = static_cast<size_t>(r);
        if (kept_samples[i] > 0 && fragment_samples[i] >= kFragmentShare * kept_samples[i]) multi[i] = 1;
        any_fragments |= multi[i] && fragment_samples[i] > 0;
      }
      for (size_t c = 0; any_fragments && c < segment_of_cell.size(); ++c) {
        const int32_t r = region_of_cell[c];
        if (!fragment_cell[c] || r < 0 || !multi[static_cast<size_t>(r)]) continue;
        const int32_t i = grid.point_of_cell[c];
        seg_points.push_back(roi.points_B[static_cast<size_t>(i)]);
        seg_normals.push_back(normals[c]);
        seg_roi_index.push_back(i);
        cell_of_sample.push_back(static_cast<int32_t>(c));
      }
      // Each region view lists its samples in order, the views in the order
      // of their first samples: the kept segments' samples a segment at a
      // time (a segment lies in one connected region), then the pieces'
      // samples one by one.
      std::vector<int32_t> view_of_region(static_cast<size_t>(n_cc), -1);
      const auto view_of = [&](int32_t r) -> std::vector<int32_t>* {
        if (r < 0 || !multi[static_cast<size_t>(r)]) return nullptr;
        int32_t& v = view_of_region[static_cast<size_t>(r)];
        if (v < 0) {
          v = static_cast<int32_t>(region_views.size());
          region_views.emplace_back();
        }
        return &region_views[static_cast<size_t>(v)];
      };
      std::vector<int32_t> region_of_kept(static_cast<size_t>(kept), -1);
      for (int32_t sgm = 0; sgm < n_regions; ++sgm) {
        const int32_t j = renumber[static_cast<size_t>(sgm)];
        if (j >= 0) region_of_kept[static_cast<size_t>(j)] = region_of_segment[static_cast<size_t>(sgm)];
      }
      for (int32_t j = 0; j < kept; ++j) {
        std::vector<int32_t>* out = view_of(region_of_kept[static_cast<size_t>(j)]);
        if (out == nullptr) continue;
        const size_t at = out->size();
        out->resize(at + static_cast<size_t>(start[static_cast<size_t>(j) + 1] - start[static_cast<size_t>(j)]));
        std::iota(out->begin() + static_cast<std::ptrdiff_t>(at), out->end(), start[static_cast<size_t>(j)]);
      }
      for (auto k = static_cast<size_t>(start.back()); k < seg_points.size(); ++k) {
        std::vector<int32_t>* out = view_of(region_of_cell[static_cast<size_t>(cell_of_sample[k])]);
        if (out != nullptr) out->push_back(static_cast<int32_t>(k));
      }
    }
    // One pass gives every ROI point its segment and its connected region.
    internal::SpreadLabels(roi, grid, segment_of_cell, region_of_cell, grid_jump, &result.segment_of_point,
                           &region_of_point);
    t = stage("segment", t);
  } else {
    // Unorganized clouds: voxel connected components; the estimator estimates normals.
    const int n = internal::VoxelRegions(pts, kUnorganizedVoxel, &region_of_point);
    t = stage("regions", t);
    std::vector<int32_t> size(static_cast<size_t>(n), 0);
    for (int32_t r : region_of_point) ++size[static_cast<size_t>(r)];
    std::vector<int32_t> renumber(static_cast<size_t>(n), -1);
    int kept = 0;
    for (int r = 0; r < n; ++r) {
      if (size[static_cast<size_t>(r)] >= options_.min_segment_points) renumber[static_cast<size_t>(r)] = kept++;
    }
    std::vector<std::vector<int32_t>> members(static_cast<size_t>(kept));
    for (size_t i = 0; i < pts.size(); ++i) {
      const int32_t s = renumber[static_cast<size_t>(region_of_point[i])];
      result.segment_of_point[i] = s;
      if (s >= 0) members[static_cast<size_t>(s)].push_back(static_cast<int32_t>(i));
    }
    for (const auto& m : members) {
      const auto begin = static_cast<int32_t>(seg_points.size());
      for (int32_t i : m) {
        seg_points.push_back(pts[static_cast<size_t>(i)]);
        seg_roi_index.push_back(i);
      }
      seg_range.emplace_back(begin, static_cast<int32_t>(seg_points.size()));
    }
    t = stage("segment", t);
  }

  // Largest connected region (empty-box rule).
  {
    std::vector<int64_t> count;
    for (int32_t r : region_of_point) {
      if (r < 0) continue;
      if (static_cast<size_t>(r) >= count.size()) count.resize(static_cast<size_t>(r) + 1, 0);
      ++count[static_cast<size_t>(r)];
    }
    result.largest_region_points = count.empty() ? 0 : *std::max_element(count.begin(), count.end());
  }

  if (seg_range.empty()) {
    result.reason = "no segment of at least " + std::to_string(options_.min_segment_points) +
                    " points in the ROI (" + std::to_string(result.roi_point_count) + " ROI points, largest region " +
                    std::to_string(result.largest_region_points) + ")";
    return finish();
  }
  if (models.empty()) {
    result.reason = model_problems.empty() ? "no part class to look for" : "no pose model: " + model_problems;
    return finish();
  }

  // 4. Pose per (segment, class), in parallel on the caller's arena. Each
  // view is the segment's samples, then (with context_relative_radius > 0)
  // the other segments' samples near its centroid: a part that self-occlusion
  // cut into pieces is seen whole from each piece.
  double max_diameter = 0.0;
  for (const ClassModel* m : models) max_diameter = std::max(max_diameter, m->diameter());
  const float context_radius = static_cast<float>(options_.context_relative_radius * max_diameter);
  std::vector<std::vector<int32_t>> view_of_segment(seg_range.size());
  tbb::parallel_for(size_t{0}, seg_range.size(), [&](size_t s) {
    const auto [b, e] = seg_range[s];
    std::vector<int32_t>& view = view_of_segment[s];
    for (int32_t k = b; k < e; ++k) view.push_back(k);
    if (!(context_radius > 0.f)) return;
    Eigen::Vector3f centroid = Eigen::Vector3f::Zero();
    for (int32_t k = b; k < e; ++k) centroid += seg_points[static_cast<size_t>(k)];
    centroid /= static_cast<float>(e - b);
    const float r2 = context_radius * context_radius;
    for (int32_t k = 0; k < static_cast<int32_t>(seg_points.size()); ++k) {
      if (k >= b && k < e) continue;
      if ((seg_points[static_cast<size_t>(k)] - centroid).squaredNorm() < r2) view.push_back(k);
    }
  });
  // Runs every class model on every view (index lists into seg_points).
  const bool have_normals = !seg_normals.empty();
  std::string first_reason;
  int rejected_low_score = 0;
  const auto gather = [&](const std::vector<int32_t>& index, std::vector<Eigen::Vector3f>* points,
                          std::vector<Eigen::Vector3f>* normals) {
    points->reserve(index.size());
    for (int32_t k : index) points->push_back(seg_points[static_cast<size_t>(k)]);
    if (have_normals) {
      normals->reserve(index.size());
      for (int32_t k : index) normals->push_back(seg_normals[static_cast<size_t>(k)]);
    }
  };
  // views[first_region_view..] are region views (see match_regions).
  // best_out (optional): per view, the best score over the classes tried (-1
  // for none). second_look: with second_look_search (the classes that fit
  // in the same order and with the same early exit as in the waves).
  // tried (optional): per view and class model index, the coarse poses
  // refined and what the estimate derived from the view; out from a wave,
  // in (PoseSearch::skip_coarse, PoseSearch::prepared) to the second look.
  struct Tried {
    std::vector<Pose> poses;
    std::shared_ptr<const PreparedView> prepared;
    double best_score = -1.0;  // of its hypotheses within the fit residual limit; -1: none
  };
  using TriedPoses = std::vector<Tried>;  // per class model index
  std::atomic<int> coarse_skipped{0}, coarse_refined{0};
  const auto estimate = [&](const std::vector<std::vector<int32_t>>& views, size_t first_region_view,
                            std::vector<double>* best_out = nullptr, bool second_look = false,
                            std::vector<TriedPoses>* tried = nullptr) {
    // Per view: the classes that can fit it (SegmentFitsClass), ordered by
    // how well the view's principal extents match each model's.
    const size_t n_models = models.size();
    std::vector<std::vector<int>> order(views.size());
    // Classes too small for the view: it is not one instance of them, but a
    // merged segment of several may hold one; tried last, only when no class
    // that fits found anything.
    std::vector<std::vector<int>> too_small(views.size());
    const bool skip_tried = second_look && tried != nullptr;
    tbb::parallel_for(size_t{0}, views.size(), [&](size_t v) {
      std::vector<Eigen::Vector3f> points;
      for (int32_t k : views[v]) points.push_back(seg_points[static_cast<size_t>(k)]);
      const Eigen::Vector3f e = internal::PrincipalExtents(points);
      bool any_fits = false;
      for (size_t m = 0; m < n_models && !any_fits; ++m) any_fits = internal::SegmentFitsClass(e, models[m]->diameter());
      // A region view exists to join the pieces of one part: one that no
      // class fits only repeats its segments' work.
      if (options_.class_prefilter && !any_fits && v >= first_region_view) return;
      // The share of the view's normals on its two main planes, against
      // each class's range (PerceptionOptions::rank_planar_share_weight).
      float planar_share = -1.f;  // -1: not used
      if (have_normals && options_.rank_planar_share_weight > 0.0) {
        std::vector<Eigen::Vector3f> normals;
        const size_t stride = std::max<size_t>(1, views[v].size() / kPlanarShareNormals);
        for (size_t i = 0; i < views[v].size(); i += stride) {
          normals.push_back(seg_normals[static_cast<size_t>(views[v][i])]);
        }
        planar_share = internal::PlanarShare(normals);
      }
      // (-best score of the view's wave, cost, class): the second look tries
      // first the class that came closest in the wave.
      std::vector<std::tuple<double, double, int>> ranked;
      for (size_t m = 0; m < n_models; ++m) {
        if (options_.class_prefilter && !internal::SegmentFitsClass(e, models[m]->diameter())) {
          too_small[v].push_back(static_cast<int>(m));
          continue;
        }
        const double wave_best = skip_tried && options_.second_look_rank_by_wave && m < (*tried)[v].size()
                                     ? (*tried)[v][m].best_score
                                     : -1.0;
        ranked.emplace_back(-wave_best,
                            ExtentMismatch(e, models[m]->extents()) +
                                options_.rank_planar_share_weight * PlanarShareMismatch(planar_share, *models[m]),
                            static_cast<int>(m));
      }
      if (options_.early_exit_score > 0.0 && !thorough) std::stable_sort(ranked.begin(), ranked.end());
      for (const auto& [wave, cost, m] : ranked) order[v].push_back(m);
    });
    // Per view (in parallel, no barrier between views): the first class;
    // the other fitting ones (in parallel) unless it gave a confident
    // detection; then, when none found anything, the classes too small.
    struct Job {
      int model = 0;
      bool too_small = false;
      internal::ClassEstimate estimate;
    };
    std::vector<std::vector<Job>> per_view(views.size());
    const bool early_exit = options_.early_exit_score > 0.0 && !thorough;
    if (best_out != nullptr) best_out->assign(views.size(), -1.0);
    if (tried != nullptr && !skip_tried) tried->assign(views.size(), TriedPoses(n_models));
    tbb::parallel_for(size_t{0}, views.size(), [&](size_t v) {
      std::vector<Eigen::Vector3f> points, normals;
      gather(views[v], &points, &normals);
      internal::SegmentView view;
      view.points_B = points;
      view.normals_B = normals;
      view.frame = &frame;
      view.floor_plane_B = floor_plane_B;
      if (thorough) view.search = options_.thorough_search;
      if (second_look) view.search = options_.second_look_search;
      view.keep_prepared = tried != nullptr && !skip_tried;
      std::vector<Job>& done = per_view[v];
      // Runs classes ms[from, to) in parallel.
      const auto run = [&](const std::vector<int>& ms, size_t from, size_t to, bool too_small) {
        to = std::min(to, ms.size());
        if (from >= to) return;
        const size_t base = done.size();
        done.resize(base + to - from);
        tbb::parallel_for(from, to, [&](size_t r) {
          Job& job = done[base + r - from];
          job.model = ms[r];
          job.too_small = too_small;
          const ClassModel& model = *models[static_cast<size_t>(ms[r])];
          const size_t mi = static_cast<size_t>(ms[r]);
          const Tried* skip = skip_tried && mi < (*tried)[v].size() ? &(*tried)[v][mi] : nullptr;
          if (skip != nullptr && (!skip->poses.empty() || skip->prepared) && view.search) {
            internal::SegmentView with_skip = view;
            with_skip.search->skip_coarse = skip->poses;
            with_skip.search->prepared = skip->prepared;
            job.estimate = model.Estimate(with_skip);
          } else {
            job.estimate = model.Estimate(view);
          }
          coarse_skipped += job.estimate.coarse_skipped;
          coarse_refined += static_cast<int>(job.estimate.coarse_poses.size());
          if (tried != nullptr && !skip_tried) {
            (*tried)[v][mi] = Tried{std::move(job.estimate.coarse_poses), std::move(job.estimate.prepared)};
          }
          if (limit_fit && !job.estimate.hypotheses.empty()) {
            std::erase_if(job.estimate.hypotheses, [&](const internal::ClassHypothesis& h) {
              return h.rms_residual > fit_rms_limit(model, h.X_BO);
            });
            if (job.estimate.hypotheses.empty()) {
              job.estimate.reason = "every hypothesis fits worse than the depth noise allows (max_fit_rms_sigmas)";
            }
          }
          if (tried != nullptr && !skip_tried) {
            for (const auto& h : job.estimate.hypotheses) {
              (*tried)[v][mi].best_score = std::max((*tried)[v][mi].best_score, h.score);
            }
          }
        });
      };
      if (early_exit && !order[v].empty()) {
        run(order[v], 0, 1, false);
        const auto& hs = done.front().estimate.hypotheses;
        const bool confident =
            !hs.empty() && hs.front().score >= options_.early_exit_score &&
            static_cast<double>(hs.front().support.size()) >= options_.early_exit_support * static_cast<double>(views[v].size());
        if (!confident) run(order[v], 1, order[v].size(), false);
      } else {
        run(order[v], 0, order[v].size(), false);
      }
      bool found = false;
      double best = -1.0;
      for (const Job& job : done) {
        for (const auto& h : job.estimate.hypotheses) {
          found |= h.score >= options_.min_detection_score;
          best = std::max(best, h.score);
        }
      }
      if (best_out != nullptr) (*best_out)[v] = best;
      if (!found) run(too_small[v], 0, too_small[v].size(), true);
    });
    result.views += static_cast<int>(views.size());
    for (const std::vector<Job>& jobs : per_view) result.estimator_calls += static_cast<int>(jobs.size());
    std::vector<std::pair<size_t, int>> jobs_done;
    std::vector<uint8_t> too_small_job;
    std::vector<internal::ClassEstimate> estimates;
    for (size_t v = 0; v < views.size(); ++v) {
      for (Job& job : per_view[v]) {
        jobs_done.emplace_back(v, job.model);
        too_small_job.push_back(job.too_small ? 1 : 0);
        estimates.push_back(std::move(job.estimate));
      }
    }
    const size_t n_jobs = jobs_done.size();
    std::vector<Candidate> candidates;
    for (size_t job = 0; job < n_jobs; ++job) {
      const size_t s = jobs_done[job].first;
      const ClassModel& model = *models[static_cast<size_t>(jobs_done[job].second)];
      if (estimates[job].hypotheses.empty() && first_reason.empty()) first_reason = estimates[job].reason;
      for (internal::ClassHypothesis& h : estimates[job].hypotheses) {
        if (!h.X_BO.matrix().allFinite() || !std::isfinite(h.score)) continue;
        // A class too small for the view must explain its part of it well
        // (measured: otherwise bushings are fitted onto bracket plates).
        const double min_score = too_small_job[job]
                                     ? std::max(options_.min_detection_score, options_.too_small_class_min_score)
                                     : options_.min_detection_score;
        if (h.score < min_score) {
          ++rejected_low_score;
          continue;
        }
        Candidate c;
        c.class_id = model.class_id();
        c.diameter = model.diameter();
        c.centre_B = h.X_BO * model.centroid_O().cast<double>();
        c.segment = static_cast<int>(s);
        c.support_roi.reserve(h.support.size());
        const std::vector<int32_t>& index = views[s];
        for (int k : h.support) {
          if (k >= 0 && static_cast<size_t>(k) < index.size()) {
            c.support_roi.push_back(seg_roi_index[static_cast<size_t>(index[static_cast<size_t>(k)])]);
          }
        }
        c.h = std::move(h);
        candidates.push_back(std::move(c));
      }
    }
    return candidates;
  };

  // 5. One detection per physical part, greedy by score across segments,
  // classes and waves: a candidate conflicts with an accepted detection whose
  // centre is near its own, that holds a share of its support when most of
  // that is already claimed, or that it interpenetrates. It is dropped when a
  // detection it conflicts with scores as well, else it replaces them all
  // (they came from an earlier wave or the second look came after them).
  std::vector<uint16_t> claims(pts.size(), 0);  // accepted detections supported by each point
  std::vector<uint8_t> mark(pts.size(), 0);     // scratch: a candidate's support
  // Per result.detections entry.
  struct Accepted {
    double diameter = 0.0;
    Eigen::Vector3d centre_B;                // of the part's surface
    std::vector<Eigen::Vector3f> surface_B;  // the model's surface samples at the detection
    bool dropped = false;                    // replaced by a later, better candidate
  };
  std::vector<Accepted> accepted;
  const auto model_of = [&](int class_id) -> const ClassModel* {
    for (const ClassModel* m : models) {
      if (m->class_id() == class_id) return m;
    }
    return nullptr;
  };
  const auto surface_B = [](const ClassModel& m, const Pose& X_BO) {
    const std::span<const Eigen::Vector3f> s = m.surface_points_O();
    std::vector<Eigen::Vector3f> out(s.size());
    const Eigen::Matrix3f R = X_BO.linear().cast<float>();
    const Eigen::Vector3f t = X_BO.translation().cast<float>();
    for (size_t i = 0; i < s.size(); ++i) out[i] = R * s[i] + t;
    return out;
  };
  // The accepted detections c interpenetrates (kInsideDepth, kMaxInsideFraction).
  const auto Interpenetrated = [&](const Candidate& c) {
    std::vector<size_t> hit;
    const ClassModel* cm = model_of(c.class_id);
    if (cm == nullptr) return hit;
    std::vector<size_t> near;  // the live detections whose part may touch c's
    for (size_t k = 0; k < result.detections.size(); ++k) {
      const Accepted& a = accepted[k];
      if (a.dropped || (a.centre_B - c.centre_B).norm() > 0.5 * (c.diameter + a.diameter)) continue;
      if (model_of(result.detections[k].class_id) != nullptr) near.push_back(k);
    }
    if (near.empty()) return hit;
    const std::vector<Eigen::Vector3f> mine = surface_B(*cm, c.h.X_BO);
    const double limit_mine = kMaxInsideFraction * static_cast<double>(mine.size());
    // The acceptance runs alone between the waves: the neighbours' tests
    // (a few, each a few hundred closest-point lookups) on both threads.
    std::vector<uint8_t> inside(near.size(), 0);
    tbb::parallel_for(size_t{0}, near.size(), [&](size_t j) {
      const size_t k = near[j];
      const Accepted& a = accepted[k];
      const ClassModel* km = model_of(result.detections[k].class_id);
      const double limit_theirs = kMaxInsideFraction * static_cast<double>(a.surface_B.size());
      inside[j] = static_cast<double>(km->CountInside(result.detections[k].X_BO, mine, kInsideDepth)) > limit_mine ||
                  static_cast<double>(cm->CountInside(c.h.X_BO, a.surface_B, kInsideDepth)) > limit_theirs;
    });
    for (size_t j = 0; j < near.size(); ++j) {
      if (inside[j]) hit.push_back(near[j]);
    }
    return hit;
  };
  const auto accept = [&](std::vector<Candidate> candidates) {
    std::stable_sort(candidates.begin(), candidates.end(),
                     [](const Candidate& a, const Candidate& b) { return a.h.score > b.h.score; });
    for (Candidate& c : candidates) {
      // The live accepted detections c conflicts with: centres within the
      // NMS distance, a share of c's support when more than
      // kMaxSharedSupport of it is claimed, or interpenetration.
      std::vector<size_t> conflicts;
      const auto conflict = [&conflicts](size_t k) {
        if (std::find(conflicts.begin(), conflicts.end(), k) == conflicts.end()) conflicts.push_back(k);
      };
      for (size_t k = 0; k < accepted.size(); ++k) {
        const Accepted& a = accepted[k];
        if (!a.dropped && (a.centre_B - c.centre_B).norm() < kNmsRelativeDistance * std::max(c.diameter, a.diameter)) {
          conflicts.push_back(k);
        }
      }
      if (!c.support_roi.empty()) {
        size_t shared = 0;
        for (int32_t i : c.support_roi) shared += claims[static_cast<size_t>(i)] > 0 ? 1 : 0;
        if (static_cast<double>(shared) > kMaxSharedSupport * static_cast<double>(c.support_roi.size())) {
          for (int32_t i : c.support_roi) mark[static_cast<size_t>(i)] = 1;
          bool attributed = false;
          for (size_t k = 0; k < result.detections.size(); ++k) {
            if (accepted[k].dropped) continue;
            size_t overlap = 0;
            for (int32_t i : result.detections[k].support) overlap += mark[static_cast<size_t>(i)];
            if (static_cast<double>(overlap) >= kSharedOwner * static_cast<double>(c.support_roi.size())) {
              attributed = true;
              conflict(k);
            }
          }
          for (int32_t i : c.support_roi) mark[static_cast<size_t>(i)] = 0;
          if (!attributed) continue;
        }
      }
      for (size_t k : Interpenetrated(c)) conflict(k);
      // Greedy by score across the waves: c loses to any conflicting
      // detection that scores as well, else replaces them all.
      if (std::any_of(conflicts.begin(), conflicts.end(),
                      [&](size_t k) { return result.detections[k].score >= c.h.score; })) {
        continue;
      }
      for (size_t k : conflicts) {
        accepted[k].dropped = true;
        for (int32_t i : result.detections[k].support) --claims[static_cast<size_t>(i)];
      }
      for (int32_t i : c.support_roi) ++claims[static_cast<size_t>(i)];
      const ClassModel* m = model_of(c.class_id);
      accepted.push_back({c.diameter, c.centre_B, m ? surface_B(*m, c.h.X_BO) : std::vector<Eigen::Vector3f>{}});
      Detection d;
      d.class_id = c.class_id;
      d.X_BO = c.h.X_BO;
      d.score = c.h.score;
      d.visible_fraction = c.h.visible_fraction;
      d.rms_residual = c.h.rms_residual;
      d.support = std::move(c.support_roi);
      result.detections.push_back(std::move(d));
    }
  };

  // Fraction of a view's points within kExplainedDistance of the surface of
  // an accepted detection (of those scoring at least min_score).
  const auto ExplainedFraction = [&](const std::vector<int32_t>& view, double min_score = 0.0) {
    if (view.empty()) return 0.0;
    std::vector<Eigen::Vector3f> points;
    points.reserve(view.size());
    Eigen::Vector3d centre = Eigen::Vector3d::Zero();
    for (int32_t k : view) {
      points.push_back(seg_points[static_cast<size_t>(k)]);
      centre += points.back().cast<double>();
    }
    centre /= static_cast<double>(points.size());
    double radius = 0.0;
    for (const Eigen::Vector3f& p : points) radius = std::max(radius, (p.cast<double>() - centre).norm());
    std::vector<uint8_t> on(points.size(), 0);
    for (size_t d = 0; d < result.detections.size(); ++d) {
      const Accepted& a = accepted[d];
      if (a.dropped || result.detections[d].score < min_score) continue;
      // The part lies within a diameter of its surface centroid.
      if ((a.centre_B - centre).norm() > radius + a.diameter) continue;
      if (const ClassModel* m = model_of(result.detections[d].class_id)) {
        m->MarkOnSurface(result.detections[d].X_BO, points, kExplainedDistance, &on);
      }
    }
    return static_cast<double>(std::count(on.begin(), on.end(), uint8_t{1})) / static_cast<double>(on.size());
  };

  // Views in waves by size (PerceptionOptions::view_waves): after each wave
  // its detections are accepted, and a view of a later wave whose points lie
  // mostly on an accepted detection's surface (a fragment of a part already
  // found) is not matched.
  const size_t n_segment_views = view_of_segment.size();
  for (auto& view : region_views) view_of_segment.push_back(std::move(view));
  std::vector<size_t> by_size(view_of_segment.size());
  std::iota(by_size.begin(), by_size.end(), size_t{0});
  std::stable_sort(by_size.begin(), by_size.end(), [&](size_t a, size_t b) {
    return view_of_segment[a].size() > view_of_segment[b].size();
  });
  std::vector<int> wave_min = options_.view_waves;
  std::vector<std::vector<int32_t>> weak_segment_views, weak_region_views;  // for the second look
  std::vector<TriedPoses> weak_segment_tried, weak_region_tried;          // their coarse poses
  wave_min.push_back(0);
  double pose_ms = 0.0, verify_ms = 0.0;
  size_t next_view = 0;
  for (size_t w = 0; w < wave_min.size() && next_view < by_size.size(); ++w) {
    const Clock::time_point t0 = Clock::now();
    std::vector<size_t> members;
    while (next_view < by_size.size() &&
           static_cast<int>(view_of_segment[by_size[next_view]].size()) >= wave_min[w]) {
      members.push_back(by_size[next_view++]);
    }
    if (!result.detections.empty() && !members.empty()) {
      std::vector<uint8_t> explained(members.size(), 0);
      tbb::parallel_for(size_t{0}, members.size(), [&](size_t i) {
        explained[i] = ExplainedFraction(view_of_segment[members[i]]) >= kExplainedFraction ? 1 : 0;
      });
      size_t kept = 0;
      for (size_t i = 0; i < members.size(); ++i) {
        if (!explained[i]) members[kept++] = members[i];
      }
      result.views += static_cast<int>(members.size() - kept);
      result.views_explained += static_cast<int>(members.size() - kept);
      members.resize(kept);
    }
    // Segment views first, then region views (estimate's convention).
    std::stable_partition(members.begin(), members.end(), [&](size_t v) { return v < n_segment_views; });
    std::vector<std::vector<int32_t>> wave_views;
    size_t first_region = 0;
    for (size_t v : members) {
      first_region += v < n_segment_views ? 1 : 0;
      wave_views.push_back(std::move(view_of_segment[v]));
    }
    std::vector<double> best;
    std::vector<TriedPoses> wave_tried;  // kept only for a second look that skips them
    const bool keep_tried = !thorough && options_.second_look_below > 0.0 && options_.second_look_skip_tried;
    std::vector<Candidate> candidates =
        estimate(wave_views, first_region, &best, false, keep_tried ? &wave_tried : nullptr);
    const Clock::time_point t1 = Clock::now();
    accept(std::move(candidates));
    pose_ms += Ms(t0, t1);
    verify_ms += Ms(t1, Clock::now());
    if (!thorough && options_.second_look_below > 0.0) {
      for (size_t i = 0; i < wave_views.size(); ++i) {
        if (best[i] < options_.second_look_below) {
          const bool segment = i < first_region;
          (segment ? weak_segment_views : weak_region_views).push_back(std::move(wave_views[i]));
          (segment ? weak_segment_tried : weak_region_tried)
              .push_back(i < wave_tried.size() ? std::move(wave_tried[i]) : TriedPoses{});
        }
      }
    }
  }
  result.timings.push_back({"pose", pose_ms});
  result.timings.push_back({"verify", verify_ms});
  t = Clock::now();

  // Second look (PerceptionOptions::second_look_below): the weak views of
  // second_look_min_points or more that no confident detection (scoring at
  // least second_look_below) explains (kExplainedFraction, as the waves judge
  // a view) are matched again with the wider search; what they find competes
  // with the detections so far by score (accept).
  {
    const size_t n_weak_segments = weak_segment_views.size();
    for (auto& view : weak_region_views) weak_segment_views.push_back(std::move(view));
    for (auto& tried : weak_region_tried) weak_segment_tried.push_back(std::move(tried));
    std::vector<uint8_t> explained(weak_segment_views.size(), 0);
    tbb::parallel_for(size_t{0}, weak_segment_views.size(), [&](size_t i) {
      explained[i] =
          ExplainedFraction(weak_segment_views[i], options_.second_look_below) >= kExplainedFraction ? 1 : 0;
    });
    std::vector<std::vector<int32_t>> again;
    std::vector<TriedPoses> again_tried;
    size_t first_region = 0;
    for (size_t i = 0; i < weak_segment_views.size(); ++i) {
      if (explained[i]) continue;
      if (static_cast<int>(weak_segment_views[i].size()) < options_.second_look_min_points) continue;
      first_region += i < n_weak_segments ? 1 : 0;
      again.push_back(std::move(weak_segment_views[i]));
      again_tried.push_back(std::move(weak_segment_tried[i]));
    }
    result.second_looks = static_cast<int>(again.size());
    if (!again.empty()) {
      accept(estimate(again, first_region, nullptr, /*second_look=*/true,
                      options_.second_look_skip_tried ? &again_tried : nullptr));
    }
    result.coarse_skipped = coarse_skipped.load();
  }
  t = stage("second_look", t);

  // Residual pass: segments that a detection explained only in part (touching
  // parts merged into one segment) are matched again on their unclaimed points.
  std::vector<std::vector<int32_t>> residual;
  for (const auto& [b, e] : seg_range) {
    std::vector<int32_t> left;
    for (int32_t k = b; k < e; ++k) {
      if (claims[static_cast<size_t>(seg_roi_index[static_cast<size_t>(k)])] == 0) left.push_back(k);
    }
    const auto n = static_cast<int32_t>(left.size());
    if (n < e - b && n >= options_.min_segment_points && n >= kResidualFraction * (e - b)) {
      residual.push_back(std::move(left));
    }
  }
  if (!residual.empty()) accept(estimate(residual, residual.size()));
  stage("residual", t);
  result.coarse_refined = coarse_refined.load();
  {
    size_t kept = 0;
    for (size_t k = 0; k < result.detections.size(); ++k) {
      if (accepted[k].dropped) continue;
      if (kept != k) result.detections[kept] = std::move(result.detections[k]);
      ++kept;
    }
    result.detections.resize(kept);
  }
  if (result.detections.empty()) {
    result.reason = "no hypothesis passed verification in " + std::to_string(seg_range.size()) + " segments" +
                    (rejected_low_score > 0 ? " (" + std::to_string(rejected_low_score) + " below min_detection_score)"
                                            : std::string()) +
                    (first_reason.empty() ? "" : " (e.g. " + first_reason + ")");
  }
  return finish();
}

}  // namespace

Result<std::unique_ptr<Perception>> Perception::Build(const Cell& cell, const PerceptionOptions& options) {
  if (options.threads < 1) return Status::InvalidArgument("perception: threads must be >= 1");
  for (const auto& [name, s] : {std::pair<const char*, const PoseSearch&>{"thorough_search", options.thorough_search},
                                 {"second_look_search", options.second_look_search}}) {
    if (!s.IsValid()) {
      return Status::InvalidArgument(std::string("perception: ") + name +
                                     " counts must be >= 1, peaks_examined >= peaks_per_reference, stop_score in [0, 1]");
    }
  }
  if (!(options.segment_max_jump > 0.0)) return Status::InvalidArgument("perception: segment_max_jump must be > 0");
  if (!(options.grid_spacing > 0.0)) return Status::InvalidArgument("perception: grid_spacing must be > 0");
  if (!(options.rank_planar_share_weight >= 0.0) || !std::isfinite(options.rank_planar_share_weight)) {
    return Status::InvalidArgument("perception: rank_planar_share_weight must be finite and >= 0");
  }
  for (size_t i = 0; i < options.view_waves.size(); ++i) {
    if (options.view_waves[i] < 1 || (i > 0 && options.view_waves[i] >= options.view_waves[i - 1])) {
      return Status::InvalidArgument("perception: view_waves must be positive and strictly decreasing");
    }
  }
  std::vector<Result<std::unique_ptr<ClassModel>>> built;
  built.reserve(cell.parts.size());
  for (size_t i = 0; i < cell.parts.size(); ++i) built.emplace_back(Status::Internal("not built"));
  tbb::task_arena arena(options.threads);
  arena.execute([&] {
    tbb::parallel_for(size_t{0}, cell.parts.size(),
                      [&](size_t i) { built[i] = internal::BuildClassModel(cell.parts[i]); });
  });
  std::vector<std::unique_ptr<ClassModel>> models;
  std::map<int, std::string> failures;
  for (size_t i = 0; i < built.size(); ++i) {
    if (built[i].ok()) {
      models.push_back(std::move(built[i]).value());
    } else {
      failures[cell.parts[i].class_id] = built[i].status().message();
    }
  }
  return std::unique_ptr<Perception>(std::make_unique<PerceptionImpl>(cell, options, std::move(models), std::move(failures)));
}

}  // namespace bp
