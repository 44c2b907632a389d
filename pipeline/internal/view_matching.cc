#include "pipeline/internal/view_matching.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <tuple>
#include <utility>

#include <tbb/parallel_for.h>

namespace bp::internal {

namespace {

// Class ranking by PlanarShare (PerceptionOptions::rank_planar_share_weight):
// a view's share counts against a class only this far outside the class's
// range (the range is of whole parts seen from 64 directions; a fragment is
// flatter or more curved than its part), from at most this many normals.
constexpr double kPlanarShareSlack = 0.1;
constexpr size_t kPlanarShareNormals = 128;

}  // namespace

double ExtentMismatch(const Eigen::Vector3f& view, const Eigen::Vector3f& model) {
  double cost = 0.0;
  for (int i = 0; i < 3; ++i) {
    const double m = std::max(1e-6, static_cast<double>(model[i]));
    cost += std::abs(static_cast<double>(view[i]) - m) / m;
  }
  return cost;
}

double PlanarShareMismatch(float share, const ClassModel& model) {
  if (share < 0.f) return 0.0;
  const auto [lo, hi] = model.planar_share_range();
  return std::max(0.0, lo - kPlanarShareSlack - share) + std::max(0.0, share - hi - kPlanarShareSlack);
}

BudgetGate::BudgetGate(const PerceptionBudget& budget) : budget_(budget) {}

double BudgetGate::Now() const { return budget_.now_ms ? budget_.now_ms() : SteadyClockMs(); }

std::optional<double> BudgetGate::Admit() const {
  const double now = Now();
  const int n = done_.load();
  const double mean_ms = n > 0 ? 1e-3 * static_cast<double>(done_us_.load()) / n : 0.0;
  if (now + mean_ms > budget_.deadline_ms) return std::nullopt;
  return now;
}

void BudgetGate::Finished(double started_ms) {
  done_us_ += static_cast<int64_t>(std::llround(1e3 * std::max(0.0, Now() - started_ms)));
  ++done_;
}

struct ViewMatcher::Job {
  int model = 0;
  bool too_small = false;
  bool skipped = false;  // not run: over the budget
  ClassEstimate estimate;
};

ViewMatcher::ViewMatcher(const PerceptionOptions& options, std::span<const ClassModel* const> models, bool thorough,
                         const Frame& frame, const std::optional<Eigen::Vector4d>& floor_plane_B, const Segments& segments,
                         const FitRmsLimit& fit_limit, const PerceptionBudget* budget)
    : options_(options), models_(models), thorough_(thorough), frame_(frame), floor_plane_B_(floor_plane_B),
      segments_(segments), fit_limit_(fit_limit) {
  if (budget != nullptr) budget_.emplace(*budget);
}

SegmentView ViewMatcher::ViewOf(const ViewIndices& index, bool own_normals, std::vector<Eigen::Vector3f>* points,
                                std::vector<Eigen::Vector3f>* normals) const {
  points->reserve(index.size());
  for (int32_t k : index) points->push_back(segments_.points[static_cast<size_t>(k)]);
  if (!segments_.normals.empty() && !own_normals) {
    normals->reserve(index.size());
    for (int32_t k : index) normals->push_back(segments_.normals[static_cast<size_t>(k)]);
  }
  SegmentView view;
  view.points_B = *points;
  view.normals_B = *normals;
  view.frame = &frame_;
  view.floor_plane_B = floor_plane_B_;
  return view;
}

void ViewMatcher::RankClasses(const ViewIndices& view, bool region_view, const ViewTrace* earlier,
                              std::vector<int>* order, std::vector<int>* too_small, double* best_cost) const {
  *best_cost = std::numeric_limits<double>::infinity();
  const size_t n_models = models_.size();
  std::vector<Eigen::Vector3f> points;
  for (int32_t k : view) points.push_back(segments_.points[static_cast<size_t>(k)]);
  const Eigen::Vector3f e = PrincipalExtents(points);
  bool any_fits = false;
  for (size_t m = 0; m < n_models && !any_fits; ++m) any_fits = SegmentFitsClass(e, models_[m]->diameter());
  // A region view exists to join the pieces of one part: one that no class
  // fits only repeats its segments' work.
  if (options_.class_prefilter && !any_fits && region_view) return;
  // The share of the view's normals on its two main planes, against each
  // class's range (PerceptionOptions::rank_planar_share_weight).
  float planar_share = -1.f;  // -1: not used
  if (!segments_.normals.empty() && options_.rank_planar_share_weight > 0.0) {
    std::vector<Eigen::Vector3f> normals;
    const size_t stride = std::max<size_t>(1, view.size() / kPlanarShareNormals);
    for (size_t i = 0; i < view.size(); i += stride) normals.push_back(segments_.normals[static_cast<size_t>(view[i])]);
    planar_share = PlanarShare(normals);
  }
  // (-best score of the view's wave, cost, class): the second look tries
  // first the class that came closest in the wave.
  std::vector<std::tuple<double, double, int>> ranked;
  for (size_t m = 0; m < n_models; ++m) {
    if (options_.class_prefilter && !SegmentFitsClass(e, models_[m]->diameter())) {
      too_small->push_back(static_cast<int>(m));
      continue;
    }
    const double wave_best =
        earlier != nullptr && options_.second_look_rank_by_wave && m < earlier->size() ? (*earlier)[m].best_score
                                                                                         : -1.0;
    ranked.emplace_back(-wave_best,
                        ExtentMismatch(e, models_[m]->extents()) +
                            options_.rank_planar_share_weight * PlanarShareMismatch(planar_share, *models_[m]),
                        static_cast<int>(m));
  }
  // Ranked where the order decides what runs: early exit (normal runs) and
  // a budget (it skips the estimates that would start last). A thorough run
  // without one runs every class, in model order.
  if ((options_.early_exit_score > 0.0 && !thorough_) || budget_) std::stable_sort(ranked.begin(), ranked.end());
  for (const auto& [wave, cost, m] : ranked) {
    order->push_back(m);
    *best_cost = std::min(*best_cost, cost);
  }
}

void ViewMatcher::RunClasses(const SegmentView& view, const std::vector<int>& ms, size_t from, size_t to,
                             bool too_small, int rank0, const ViewTrace* earlier, ViewTrace* trace,
                             std::vector<Job>* jobs) {
  to = std::min(to, ms.size());
  if (from >= to) return;
  const size_t base = jobs->size();
  jobs->resize(base + to - from);
  // Each task takes the next class of ms: the classes start in ranking order
  // whatever the partitioner does (a budget admits the first ones).
  std::atomic<size_t> next{from};
  tbb::parallel_for(from, to, [&](size_t) {
    const size_t r = next++;
    Job& job = (*jobs)[base + r - from];
    job.model = ms[r];
    job.too_small = too_small;
    const ClassModel& model = *models_[static_cast<size_t>(ms[r])];
    const auto mi = static_cast<size_t>(ms[r]);
    const WaveTrace* skip = earlier != nullptr && mi < earlier->size() ? &(*earlier)[mi] : nullptr;
    std::optional<double> started;
    if (budget_) {
      if (rank0 != kUncounted && !budget_->Counted(rank0 + static_cast<int>(r))) {
        job.skipped = true;
        ++counts_.estimates_skipped;
        return;
      }
      started = budget_->Admit();
      if (!started) {
        job.skipped = true;
        ++counts_.estimates_skipped;
        return;
      }
    }
    if (skip != nullptr && (!skip->coarse_poses.empty() || skip->prepared) && view.search) {
      SegmentView with_skip = view;
      with_skip.reuse.skip_coarse = skip->coarse_poses;
      with_skip.reuse.prepared = skip->prepared;
      job.estimate = model.Estimate(with_skip);
    } else {
      job.estimate = model.Estimate(view);
    }
    if (started) budget_->Finished(*started);
    counts_.coarse_skipped += job.estimate.trace.coarse_skipped;
    counts_.coarse_refined += static_cast<int>(job.estimate.trace.coarse_poses.size());
    if (trace != nullptr) {
      (*trace)[mi] = WaveTrace{std::move(job.estimate.trace.coarse_poses), std::move(job.estimate.trace.prepared)};
    }
    if (fit_limit_.enabled() && !job.estimate.hypotheses.empty()) {
      std::erase_if(job.estimate.hypotheses,
                    [&](const ClassHypothesis& h) { return h.rms_residual > fit_limit_.At(model, h.X_BO); });
      if (job.estimate.hypotheses.empty()) {
        job.estimate.reason = "every hypothesis fits worse than the depth noise allows (max_fit_rms_sigmas)";
      }
    }
    if (trace != nullptr) {
      for (const auto& h : job.estimate.hypotheses) (*trace)[mi].best_score = std::max((*trace)[mi].best_score, h.score);
    }
  });
}

MatchOutcome ViewMatcher::Match(const ViewSet& views, MatchPass pass, const std::vector<ViewTrace>* earlier,
                                bool keep_traces) {
  const size_t n_views = views.views.size();
  std::vector<std::vector<int>> order(n_views), too_small(n_views);
  std::vector<double> best_cost(n_views);
  tbb::parallel_for(size_t{0}, n_views, [&](size_t v) {
    RankClasses(views.views[v], v >= views.first_region, earlier != nullptr ? &(*earlier)[v] : nullptr, &order[v],
                &too_small[v], &best_cost[v]);
  });
  // The order views start in: as given, or (budget) best-fitting first.
  // Each task of the loop below takes the next view of this list, so views
  // start in this order whatever the partitioner does.
  std::vector<size_t> start_order(n_views);
  std::iota(start_order.begin(), start_order.end(), size_t{0});
  if (budget_) {
    std::stable_sort(start_order.begin(), start_order.end(),
                     [&](size_t a, size_t b) { return best_cost[a] < best_cost[b]; });
  }
  // The budget's count (PerceptionBudget::max_estimates): each view's
  // ranked classes numbered in start order, on from the previous Match.
  const bool counted = budget_ && budget_->counts();
  std::vector<int> rank0(n_views, kUncounted);
  if (counted) {
    for (size_t v : start_order) {
      rank0[v] = next_rank_;
      next_rank_ += static_cast<int>(order[v].size());
    }
  }
  std::atomic<size_t> next_view{0};
  MatchOutcome out;
  std::vector<std::vector<Job>> per_view(n_views);
  const bool early_exit = options_.early_exit_score > 0.0 && !thorough_;
  out.best.assign(n_views, -1.0);
  out.bases.resize(n_views);
  if (keep_traces) out.traces.assign(n_views, ViewTrace(models_.size()));
  tbb::parallel_for(size_t{0}, n_views, [&](size_t) {
    const size_t v = start_order[next_view++];
    const ViewIndices& index = views.views[v];
    std::vector<Eigen::Vector3f> points, normals;
    SegmentView view = ViewOf(index, views.own_normals, &points, &normals);
    if (thorough_) view.search = options_.thorough_search;
    if (pass == MatchPass::kSecondLook) view.search = options_.second_look_search;
    view.reuse.keep_prepared = keep_traces;
    // What preparing the view derives whatever the class, once for all of them.
    if (!order[v].empty() || !too_small[v].empty()) {
      const bool given = v < views.bases.size() && views.bases[v] != nullptr;
      view.reuse.base = given ? views.bases[v] : std::make_shared<const ViewBase>(SceneOf(view));
      out.bases[v] = view.reuse.base;
    }
    const ViewTrace* view_earlier = earlier != nullptr ? &(*earlier)[v] : nullptr;
    ViewTrace* trace = keep_traces ? &out.traces[v] : nullptr;
    std::vector<Job>& jobs = per_view[v];
    if (early_exit && !order[v].empty()) {
      RunClasses(view, order[v], 0, 1, false, rank0[v], view_earlier, trace, &jobs);
      const auto& hs = jobs.front().estimate.hypotheses;
      const bool confident = !hs.empty() && hs.front().score >= options_.early_exit_score &&
                             static_cast<double>(hs.front().support.size()) >=
                                 options_.early_exit_support * static_cast<double>(index.size());
      if (!confident) RunClasses(view, order[v], 1, order[v].size(), false, rank0[v], view_earlier, trace, &jobs);
    } else {
      RunClasses(view, order[v], 0, order[v].size(), false, rank0[v], view_earlier, trace, &jobs);
    }
    bool found = false;
    double best = -1.0;
    for (const Job& job : jobs) {
      for (const auto& h : job.estimate.hypotheses) {
        found |= h.score >= options_.min_detection_score;
        best = std::max(best, h.score);
      }
    }
    out.best[v] = best;
    // The fallback classes of a view the count cut are not run either.
    const bool within_count =
        !counted || budget_->Counted(rank0[v] + std::max(0, static_cast<int>(order[v].size()) - 1));
    if (!found && within_count) {
      RunClasses(view, too_small[v], 0, too_small[v].size(), true, kUncounted, view_earlier, trace, &jobs);
    } else if (!found) {
      counts_.estimates_skipped += static_cast<int>(too_small[v].size());
    }
  });
  counts_.views += static_cast<int>(n_views);
  for (const std::vector<Job>& jobs : per_view) {
    for (const Job& job : jobs) counts_.estimator_calls += job.skipped ? 0 : 1;
  }
  CollectCandidates(views, per_view, &out.candidates);
  return out;
}

MatchOutcome ViewMatcher::MatchClass(const ViewSet& views, const std::vector<int>& model_of_view) {
  const size_t n_views = views.views.size();
  MatchOutcome out;
  out.best.assign(n_views, -1.0);
  std::vector<std::vector<Job>> per_view(n_views);
  tbb::parallel_for(size_t{0}, n_views, [&](size_t v) {
    const ViewIndices& index = views.views[v];
    std::vector<Eigen::Vector3f> points, normals;
    SegmentView view = ViewOf(index, views.own_normals, &points, &normals);
    if (thorough_) view.search = options_.thorough_search;
    RunClasses(view, {model_of_view[v]}, 0, 1, false, kUncounted, nullptr, nullptr, &per_view[v]);
    for (const Job& job : per_view[v]) {
      for (const auto& h : job.estimate.hypotheses) out.best[v] = std::max(out.best[v], h.score);
    }
  });
  counts_.views += static_cast<int>(n_views);
  for (const std::vector<Job>& jobs : per_view) {
    for (const Job& job : jobs) counts_.estimator_calls += job.skipped ? 0 : 1;
  }
  CollectCandidates(views, per_view, &out.candidates);
  return out;
}

void ViewMatcher::CollectCandidates(const ViewSet& views, std::vector<std::vector<Job>>& per_view,
                                    std::vector<Candidate>* out) {
  for (size_t v = 0; v < per_view.size(); ++v) {
    const ViewIndices& index = views.views[v];
    for (Job& job : per_view[v]) {
      if (job.skipped) continue;
      const ClassModel& model = *models_[static_cast<size_t>(job.model)];
      if (job.estimate.hypotheses.empty() && counts_.first_reason.empty()) counts_.first_reason = job.estimate.reason;
      for (ClassHypothesis& h : job.estimate.hypotheses) {
        if (!h.X_BO.matrix().allFinite() || !std::isfinite(h.score)) continue;
        // A class too small for the view must explain its part of it well
        // (otherwise small parts are fitted onto larger parts' plates).
        const double min_score = job.too_small
                                     ? std::max(options_.min_detection_score, options_.too_small_class_min_score)
                                     : options_.min_detection_score;
        if (h.score < min_score) {
          ++counts_.rejected_low_score;
          continue;
        }
        if (h.free_space_fraction > options_.max_free_space_fraction) {
          ++counts_.rejected_free_space;
          continue;
        }
        Candidate c;
        c.class_id = model.class_id();
        c.diameter = model.diameter();
        c.centre_B = h.X_BO * model.centroid_O().cast<double>();
        c.view = static_cast<int>(v);
        c.support_roi.reserve(h.support.size());
        for (int k : h.support) {
          if (k >= 0 && static_cast<size_t>(k) < index.size()) {
            c.support_roi.push_back(segments_.roi_index[static_cast<size_t>(index[static_cast<size_t>(k)])]);
          }
        }
        c.h = std::move(h);
        out->push_back(std::move(c));
      }
    }
  }
}

}  // namespace bp::internal
