// Perception's pose stage for a set of views: the class models each view may
// hold, ranked; their pose estimates (with the early exit); the hypotheses
// that pass the detection bar as candidates for acceptance
// (docs/perception_pipeline.md, "Pose search per view"). Private to
// bp_pipeline. Frames: B base, O part. SI units.
#pragma once

#include <atomic>
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "core/pose.h"
#include "pipeline/frame.h"
#include "pipeline/internal/class_model.h"
#include "pipeline/internal/fit_limit.h"
#include "pipeline/internal/segmentation.h"
#include "pipeline/perception.h"

namespace bp::internal {

// A hypothesis that passed the detection bar, before acceptance.
struct Candidate {
  int class_id = 0;
  double diameter = 0.0;                               // of the class, metres
  Eigen::Vector3d centre_B = Eigen::Vector3d::Zero();  // the part's surface centroid at the hypothesis
  int view = 0;                                        // index into the matched ViewSet
  ClassHypothesis h;
  std::vector<int32_t> support_roi;  // ROI point indices
};

// Views to match: index lists into Segments::points; views[first_region..]
// are region views (SegmentationOptions::match_regions), the others
// segment views.
struct ViewSet {
  std::vector<ViewIndices> views;
  size_t first_region = 0;
  // Match without the segmentation's normals (Segments::normals): the
  // estimator estimates its own from the points
  // (PerceptionOptions::residual_own_normals).
  bool own_normals = false;
  // Per view (optional; null: none): the base an earlier Match of the same
  // view made (MatchOutcome::bases), shared instead of made again.
  std::vector<std::shared_ptr<const ViewBase>> bases;
};

// What one (view, class) estimate of a wave leaves for the second look.
struct WaveTrace {
  std::vector<Pose> coarse_poses;                // refined: not refined again
  std::shared_ptr<const PreparedView> prepared;  // reused instead of derived again
  double best_score = -1.0;  // of its hypotheses within the fit residual limit; -1: none
};
using ViewTrace = std::vector<WaveTrace>;  // per class model index

enum class MatchPass {
  kWave,        // the estimator's default search (thorough: PerceptionOptions::thorough_search)
  kSecondLook,  // PerceptionOptions::second_look_search
};

struct MatchOutcome {
  std::vector<Candidate> candidates;  // in view order, then class order, then hypothesis order
  std::vector<double> best;           // per view: the best score over the classes tried; -1: none
  std::vector<ViewTrace> traces;      // with keep_traces: per view
  // Per view: the base its estimates shared (SearchReuse::base; null when
  // no class was run on it), for a later Match of the same view.
  std::vector<std::shared_ptr<const ViewBase>> bases;
};

// Counts over every Match of one frame (PerceptionResult's fields of the
// same names). Match updates them from its tasks.
struct MatchCounts {
  int views = 0;
  int estimator_calls = 0;
  std::atomic<int> coarse_refined{0};
  std::atomic<int> coarse_skipped{0};
  std::atomic<int> estimates_skipped{0};  // not started: the budget would have been exceeded
  int rejected_low_score = 0;  // hypotheses below the detection bar
  int rejected_free_space = 0;  // above it, but too much in free space (max_free_space_fraction)
  std::string first_reason;    // the first estimate's reason for no hypothesis
};

// The PerceptionBudget of a run: admits an estimate while the clock plus
// the mean duration of the estimates admitted so far is within the
// deadline. Thread-safe.
class BudgetGate {
 public:
  explicit BudgetGate(const PerceptionBudget& budget);
  // The clock now if an estimate may start, else nullopt.
  std::optional<double> Admit() const;
  // An admitted estimate that started at `started_ms` has finished.
  void Finished(double started_ms);
  // Whether the estimate numbered `rank` (from 0, in start order) is within
  // PerceptionBudget::max_estimates (always, without a count).
  bool Counted(int rank) const { return budget_.max_estimates <= 0 || rank < budget_.max_estimates; }
  bool counts() const { return budget_.max_estimates > 0; }

 private:
  double Now() const;
  const PerceptionBudget& budget_;
  std::atomic<int64_t> done_us_{0};  // summed durations of finished estimates, microseconds
  std::atomic<int> done_{0};
};

// Runs class models on views, per frame. Not thread-safe itself; Match runs
// its views and classes in parallel on the caller's oneTBB arena.
class ViewMatcher {
 public:
  // Everything referenced must outlive the matcher. With a budget, views
  // start in order of their best class's ranking cost (the views most
  // likely to hold a part first), a view's classes in ranking order, and
  // estimates the budget would not cover are skipped
  // (MatchCounts::estimates_skipped).
  ViewMatcher(const PerceptionOptions& options, std::span<const ClassModel* const> models, bool thorough,
              const Frame& frame, const std::optional<Eigen::Vector4d>& floor_plane_B, const Segments& segments,
              const FitRmsLimit& fit_limit, const PerceptionBudget* budget = nullptr);

  // Per view, in parallel: its base (ViewBase: the views.bases one, else
  // made once for all its classes), the classes that fit it ranked (RankClasses), the
  // first alone, the others unless it gave a confident hypothesis
  // (PerceptionOptions::early_exit_score; thorough: every class), then the
  // classes too small for the view when none found a detection.
  // earlier (second look, optional): per view, what its wave left
  // (WaveTrace): coarse poses not refined again, the prepared view, the
  // class order. keep_traces: fill MatchOutcome::traces for a second look.
  MatchOutcome Match(const ViewSet& views, MatchPass pass, const std::vector<ViewTrace>* earlier = nullptr,
                     bool keep_traces = false);

  // Each view by one class model alone (models index model_of_view[v]),
  // with the estimator's default search, views in parallel: candidates as
  // Match gives them (fit limit, detection bar, free space).
  MatchOutcome MatchClass(const ViewSet& views, const std::vector<int>& model_of_view);

  const MatchCounts& counts() const { return counts_; }

 private:
  struct Job;
  // The view's samples and normals (filled in; none with own_normals) seen
  // as a SegmentView of this frame.
  SegmentView ViewOf(const ViewIndices& index, bool own_normals, std::vector<Eigen::Vector3f>* points,
                     std::vector<Eigen::Vector3f>* normals) const;
  // The class ranking of one view: the classes that fit it (best first;
  // model order in a thorough run without a budget) and those too small for it. Empty for a region view no class fits.
  // *best_cost: the ranking cost of the best class that fits (+inf: none).
  void RankClasses(const ViewIndices& view, bool region_view, const ViewTrace* earlier, std::vector<int>* order,
                   std::vector<int>* too_small, double* best_cost) const;
  // Runs the classes ms[from, to) on one view in parallel, appending to jobs.
  // rank0: the number of ms[0] in the budget's count (class r is rank0 + r;
  // PerceptionBudget::max_estimates), or kUncounted.
  static constexpr int kUncounted = -1;
  void RunClasses(const SegmentView& view, const std::vector<int>& ms, size_t from, size_t to, bool too_small,
                  int rank0, const ViewTrace* earlier, ViewTrace* trace, std::vector<Job>* jobs);
  // The jobs' hypotheses that pass the detection bar, as candidates.
  void CollectCandidates(const ViewSet& views, std::vector<std::vector<Job>>& per_view,
                         std::vector<Candidate>* out);

  const PerceptionOptions& options_;
  std::span<const ClassModel* const> models_;
  bool thorough_;
  const Frame& frame_;
  std::optional<Eigen::Vector4d> floor_plane_B_;  // none: nothing rests on a support plane
  const Segments& segments_;
  const FitRmsLimit& fit_limit_;
  std::optional<BudgetGate> budget_;
  int next_rank_ = 0;  // the budget's count: the number the next Match's first estimate gets
  MatchCounts counts_;
};

// How badly a view's principal extents (largest first) match a model's:
// the differences relative to the model's extents, summed.
double ExtentMismatch(const Eigen::Vector3f& view, const Eigen::Vector3f& model);

// How far a view's PlanarShare lies outside a class's range (plus a slack
// of 0.1 either side); 0 inside it or for share < 0 (not used).
double PlanarShareMismatch(float share, const ClassModel& model);

}  // namespace bp::internal
