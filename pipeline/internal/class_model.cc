#include "pipeline/internal/class_model.h"

#include "core/mesh.h"

#include "pipeline/pose_estimator.h"

namespace bp::internal {

namespace {

class PpfClassModel final : public ClassModel {
 public:
  PpfClassModel(int class_id, std::unique_ptr<PoseEstimator> estimator)
      : class_id_(class_id), estimator_(std::move(estimator)) {}
  int class_id() const override { return class_id_; }
  double diameter() const override { return estimator_->diameter(); }

  ClassEstimate Estimate(const SegmentView& view) const override {
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
    ClassEstimate out;
    Result<PoseEstimates> est = estimator_->Estimate(scene);
    if (!est.ok()) {
      out.reason = est.status().ToString();
      return out;
    }
    for (PoseHypothesis& h : est->hypotheses) {
      if (!h.X_BO.matrix().allFinite() || !std::isfinite(h.score)) continue;
      ClassHypothesis c;
      c.X_BO = h.X_BO;
      c.score = h.score;
      const int seen = h.visible_points - h.occluded_points;
      c.visible_fraction = h.visible_points > 0 ? static_cast<double>(std::max(0, seen)) / h.visible_points : 0.0;
      c.support = std::move(h.supporting_indices);
      out.hypotheses.push_back(std::move(c));
    }
    if (out.hypotheses.empty()) out.reason = est->no_result_reason;
    return out;
  }

 private:
  int class_id_;
  std::unique_ptr<PoseEstimator> estimator_;
};

}  // namespace

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
