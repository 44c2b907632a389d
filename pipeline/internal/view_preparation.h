// What an estimate derives from a view before its search (the "prepare" step
// of PoseEstimator::Estimate): the finite points, the view's shape, the
// points subsampled at the PPF step with normals, the support structures and
// the ICP points. Private to bp_pipeline. Frames: B base, C camera. Metres.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <span>
#include <string>
#include <vector>

#include <Eigen/Core>

#include "pipeline/internal/ppf_matcher.h"
#include "pipeline/internal/verification.h"
#include "pipeline/pose_estimator.h"

namespace bp::internal {

// The least-squares plane of pts[i] for keep[i] (all when keep is empty,
// else keep.size() == pts.size()): its centroid, unit normal (either
// side) and RMS distance (metres). False for fewer than 3 points.
bool FitPlane(std::span<const Eigen::Vector3f> pts, std::span<const uint8_t> keep, Eigen::Vector3d* c,
              Eigen::Vector3d* n, double* rms);

// A fingerprint of a view's points: their count and the sums of their
// finite coordinates (what was derived from a view must come from the same
// points).
std::array<double, 4> Fingerprint(std::span<const Eigen::Vector3f> points);

// What preparing a view derives whatever the estimator: its finite points,
// their spread, a planar view's normal, and the support structure. The
// estimates of one view share it (SearchReuse::base: every class a view is
// matched with, and a view matched once more with the estimator's own
// normals), each otherwise derived it again, the same. Thread-safe:
// read-only but for the support structure, built once by its first caller.
class ViewBase {
 public:
  explicit ViewBase(const SceneView& view);
  ViewBase(const ViewBase&) = delete;
  ViewBase& operator=(const ViewBase&) = delete;

  size_t view_points() const { return view_points_; }  // SceneView::points_B.size(), finite or not
  const std::vector<Eigen::Vector3f>& pts() const { return pts_; }  // the finite points
  const std::vector<int>& index() const { return index_; }          // their indices in SceneView::points_B
  // Square roots of the eigenvalues of the finite points' covariance
  // (their spread along the principal axes, metres), ascending; zero for
  // fewer than 2 points.
  const Eigen::Vector3d& spread() const { return spread_; }
  // A planar view's normal (RMS off its plane below 1 mm), towards the camera.
  const std::optional<Eigen::Vector3f>& view_plane() const { return view_plane_; }
  // The plane most of the view lies on: fitted by trimmed least squares
  // (from the plane of all the points, four times the points within the
  // larger of 1.5 mm and twice the RMS distance of those kept before), its
  // normal towards the camera, the points within 1.5 mm of it and their
  // share of pts(). No normal for fewer than 3 points. Found by the first
  // call (PoseEstimatorOptions::planar_view_min_share: a view whose
  // least-squares plane leans to a few points off it, mixed pixels along a
  // thin plate's outline, is still one plane to the face seeds).
  struct MostlyPlanar {
    std::optional<Eigen::Vector3f> normal;
    double share = 0.0;  // in [0, 1]
    std::vector<Eigen::Vector3f> pts;
  };
  const MostlyPlanar& OnMostlyOnePlane() const;
  // The support structure of pts() with cells of `cell` (2 support_distance)
  // against `view` (the one the base was made from): built by the first
  // call, shared by later calls with the same cell; nullptr for another
  // cell (an estimator with another support_distance builds its own).
  const SceneSupport* Support(float cell, const SceneView& view) const;

 private:
  size_t view_points_ = 0;
  std::vector<Eigen::Vector3f> pts_;
  std::vector<int> index_;
  Eigen::Vector3d spread_ = Eigen::Vector3d::Zero();
  std::optional<Eigen::Vector3f> view_plane_;
  Eigen::Vector3f camera_ = Eigen::Vector3f::Zero();  // the viewpoint, B
  mutable std::once_flag plane_once_;
  mutable MostlyPlanar plane_;
  mutable std::once_flag support_once_;
  mutable float support_cell_ = 0.f;
  mutable SceneSupport support_;
};

// An estimate of the same view by the same estimator may reuse it
// (SearchReuse::prepared: the perception's second look). Shared read-only
// once its estimate has returned it.
struct PreparedView {
  uint64_t model_id = 0;  // PoseModel::id of the estimator that made it
  // Of the view's points (count, coordinate sums), with SearchReuse::keep_prepared.
  std::array<double, 4> fingerprint{};
  std::shared_ptr<const ViewBase> base;  // the finite points (pts, index), the view plane
  const std::vector<Eigen::Vector3f>& pts() const { return base->pts(); }
  const std::vector<int>& index() const { return base->index(); }
  std::vector<Eigen::Vector3f> sub_p, sub_n;  // subsampled at the PPF step, with normals towards the camera
  SegmentDepth segment_depth;                 // without a depth image only
  // Of pts, for the support queries: the base's, or (another cell) its own.
  std::shared_ptr<const SceneSupport> support;
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

// Fills *w from the view (w->model_id included), on `base` when given
// (REQUIRES: made from the same points: EstimatePose checks their count)
// else on a base of its own. Not ok
// for fewer than 30 finite points, (nearly) collinear points, a view much
// smaller than the part or fewer than 8 subsampled points with a normal.
Preparation PrepareView(const PoseModel& model, const SceneView& view, std::shared_ptr<const ViewBase> base,
                        PreparedView* w);

// 1 for points on the boundary of a sampled surface: the centroid of their
// neighbours within radius is off-centre by more than a quarter radius (a
// straight edge gives 4 / (3 pi) ~ 0.42 radius, the interior ~0).
// queries: the points to flag; hashed: the points hash was built on.
std::vector<uint8_t> BoundaryFlags(std::span<const Eigen::Vector3f> queries, std::span<const Eigen::Vector3f> hashed,
                                   const PointHash& hash, float radius);

}  // namespace bp::internal
