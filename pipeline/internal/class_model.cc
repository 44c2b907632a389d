#include "pipeline/internal/class_model.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>

#include "core/mesh.h"

#include "pipeline/pose_estimator.h"

namespace bp::internal {

namespace {

SceneView ToScene(const SegmentView& view) {
  SceneView scene;
  scene.points_B = view.points_B;
  scene.normals_B = view.normals_B;
  if (view.frame != nullptr) {
    scene.X_BC = view.frame->X_BC;
    if (view.frame->organized()) {
      scene.depth = &view.frame->depth;
      scene.intrinsics = view.frame->intrinsics;
    }
  }
  scene.support_plane_B = view.floor_plane_B;
  return scene;
}

class PpfClassModel final : public ClassModel {
 public:
  PpfClassModel(int class_id, std::unique_ptr<PoseEstimator> estimator)
      : class_id_(class_id), estimator_(std::move(estimator)),
        extents_(PrincipalExtents(estimator_->surface_points_O())) {}
  int class_id() const override { return class_id_; }
  double diameter() const override { return estimator_->diameter(); }
  Eigen::Vector3f extents() const override { return extents_; }
  Eigen::Vector3f centroid_O() const override { return estimator_->centroid_O(); }

  void MarkOnSurface(const Pose& X_BO, std::span<const Eigen::Vector3f> points_B, float tolerance,
                     std::vector<uint8_t>* on_surface) const override {
    estimator_->MarkOnSurface(X_BO, points_B, tolerance, on_surface);
  }
  size_t CountInside(const Pose& X_BO, std::span<const Eigen::Vector3f> points_B, float min_depth) const override {
    return estimator_->CountInside(X_BO, points_B, min_depth);
  }
  std::span<const Eigen::Vector3f> surface_points_O() const override { return estimator_->surface_points_O(); }

  Result<PoseHypothesis> Score(const SegmentView& view, const Pose& X_BO) const override {
    return estimator_->Score(ToScene(view), X_BO);
  }

  ClassEstimate Estimate(const SegmentView& view) const override {
    const SceneView scene = ToScene(view);
    ClassEstimate out;
    PoseSearch search = view.search ? *view.search : estimator_->default_search();
    search.keep_prepared = search.keep_prepared || view.keep_prepared;
    Result<PoseEstimates> est = estimator_->Estimate(scene, search);
    if (!est.ok()) {
      out.reason = est.status().ToString();
      return out;
    }
    for (PoseHypothesis& h : est->hypotheses) {
      if (!h.X_BO.matrix().allFinite() || !std::isfinite(h.score)) continue;
      ClassHypothesis c;
      c.X_BO = h.X_BO;
      c.score = h.score;
      c.rms_residual = h.rms_residual;
      const int seen = h.visible_points - h.occluded_points;
      c.visible_fraction = h.visible_points > 0 ? static_cast<double>(std::max(0, seen)) / h.visible_points : 0.0;
      c.support = std::move(h.supporting_indices);
      out.hypotheses.push_back(std::move(c));
    }
    if (out.hypotheses.empty()) out.reason = est->no_result_reason;
    out.coarse_poses = std::move(est->coarse_poses);
    out.coarse_skipped = est->coarse_skipped;
    out.prepared = std::move(est->prepared);
    return out;
  }

 private:
  int class_id_;
  std::unique_ptr<PoseEstimator> estimator_;
  Eigen::Vector3f extents_;
};

// Absolute and relative slack of SegmentFitsClass: depth noise and normal-
// estimation outliers at the segment border (a few mm at most).
constexpr double kFitToleranceAbs = 0.004;
constexpr double kFitToleranceRel = 0.05;

}  // namespace

Eigen::Vector3f PrincipalExtents(std::span<const Eigen::Vector3f> points) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  int n = 0;
  for (const Eigen::Vector3f& p : points) {
    if (!p.allFinite()) continue;
    mean += p.cast<double>();
    ++n;
  }
  if (n < 2) return Eigen::Vector3f::Zero();
  mean /= n;
  Eigen::Matrix3d cov = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3f& p : points) {
    if (!p.allFinite()) continue;
    const Eigen::Vector3d d = p.cast<double>() - mean;
    cov += d * d.transpose();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(cov);
  const Eigen::Matrix3d axes = eig.eigenvectors();  // ascending eigenvalues
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(1e30), hi = Eigen::Vector3d::Constant(-1e30);
  for (const Eigen::Vector3f& p : points) {
    if (!p.allFinite()) continue;
    const Eigen::Vector3d q = axes.transpose() * (p.cast<double>() - mean);
    lo = lo.cwiseMin(q);
    hi = hi.cwiseMax(q);
  }
  Eigen::Vector3d e = hi - lo;
  std::sort(e.data(), e.data() + 3, [](double a, double b) { return a > b; });
  return e.cast<float>();
}

bool SegmentFitsClass(const Eigen::Vector3f& segment_extents, double model_diameter) {
  return segment_extents.x() <= model_diameter * (1.0 + kFitToleranceRel) + kFitToleranceAbs;
}

Result<std::unique_ptr<ClassModel>> BuildClassModel(const PartSpec& part) {
  Result<TriangleMesh> mesh = LoadMesh(part.mesh);
  if (!mesh.ok()) return mesh.status();
  auto estimator = PoseEstimator::Build(*mesh, part.symmetry);
  if (!estimator.ok()) {
    return Status::InvalidArgument("part '" + part.name + "': " + estimator.status().ToString());
  }
  return std::unique_ptr<ClassModel>(std::make_unique<PpfClassModel>(part.class_id, std::move(*estimator)));
}

}  // namespace bp::internal
