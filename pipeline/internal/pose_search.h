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

// The model behind a PoseEstimator, for EstimatePose.
class PoseEstimatorAccess {
 public:
  static const PoseModel& Model(const PoseEstimator& estimator);
};

}  // namespace bp::internal
