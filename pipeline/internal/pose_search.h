// The steps of PoseEstimator::Estimate after the view is prepared
// (docs/perception.md): coarse (PPF voting, resting seeds), the first pass
// (ICP on the subsampled points and a quick verification of each coarse pose
// and face seed, stopping at one that explains the view), the fine pass (ICP
// on the full-resolution points, verification, near-symmetric turns, filled
// holes) and the kept hypotheses. Private to bp_pipeline. Frames: B base, O
// part. Metres.
#pragma once

#include <memory>

#include "pipeline/internal/view_preparation.h"
#include "pipeline/pose_estimator.h"

namespace bp::internal {

struct PoseModel;

// Searches a prepared view. `owned` is the PreparedView this estimate made
// (null when it reuses search.prepared: then the PPF peaks it recorded are
// replayed); `prepared` is the one to use. Fills *out's hypotheses,
// coarse poses, counts, timings and reason.
void SearchPreparedView(const PoseModel& model, const SceneView& view, const PoseSearch& search,
                        const PreparedView& prepared, PreparedView* owned, PoseEstimates* out);

}  // namespace bp::internal
