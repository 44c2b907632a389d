// What an estimate derives from a view before its search (the "prepare" step
// of PoseEstimator::Estimate): the finite points, the view's shape, the
// points subsampled at the PPF step with normals, the support structures and
// the ICP points. Private to bp_pipeline. Frames: B base, C camera. Metres.
#pragma once

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pipeline/internal/ppf_matcher.h"
#include "pipeline/internal/verification.h"
#include "pipeline/pose_estimator.h"

namespace bp::internal {

// An estimate of the same view by the same estimator may reuse it
// (SearchReuse::prepared: the perception's second look). Shared read-only
// once its estimate has returned it.
struct PreparedView {
  uint64_t model_id = 0;  // PoseModel::id of the estimator that made it
  // Of the view's points (count, coordinate sums), with SearchReuse::keep_prepared.
  std::array<double, 4> fingerprint{};
  std::vector<Eigen::Vector3f> pts;  // finite points
  std::vector<int> index;            // their indices in SceneView::points_B
  std::optional<Eigen::Vector3f> view_plane;  // a planar view's normal, towards the camera
  std::vector<Eigen::Vector3f> sub_p, sub_n;  // subsampled at the PPF step, with normals towards the camera
  SegmentDepth segment_depth;                 // without a depth image only
  SceneSupport support;                       // of pts, for the support queries
  std::vector<uint8_t> sub_boundary;          // per subsampled point: on the view's boundary
  std::vector<Eigen::Vector3f> fine;          // the fine ICP pass's points
  std::vector<uint8_t> fine_boundary;         // per fine point
  // The first search's PPF peaks (PpfMatchOptions::record): a wider search
  // (more peaks per reference point) of the same view reads them instead of
  // voting again.
  PpfVotes votes;
};

struct PoseModel;

// What a view gives, or why it gives nothing to search.
struct Preparation {
  bool ok = false;
  std::string reason;      // when !ok
  int scene_points = 0;    // finite points
  int sampled_points = 0;  // subsampled points with a normal
  double ms = 0.0;
};

// Fills *w from the view (w->model_id included). Not ok
// for fewer than 30 finite points, (nearly) collinear points, a view much
// smaller than the part or fewer than 8 subsampled points with a normal.
Preparation PrepareView(const PoseModel& model, const SceneView& view, PreparedView* w);

// 1 for points on the boundary of a sampled surface: the centroid of their
// neighbours within radius is off-centre by more than a quarter radius (a
// straight edge gives 4 / (3 pi) ~ 0.42 radius, the interior ~0).
// queries: the points to flag; hashed: the points hash was built on.
std::vector<uint8_t> BoundaryFlags(std::span<const Eigen::Vector3f> queries, std::span<const Eigen::Vector3f> hashed,
                                   const PointHash& hash, float radius);

}  // namespace bp::internal
