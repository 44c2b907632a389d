#include "pipeline/internal/segmentation.h"

#include <algorithm>
#include <cmath>
#include <numeric>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_invoke.h>
#include <tbb/partitioner.h>
#include <tbb/task_arena.h>

namespace bp::internal {

namespace {

constexpr double kPi = 3.14159265358979323846;
// Normals use neighbours this far away (in metres on the bin floor).
constexpr double kNormalBaseline = 0.0025;
// A connected region with one segment is matched whole too when its pieces
// below min_segment_points hold at least this fraction of the segment's
// samples (SegmentationOptions::match_regions).
constexpr double kFragmentShare = 0.25;

// The grid's cells in contiguous ranges, one task each (at most one range
// per thread of the arena, at least 16384 cells per range). Per-range counts
// merged in range order give the serial pass's result.
class CellRanges {
 public:
  explicit CellRanges(size_t cells)
      : cells_(cells),
        count_(std::clamp<size_t>(cells / 16384, 1, static_cast<size_t>(tbb::this_task_arena::max_concurrency()))) {}
  size_t count() const { return count_; }
  // body(k, begin, end) for every range k, in parallel.
  template <typename Body>
  void ForEach(Body&& body) const {
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, count_, 1),
        [&](const tbb::blocked_range<size_t>& r) {
          for (size_t k = r.begin(); k < r.end(); ++k) body(k, cells_ * k / count_, cells_ * (k + 1) / count_);
        },
        tbb::simple_partitioner());
  }

 private:
  size_t cells_;
  size_t count_;
};

// Per grown segment: its sample count and its connected region.
struct SegmentSizes {
  std::vector<int32_t> size;
  std::vector<int32_t> region;
};

SegmentSizes CountSegments(const GridLabels& labels, const CellRanges& ranges) {
  const auto n = static_cast<size_t>(labels.segments);
  std::vector<std::vector<int32_t>> range_size(ranges.count()), range_region(ranges.count());
  ranges.ForEach([&](size_t k, size_t begin, size_t end) {
    range_size[k].assign(n, 0);
    range_region[k].assign(n, -1);
    int32_t* const sz = range_size[k].data();
    int32_t* const rg = range_region[k].data();
    for (size_t c = begin; c < end; ++c) {
      const int32_t sgm = labels.segment_of_cell[c];
      if (sgm < 0) continue;
      ++sz[sgm];
      rg[sgm] = labels.region_of_cell[c];
    }
  });
  SegmentSizes out{std::move(range_size[0]), std::move(range_region[0])};
  for (size_t k = 1; k < ranges.count(); ++k) {
    for (size_t sgm = 0; sgm < n; ++sgm) {
      out.size[sgm] += range_size[k][sgm];
      if (out.region[sgm] < 0) out.region[sgm] = range_region[k][sgm];
    }
  }
  return out;
}

// A connected region the normal condition cut into pieces all below
// min_segment_points, but big enough as a whole, becomes one segment (its
// first piece's label): a thin part on its side shows only edge strips.
void MergeFragmentedRegions(int min_points, GridLabels& labels, SegmentSizes& sizes) {
  const auto n_cc = static_cast<size_t>(labels.regions);
  std::vector<int32_t> total(n_cc, 0), largest(n_cc, 0), label(n_cc, -1);
  std::vector<int32_t>& size = sizes.size;
  for (int32_t sgm = 0; sgm < labels.segments; ++sgm) {
    const int32_t r = sizes.region[static_cast<size_t>(sgm)];
    if (r < 0) continue;
    const auto ri = static_cast<size_t>(r);
    total[ri] += size[static_cast<size_t>(sgm)];
    largest[ri] = std::max(largest[ri], size[static_cast<size_t>(sgm)]);
    if (label[ri] < 0) label[ri] = sgm;
  }
  std::vector<int32_t> relabel(static_cast<size_t>(labels.segments), -1);
  bool any = false;
  for (int32_t sgm = 0; sgm < labels.segments; ++sgm) {
    const int32_t r = sizes.region[static_cast<size_t>(sgm)];
    if (r < 0) continue;
    const auto ri = static_cast<size_t>(r);
    if (largest[ri] >= min_points || total[ri] < min_points || label[ri] == sgm) continue;
    relabel[static_cast<size_t>(sgm)] = label[ri];
    size[static_cast<size_t>(label[ri])] += size[static_cast<size_t>(sgm)];
    size[static_cast<size_t>(sgm)] = 0;
    any = true;
  }
  if (!any) return;
  for (int32_t& sgm : labels.segment_of_cell) {
    if (sgm >= 0 && relabel[static_cast<size_t>(sgm)] >= 0) sgm = relabel[static_cast<size_t>(sgm)];
  }
}

// The segments of at least min_points samples, renumbered by size (largest
// first; -1 for the others).
std::vector<int32_t> RenumberBySize(const std::vector<int32_t>& size, int min_points, int* kept) {
  std::vector<int32_t> order(size.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(), [&](int32_t a, int32_t b) { return size[a] > size[b]; });
  std::vector<int32_t> renumber(size.size(), -1);
  *kept = 0;
  for (int32_t s : order) {
    if (size[static_cast<size_t>(s)] < min_points) break;
    renumber[static_cast<size_t>(s)] = (*kept)++;
  }
  return renumber;
}

// What the renumbering pass gives: per range the kept segments' sample
// counts; per cell whether it is a piece below min_segment_points; per
// connected region its RegionSegmentCounts (match_regions).
struct KeptCells {
  std::vector<std::vector<int32_t>> range_count;
  std::vector<uint8_t> fragment_cell;
  RegionSegmentCounts region_counts;
};

// One pass renumbers the cells, flags the pieces' cells, counts the kept
// segments' samples and, per connected region, its kept and fragment
// samples and whether it holds more than one segment.
KeptCells RenumberCells(const std::vector<int32_t>& renumber, int kept, bool match_regions, const CellRanges& ranges,
                        GridLabels& labels) {
  const size_t n_cells = labels.segment_of_cell.size();
  KeptCells out;
  out.fragment_cell.assign(match_regions ? n_cells : 0, 0);
  out.range_count.resize(ranges.count());
  std::vector<RegionSegmentCounts> range_rc(ranges.count());
  ranges.ForEach([&](size_t k, size_t begin, size_t end) {
    std::vector<int32_t>& count = out.range_count[k];
    count.assign(static_cast<size_t>(kept), 0);
    RegionSegmentCounts& rc = range_rc[k];
    if (match_regions) rc = RegionSegmentCounts(static_cast<size_t>(labels.regions));
    for (size_t c = begin; c < end; ++c) {
      int32_t& sgm = labels.segment_of_cell[c];
      if (sgm >= 0) {
        sgm = renumber[static_cast<size_t>(sgm)];
        if (sgm >= 0) {
          ++count[static_cast<size_t>(sgm)];
        } else if (match_regions) {
          out.fragment_cell[c] = 1;
        }
      }
      if (!match_regions) continue;
      const int32_t r = labels.region_of_cell[c];
      if (r >= 0) rc.Add(r, sgm, out.fragment_cell[c] != 0);
    }
  });
  out.region_counts = std::move(range_rc[0]);
  for (size_t k = 1; k < ranges.count() && match_regions; ++k) out.region_counts.Merge(range_rc[k]);
  return out;
}

// Groups the kept segments' samples by segment (cell order within each);
// start[s] is segment s's first sample, start[kept] their count.
// cell_of_sample gets each sample's cell.
void GroupSamples(const RoiCloud& roi, const GridLabels& labels, const std::vector<int32_t>& start,
                  const KeptCells& cells, const CellRanges& ranges, Segments& out,
                  std::vector<int32_t>& cell_of_sample) {
  const size_t kept = start.size() - 1;
  out.points.resize(static_cast<size_t>(start.back()));
  out.normals.resize(out.points.size());
  out.roi_index.resize(out.points.size());
  cell_of_sample.resize(out.points.size());
  // Each range writes its samples of a segment after the earlier ranges'.
  std::vector<std::vector<int32_t>> range_fill(ranges.count());
  range_fill[0].assign(start.begin(), start.end() - 1);
  for (size_t k = 1; k < ranges.count(); ++k) {
    range_fill[k] = range_fill[k - 1];
    for (size_t sgm = 0; sgm < kept; ++sgm) range_fill[k][sgm] += cells.range_count[k - 1][sgm];
  }
  ranges.ForEach([&](size_t k, size_t begin, size_t end) {
    int32_t* const fill = range_fill[k].data();
    for (size_t c = begin; c < end; ++c) {
      const int32_t sgm = labels.segment_of_cell[c];
      if (sgm < 0) continue;
      const auto j = static_cast<size_t>(fill[sgm]++);
      const int32_t i = labels.grid.point_of_cell[c];
      out.points[j] = roi.points_B[static_cast<size_t>(i)];
      out.normals[j] = labels.normals[c];
      out.roi_index[j] = i;
      cell_of_sample[j] = static_cast<int32_t>(c);
    }
  });
  for (size_t s = 0; s < kept; ++s) out.range.emplace_back(start[s], start[s + 1]);
}

// Connected regions that hold two or more segments, or one segment and
// pieces too small to be segments (kFragmentShare of its samples or more),
// become views of all their non-floor samples. The pieces' samples are
// appended to out.points (in no range). Each region view lists its samples
// in order, the views in the order of their first samples: the kept
// segments' samples a segment at a time (a segment lies in one connected
// region), then the pieces' samples one by one.
void BuildRegionViews(const RoiCloud& roi, const GridLabels& labels, const std::vector<int32_t>& renumber,
                      const std::vector<int32_t>& region_of_segment, const std::vector<int32_t>& start,
                      KeptCells& cells, std::vector<int32_t>& cell_of_sample, Segments& out) {
  const auto kept = static_cast<int32_t>(start.size() - 1);
  std::vector<int32_t>& kept_samples = cells.region_counts.kept_samples;
  std::vector<int32_t>& fragment_samples = cells.region_counts.fragment_samples;
  std::vector<uint8_t>& multi = cells.region_counts.multi;
  bool any_fragments = false;
  for (int32_t r = 0; r < labels.regions; ++r) {
    const auto i = static_cast<size_t>(r);
    if (kept_samples[i] > 0 && fragment_samples[i] >= kFragmentShare * kept_samples[i]) multi[i] = 1;
    any_fragments |= multi[i] && fragment_samples[i] > 0;
  }
  for (size_t c = 0; any_fragments && c < labels.segment_of_cell.size(); ++c) {
    const int32_t r = labels.region_of_cell[c];
    if (!cells.fragment_cell[c] || r < 0 || !multi[static_cast<size_t>(r)]) continue;
    const int32_t i = labels.grid.point_of_cell[c];
    out.points.push_back(roi.points_B[static_cast<size_t>(i)]);
    out.normals.push_back(labels.normals[c]);
    out.roi_index.push_back(i);
    cell_of_sample.push_back(static_cast<int32_t>(c));
  }
  std::vector<int32_t> view_of_region(static_cast<size_t>(labels.regions), -1);
  const auto view_of = [&](int32_t r) -> ViewIndices* {
    if (r < 0 || !multi[static_cast<size_t>(r)]) return nullptr;
    int32_t& v = view_of_region[static_cast<size_t>(r)];
    if (v < 0) {
      v = static_cast<int32_t>(out.region_views.size());
      out.region_views.emplace_back();
    }
    return &out.region_views[static_cast<size_t>(v)];
  };
  std::vector<int32_t> region_of_kept(static_cast<size_t>(kept), -1);
  for (size_t sgm = 0; sgm < renumber.size(); ++sgm) {
    const int32_t j = renumber[sgm];
    if (j >= 0) region_of_kept[static_cast<size_t>(j)] = region_of_segment[sgm];
  }
  for (int32_t j = 0; j < kept; ++j) {
    ViewIndices* view = view_of(region_of_kept[static_cast<size_t>(j)]);
    if (view == nullptr) continue;
    const size_t at = view->size();
    const auto s = static_cast<size_t>(j);
    view->resize(at + static_cast<size_t>(start[s + 1] - start[s]));
    std::iota(view->begin() + static_cast<std::ptrdiff_t>(at), view->end(), start[s]);
  }
  for (auto k = static_cast<size_t>(start.back()); k < out.points.size(); ++k) {
    ViewIndices* view = view_of(labels.region_of_cell[static_cast<size_t>(cell_of_sample[k])]);
    if (view != nullptr) view->push_back(static_cast<int32_t>(k));
  }
}

// Appends the samples of the pieces below min_segment_points that no region
// view holds (their connected region is not `multi`), in cell order: views
// never name them; the residual regions' pass (ResidualRegionViews) does.
void AppendOtherPieces(const RoiCloud& roi, const GridLabels& labels, const KeptCells& cells,
                       std::vector<int32_t>& cell_of_sample, Segments& out) {
  const std::vector<uint8_t>& multi = cells.region_counts.multi;
  for (size_t c = 0; c < labels.segment_of_cell.size(); ++c) {
    const int32_t r = labels.region_of_cell[c];
    if (!cells.fragment_cell[c] || (r >= 0 && multi[static_cast<size_t>(r)])) continue;
    const int32_t i = labels.grid.point_of_cell[c];
    out.points.push_back(roi.points_B[static_cast<size_t>(i)]);
    out.normals.push_back(labels.normals[c]);
    out.roi_index.push_back(i);
    cell_of_sample.push_back(static_cast<int32_t>(c));
  }
}

}  // namespace

GridLabels LabelGrid(const RoiCloud& roi, const Frame& frame, const Pose& X_BW, const SegmentationOptions& options) {
  GridLabels out;
  // Grid stride from the pixel footprint on the bin floor.
  const double z_floor = std::abs((frame.X_BC.inverse() * X_BW.translation()).z());
  const double footprint = z_floor / frame.intrinsics.fx;
  const int stride =
      std::clamp(static_cast<int>(std::lround(options.grid_spacing / std::max(footprint, 1e-6))), 1, 8);
  out.grid = MakeSampleGrid(roi, stride);
  const double spacing = footprint * stride;
  out.spacing = static_cast<float>(spacing);
  out.grid_jump = std::max(static_cast<float>(options.max_jump), static_cast<float>(2.5 * spacing));
  const int radius = std::clamp(static_cast<int>(std::lround(kNormalBaseline / std::max(spacing, 1e-6))), 1, 6);
  const Eigen::Vector3f viewpoint_B = frame.X_BC.translation().cast<float>();
  // The normals (bands of rows in parallel), then two tasks: the connected
  // regions (depth continuity only), and the floor band and the segments'
  // region growing, which needs the normals but not the regions.
  GridNormals(roi, out.grid, radius, out.grid_jump, viewpoint_B, &out.normals);
  const Eigen::Vector3f z_W_in_B = X_BW.linear().col(2).cast<float>();
  const float floor_d = static_cast<float>(-X_BW.translation().dot(X_BW.linear().col(2)));
  const auto grow_segments = [&] {
    std::vector<uint8_t> excluded(out.grid.point_of_cell.size(), 0);
    for (size_t c = 0; c < out.grid.point_of_cell.size(); ++c) {
      const int32_t i = out.grid.point_of_cell[c];
      if (i < 0) continue;
      const Eigen::Vector3f& p = roi.points_B[static_cast<size_t>(i)];
      const float height = z_W_in_B.dot(p) + floor_d;
      if (height < options.floor_band && out.normals[c].allFinite() &&
          std::abs(out.normals[c].dot(z_W_in_B)) > options.floor_min_normal_z) {
        excluded[c] = 1;
      }
    }
    const float angle = static_cast<float>(options.normal_angle_deg * kPi / 180.0);
    out.segments = GrowRegions(roi, out.grid, out.normals, out.grid_jump, angle, excluded, &out.segment_of_cell,
                               static_cast<float>(options.convex_tolerance));
  };
  tbb::parallel_invoke(
      [&] { out.regions = GrowRegions(roi, out.grid, {}, out.grid_jump, 0.f, {}, &out.region_of_cell); },
      grow_segments);
  return out;
}

Segments GroupGridSegments(const RoiCloud& roi, GridLabels labels, const SegmentationOptions& options) {
  // The passes over all cells are few (each pass over a 640x480 grid costs
  // about half a millisecond): per-region facts come from per-segment ones.
  // Every segment lies in one connected region, and segment ids grow with
  // their first cell in row-major order.
  const CellRanges ranges(labels.segment_of_cell.size());
  SegmentSizes sizes = CountSegments(labels, ranges);
  if (options.match_fragmented_regions) MergeFragmentedRegions(options.min_segment_points, labels, sizes);
  int kept = 0;
  const std::vector<int32_t> renumber = RenumberBySize(sizes.size, options.min_segment_points, &kept);
  KeptCells cells = RenumberCells(renumber, kept, options.match_regions, ranges, labels);
  std::vector<int32_t> start(static_cast<size_t>(kept) + 1, 0);
  for (size_t s = 0; s < renumber.size(); ++s) {
    if (renumber[s] >= 0) start[static_cast<size_t>(renumber[s]) + 1] = sizes.size[s];
  }
  std::partial_sum(start.begin(), start.end(), start.begin());
  Segments out;
  std::vector<int32_t> cell_of_sample;
  GroupSamples(roi, labels, start, cells, ranges, out, cell_of_sample);
  if (options.match_regions) {
    BuildRegionViews(roi, labels, renumber, sizes.region, start, cells, cell_of_sample, out);
    AppendOtherPieces(roi, labels, cells, cell_of_sample, out);
  }
  out.cell_of_sample = std::move(cell_of_sample);
  out.grid_width = labels.grid.width;
  out.grid_jump = labels.grid_jump;
  out.min_points = options.min_segment_points;
  // One pass gives every ROI point its segment and its connected region.
  SpreadLabels(roi, labels.grid, labels.segment_of_cell, labels.region_of_cell, labels.grid_jump,
               &out.segment_of_point, &out.region_of_point);
  return out;
}

std::pair<std::vector<int32_t>, int> LabelCloud(const RoiCloud& roi, float voxel) {
  std::vector<int32_t> region_of_point;
  const int n = VoxelRegions(roi.points_B, voxel, &region_of_point);
  return {std::move(region_of_point), n};
}

Segments GroupCloudSegments(const RoiCloud& roi, std::vector<int32_t> region_of_point, int regions,
                            int min_segment_points) {
  const std::vector<Eigen::Vector3f>& pts = roi.points_B;
  Segments out;
  std::vector<int32_t> size(static_cast<size_t>(regions), 0);
  for (int32_t r : region_of_point) ++size[static_cast<size_t>(r)];
  std::vector<int32_t> renumber(static_cast<size_t>(regions), -1);
  int kept = 0;
  for (int r = 0; r < regions; ++r) {
    if (size[static_cast<size_t>(r)] >= min_segment_points) renumber[static_cast<size_t>(r)] = kept++;
  }
  std::vector<std::vector<int32_t>> members(static_cast<size_t>(kept));
  out.segment_of_point.assign(pts.size(), -1);
  for (size_t i = 0; i < pts.size(); ++i) {
    const int32_t s = renumber[static_cast<size_t>(region_of_point[i])];
    out.segment_of_point[i] = s;
    if (s >= 0) members[static_cast<size_t>(s)].push_back(static_cast<int32_t>(i));
  }
  for (const auto& m : members) {
    const auto begin = static_cast<int32_t>(out.points.size());
    for (int32_t i : m) {
      out.points.push_back(pts[static_cast<size_t>(i)]);
      out.roi_index.push_back(i);
    }
    out.range.emplace_back(begin, static_cast<int32_t>(out.points.size()));
  }
  out.region_of_point = std::move(region_of_point);
  out.min_points = min_segment_points;
  return out;
}

int64_t LargestRegionPoints(const std::vector<int32_t>& region_of_point) {
  std::vector<int64_t> count;
  for (int32_t r : region_of_point) {
    if (r < 0) continue;
    if (static_cast<size_t>(r) >= count.size()) count.resize(static_cast<size_t>(r) + 1, 0);
    ++count[static_cast<size_t>(r)];
  }
  return count.empty() ? 0 : *std::max_element(count.begin(), count.end());
}

std::vector<ViewIndices> SegmentViews(const Segments& segments, float context_radius) {
  std::vector<ViewIndices> views(segments.range.size());
  tbb::parallel_for(size_t{0}, segments.range.size(), [&](size_t s) {
    const auto [b, e] = segments.range[s];
    ViewIndices& view = views[s];
    for (int32_t k = b; k < e; ++k) view.push_back(k);
    if (!(context_radius > 0.f)) return;
    Eigen::Vector3f centroid = Eigen::Vector3f::Zero();
    for (int32_t k = b; k < e; ++k) centroid += segments.points[static_cast<size_t>(k)];
    centroid /= static_cast<float>(e - b);
    const float r2 = context_radius * context_radius;
    for (int32_t k = 0; k < static_cast<int32_t>(segments.points.size()); ++k) {
      if (k >= b && k < e) continue;
      if ((segments.points[static_cast<size_t>(k)] - centroid).squaredNorm() < r2) view.push_back(k);
    }
  });
  return views;
}

}  // namespace bp::internal
