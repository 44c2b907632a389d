#include "pipeline/internal/view_passes.h"

#include <algorithm>
#include <chrono>
#include <numeric>
#include <utility>

#include <tbb/parallel_for.h>

namespace bp::internal {

namespace {

using Clock = std::chrono::steady_clock;
double Ms(Clock::time_point t0, Clock::time_point t1) {
  return std::chrono::duration<double, std::milli>(t1 - t0).count();
}

// A view with at least this fraction of its points on an accepted
// detection's surface (Acceptance::ExplainedFraction) is a piece of a part
// already found.
constexpr double kExplainedFraction = 0.6;
// A segment is matched again on its unclaimed points when at least this
// fraction of it is left.
constexpr double kResidualFraction = 0.25;

// Per view: 1 when detections scoring at least min_score explain it.
std::vector<uint8_t> Explained(const std::vector<ViewIndices>& views, const std::vector<size_t>& which,
                               double min_score, const Segments& segments, const Acceptance& acceptance) {
  std::vector<uint8_t> explained(which.size(), 0);
  tbb::parallel_for(size_t{0}, which.size(), [&](size_t i) {
    explained[i] = acceptance.ExplainedFraction(segments, views[which[i]], min_score) >= kExplainedFraction ? 1 : 0;
  });
  return explained;
}

// Unexplained samples join across gaps of up to this many grid cells less
// one (within the grid's neighbour distance in space): grazing dropout and
// mixed pixels leave holes along a part's creases that split its samples
// into groups (1: the 8 neighbours).
constexpr int32_t kResidualReach = 3;
// A residual region with at least this fraction of one kept segment's
// samples, and samples of no other segment or piece, repeats that segment's
// match.
constexpr double kSameSegmentFraction = 0.9;

// Union-find root with path halving.
int32_t Root(std::vector<int32_t>& parent, int32_t a) {
  while (parent[static_cast<size_t>(a)] != a) {
    parent[static_cast<size_t>(a)] = parent[static_cast<size_t>(parent[static_cast<size_t>(a)])];
    a = parent[static_cast<size_t>(a)];
  }
  return a;
}

// Joins the sets of x and y (union-find; the smaller root is kept).
void Unite(std::vector<int32_t>& parent, int32_t x, int32_t y) {
  const int32_t a = Root(parent, x), b = Root(parent, y);
  if (a != b) parent[static_cast<size_t>(std::max(a, b))] = std::min(a, b);
}

// Calls visit(j) with the unexplained sample j of each grid cell up to
// kResidualReach cells below cell c, or right of it on its row. The cells
// above c and to its left reach c from their side, so one pass over all
// cells visits every pair of cells within reach once. sample_of_cell: -1
// for a cell with none.
template <typename Visit>
void ForEachLaterCellInReach(int32_t c, int32_t grid_width, const std::vector<int32_t>& sample_of_cell,
                             Visit&& visit) {
  const auto max_cell = static_cast<int32_t>(sample_of_cell.size()) - 1;
  const int32_t cu = c % grid_width, cv = c / grid_width;
  for (int32_t dv = 0; dv <= kResidualReach; ++dv) {
    for (int32_t du = dv == 0 ? 1 : -kResidualReach; du <= kResidualReach; ++du) {
      const int32_t u = cu + du, d = (cv + dv) * grid_width + u;
      if (u < 0 || u >= grid_width || d > max_cell) continue;
      const int32_t j = sample_of_cell[static_cast<size_t>(d)];
      if (j >= 0) visit(j);
    }
  }
}

// The kept segment holding sample k, -1 for a piece's sample.
int32_t SegmentOfSample(const Segments& segments, int32_t k) {
  const auto it = std::upper_bound(segments.range.begin(), segments.range.end(), k,
                                   [](int32_t v, const std::pair<int32_t, int32_t>& r) { return v < r.second; });
  return it != segments.range.end() && k >= it->first ? static_cast<int32_t>(it - segments.range.begin()) : -1;
}

// Whether the group repeats one kept segment's match (kSameSegmentFraction).
bool RepeatsASegment(const Segments& segments, const ViewIndices& group) {
  const int32_t s = SegmentOfSample(segments, group.front());
  if (s < 0 || SegmentOfSample(segments, group.back()) != s) return false;
  // Sample order: a group whose first and last samples lie in segment s
  // holds only s's samples.
  const auto [b, e] = segments.range[static_cast<size_t>(s)];
  return static_cast<double>(group.size()) >= kSameSegmentFraction * (e - b);
}

// The unions of residual groups whose cells lie within kResidualReach of
// each other whatever their depths (ResidualRegionViews, across_jumps): per
// union of two or more groups whose largest holds less than
// kSameSegmentFraction of it, its samples in sample order, when at least
// min_segment_points. sample_of_cell: the unexplained sample of each grid
// cell, -1 for none.
std::vector<ViewIndices> JoinedAcrossJumps(const Segments& segments, const std::vector<int32_t>& sample_of_cell,
                                           const std::vector<ViewIndices>& groups, int min_segment_points) {
  std::vector<ViewIndices> out;
  if (groups.size() < 2) return out;
  std::vector<int32_t> group_of_sample(segments.points.size(), -1);
  for (size_t g = 0; g < groups.size(); ++g) {
    for (int32_t k : groups[g]) group_of_sample[static_cast<size_t>(k)] = static_cast<int32_t>(g);
  }
  std::vector<int32_t> parent(groups.size());
  std::iota(parent.begin(), parent.end(), 0);
  for (const ViewIndices& group : groups) {
    for (int32_t k : group) {
      const int32_t gk = group_of_sample[static_cast<size_t>(k)];
      ForEachLaterCellInReach(segments.cell_of_sample[static_cast<size_t>(k)], segments.grid_width, sample_of_cell,
                              [&](int32_t j) { Unite(parent, gk, group_of_sample[static_cast<size_t>(j)]); });
    }
  }
  // Per union (by its root): its groups, in group order.
  std::vector<std::vector<int32_t>> members(groups.size());
  for (size_t g = 0; g < groups.size(); ++g) {
    members[static_cast<size_t>(Root(parent, static_cast<int32_t>(g)))].push_back(static_cast<int32_t>(g));
  }
  for (const std::vector<int32_t>& m : members) {
    if (m.size() < 2) continue;
    size_t total = 0, largest = 0;
    for (int32_t g : m) {
      total += groups[static_cast<size_t>(g)].size();
      largest = std::max(largest, groups[static_cast<size_t>(g)].size());
    }
    if (static_cast<int>(total) < min_segment_points ||
        static_cast<double>(largest) >= kSameSegmentFraction * static_cast<double>(total)) {
      continue;
    }
    ViewIndices view;
    view.reserve(total);
    for (int32_t g : m) view.insert(view.end(), groups[static_cast<size_t>(g)].begin(), groups[static_cast<size_t>(g)].end());
    std::sort(view.begin(), view.end());
    out.push_back(std::move(view));
  }
  return out;
}

}  // namespace

WaveResult MatchInWaves(ViewSet views, const PerceptionOptions& options, bool thorough, const Segments& segments,
                        ViewMatcher& matcher, Acceptance& acceptance) {
  WaveResult out;
  std::vector<size_t> by_size(views.views.size());
  std::iota(by_size.begin(), by_size.end(), size_t{0});
  std::stable_sort(by_size.begin(), by_size.end(),
                   [&](size_t a, size_t b) { return views.views[a].size() > views.views[b].size(); });
  std::vector<int> wave_min = options.view_waves;
  wave_min.push_back(0);
  const bool second_look = !thorough && options.second_look_below > 0.0;
  const bool keep_traces = second_look && options.second_look_skip_tried;
  WeakViews weak_regions;  // joined after the weak segment views
  size_t next_view = 0;
  for (size_t w = 0; w < wave_min.size() && next_view < by_size.size(); ++w) {
    const Clock::time_point t0 = Clock::now();
    std::vector<size_t> members;
    while (next_view < by_size.size() && static_cast<int>(views.views[by_size[next_view]].size()) >= wave_min[w]) {
      members.push_back(by_size[next_view++]);
    }
    if (!acceptance.never_accepted() && !members.empty()) {
      const std::vector<uint8_t> explained = Explained(views.views, members, 0.0, segments, acceptance);
      size_t kept = 0;
      for (size_t i = 0; i < members.size(); ++i) {
        if (!explained[i]) members[kept++] = members[i];
      }
      out.views_explained += static_cast<int>(members.size() - kept);
      members.resize(kept);
    }
    // Segment views first, then region views.
    std::stable_partition(members.begin(), members.end(), [&](size_t v) { return v < views.first_region; });
    ViewSet wave;
    for (size_t v : members) {
      wave.first_region += v < views.first_region ? 1 : 0;
      wave.views.push_back(std::move(views.views[v]));
    }
    MatchOutcome matched = matcher.Match(wave, MatchPass::kWave, nullptr, keep_traces);
    const Clock::time_point t1 = Clock::now();
    acceptance.Accept(std::move(matched.candidates));
    out.match_ms += Ms(t0, t1);
    out.accept_ms += Ms(t1, Clock::now());
    if (!second_look) continue;
    for (size_t i = 0; i < wave.views.size(); ++i) {
      if (matched.best[i] >= options.second_look_below) continue;
      WeakViews& weak = i < wave.first_region ? out.weak : weak_regions;
      weak.views.views.push_back(std::move(wave.views[i]));
      weak.traces.push_back(i < matched.traces.size() ? std::move(matched.traces[i]) : ViewTrace{});
    }
  }
  out.weak.views.first_region = out.weak.views.views.size();
  for (auto& view : weak_regions.views.views) out.weak.views.views.push_back(std::move(view));
  for (auto& trace : weak_regions.traces) out.weak.traces.push_back(std::move(trace));
  return out;
}

int SecondLook(WeakViews weak, const PerceptionOptions& options, const Segments& segments, ViewMatcher& matcher,
               Acceptance& acceptance) {
  std::vector<size_t> all(weak.views.views.size());
  std::iota(all.begin(), all.end(), size_t{0});
  const std::vector<uint8_t> explained =
      Explained(weak.views.views, all, options.second_look_below, segments, acceptance);
  ViewSet again;
  std::vector<ViewTrace> again_traces;
  for (size_t i = 0; i < weak.views.views.size(); ++i) {
    if (explained[i]) continue;
    if (static_cast<int>(weak.views.views[i].size()) < options.second_look_min_points) continue;
    again.first_region += i < weak.views.first_region ? 1 : 0;
    again.views.push_back(std::move(weak.views.views[i]));
    again_traces.push_back(std::move(weak.traces[i]));
  }
  if (!again.views.empty()) {
    MatchOutcome matched = matcher.Match(again, MatchPass::kSecondLook,
                                         options.second_look_skip_tried ? &again_traces : nullptr);
    acceptance.Accept(std::move(matched.candidates));
  }
  return static_cast<int>(again.views.size());
}

std::vector<ViewIndices> ResidualViews(const Segments& segments, const Acceptance& acceptance,
                                       int min_segment_points) {
  std::vector<ViewIndices> residual;
  for (const auto& [b, e] : segments.range) {
    ViewIndices left;
    for (int32_t k = b; k < e; ++k) {
      if (acceptance.claims(segments.roi_index[static_cast<size_t>(k)]) == 0) left.push_back(k);
    }
    const auto n = static_cast<int32_t>(left.size());
    if (n < e - b && n >= min_segment_points && n >= kResidualFraction * (e - b)) residual.push_back(std::move(left));
  }
  return residual;
}

ViewSet NothingFound(ViewSet& views, const MatchOutcome& matched, double min_score) {
  ViewSet out;
  out.own_normals = true;
  for (size_t v = 0; v < views.views.size() && v < matched.best.size(); ++v) {
    if (matched.best[v] >= min_score) continue;
    out.first_region += v < views.first_region ? 1 : 0;
    out.views.push_back(std::move(views.views[v]));
    out.bases.push_back(v < matched.bases.size() ? matched.bases[v] : nullptr);
  }
  return out;
}

std::vector<ViewIndices> ResidualRegionViews(const Segments& segments, const Acceptance& acceptance,
                                             int min_segment_points, bool across_jumps) {
  std::vector<ViewIndices> out;
  const size_t n = segments.points.size();
  if (segments.grid_width <= 0 || segments.cell_of_sample.size() != n) return out;
  const std::vector<uint8_t> left = acceptance.UnexplainedSamples(segments);
  // The unexplained samples by grid cell.
  int32_t max_cell = -1;
  for (int32_t c : segments.cell_of_sample) max_cell = std::max(max_cell, c);
  std::vector<int32_t> sample_of_cell(static_cast<size_t>(max_cell) + 1, -1);
  std::vector<int32_t> parent(n);
  std::iota(parent.begin(), parent.end(), 0);
  for (size_t k = 0; k < n; ++k) {
    if (left[k]) sample_of_cell[static_cast<size_t>(segments.cell_of_sample[k])] = static_cast<int32_t>(k);
  }
  const float jump2 = segments.grid_jump * segments.grid_jump;
  // Each unexplained sample joins those of the cells within kResidualReach
  // that lie within the grid's neighbour distance of it.
  for (size_t k = 0; k < n; ++k) {
    if (!left[k]) continue;
    ForEachLaterCellInReach(segments.cell_of_sample[k], segments.grid_width, sample_of_cell, [&](int32_t j) {
      if ((segments.points[k] - segments.points[static_cast<size_t>(j)]).squaredNorm() <= jump2) {
        Unite(parent, static_cast<int32_t>(k), j);
      }
    });
  }
  // Groups in order of their first sample, each in sample order.
  std::vector<int32_t> group_of_root(n, -1);
  std::vector<ViewIndices> groups;
  for (size_t k = 0; k < n; ++k) {
    if (!left[k]) continue;
    int32_t& g = group_of_root[static_cast<size_t>(Root(parent, static_cast<int32_t>(k)))];
    if (g < 0) {
      g = static_cast<int32_t>(groups.size());
      groups.emplace_back();
    }
    groups[static_cast<size_t>(g)].push_back(static_cast<int32_t>(k));
  }
  std::vector<ViewIndices> joined;
  if (across_jumps) joined = JoinedAcrossJumps(segments, sample_of_cell, groups, min_segment_points);
  for (ViewIndices& g : groups) {
    if (static_cast<int>(g.size()) >= min_segment_points && !RepeatsASegment(segments, g)) out.push_back(std::move(g));
  }
  for (ViewIndices& j : joined) out.push_back(std::move(j));
  return out;
}

}  // namespace bp::internal
