// The steps of PoseEstimator::Estimate (docs/perception.md): prepare the view
// (internal/view_preparation.h), coarse (PPF voting, resting seeds), the first
// pass (ICP on the subsampled points and a quick verification of each coarse
// pose and face seed, stopping at one that explains the view), the fine pass
// (ICP on the full-resolution points, verification, near-symmetric turns,
// filled holes) and the kept hypotheses. Also what perception's second look
// reuses from a wave's estimate of the same view. Private to bp_pipeline.
// Frames: B base, O part. Metres.
#pragma once

#include <memory>
#include <span>
#include <vector>

#include "core/pose.h"
#include "core/status.h"
#include "pipeline/internal/view_preparation.h"
#include "pipeline/pose_estimator.h"

namespace bp::internal {

struct PoseModel;

// What an estimate of a view may take from an earlier estimate of the same
// view (the same points) by the same estimator.
struct SearchReuse {
  // Coarse poses the earlier estimate refined (its SearchTrace::coarse_poses):
  // a coarse pose or seed within the pose clustering thresholds of one of
  // them is not refined again (it would converge to a hypothesis that
  // estimate already returned or rejected). Must outlive the call.
  std::span<const Pose> skip_coarse = {};
  // The earlier estimate's prepared view (its SearchTrace::prepared), used
  // instead of deriving it again; its PPF peaks are replayed.
  std::shared_ptr<const PreparedView> prepared = nullptr;
  // Return this estimate's prepared view in SearchTrace::prepared.
  bool keep_prepared = false;
  // What preparing this view derives whatever the estimator (the finite
  // points, their spread, the support structure), made by another estimate
  // of it or for it (ViewMatcher: once per view); not derived again. Must
  // come from the view's points (a base of another count of points is
  // refused). Unused with `prepared`.
  std::shared_ptr<const ViewBase> base = nullptr;
};

// What an estimate leaves for a later estimate of the same view.
struct SearchTrace {
  std::vector<Pose> coarse_poses;  // refined by the first pass, in order
  int coarse_skipped = 0;          // left out by SearchReuse::skip_coarse
  std::shared_ptr<const PreparedView> prepared = nullptr;  // with SearchReuse::keep_prepared
};

// PoseEstimator::Estimate with reuse. InvalidArgument for the misuses
// Estimate reports, and for a prepared view made by another estimator or
// for other points. trace: optional.
Result<PoseEstimates> EstimatePose(const PoseModel& model, const SceneView& view, const PoseSearch& search,
                                   const SearchReuse& reuse = {}, SearchTrace* trace = nullptr);

// What ChooseTurn found: the pose that explains most of the view and its
// figures, verified in full, and the given pose's.
struct TurnChoice {
  Pose X_BO = Pose::Identity();
  int net = 0;       // supported minus free-space samples at X_BO
  int given_net = 0;  // the same at the pose ChooseTurn was given
  double score = -1.0;  // VerifyStats::score at X_BO
};

// A part nearly round about an axis (a pipe tee about its run) judged again
// on a view of its own points (perception: after its neighbours are
// accepted, the points they explain left out of the view and of its depth
// image). Looks at X_BO's turns about the model's turn axes as the fine
// pass does, but finer (step_deg > 0; the fine pass's turn_step_deg misses
// a true turn whose peak is narrower than its step): quick looks every two
// steps, a step either side of the best three, the best bisected to an
// eighth of the step; then verifies in full X_BO, the
// best turn per axis and `others`; returns the one with the most supported
// minus free-space samples (X_BO on ties; none that sinks the part into the
// support plane). Needs the view's depth image: without one, X_BO.
TurnChoice ChooseTurn(const PoseModel& model, const SceneView& view, const Pose& X_BO, std::span<const Pose> others,
                      double step_deg);

// The model behind a PoseEstimator, for EstimatePose.
class PoseEstimatorAccess {
 public:
  static const PoseModel& Model(const PoseEstimator& estimator);
};

}  // namespace bp::internal
