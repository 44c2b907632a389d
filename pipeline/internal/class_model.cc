#include "pipeline/internal/class_model.h"

#include <algorithm>
#include <cmath>

#include <Eigen/Eigenvalues>

#include "core/mesh.h"

#include "pipeline/internal/model_sampling.h"
#include "pipeline/internal/part_settings.h"
#include "pipeline/internal/pose_model.h"
#include "pipeline/pose_estimator.h"

namespace bp::internal {

namespace {

// CountInside depth for acceptance: this, or this fraction of the thinnest
// plate when that is less (the field sees the nearer face past half a wall).
constexpr double kInsideDepth = 0.001;
constexpr double kInsideWallFraction = 0.4;


class PpfClassModel final : public ClassModel {
 public:
  PpfClassModel(int class_id, std::unique_ptr<PoseEstimator> estimator, std::pair<float, float> planar_share)
      : class_id_(class_id), estimator_(std::move(estimator)),
        extents_(PrincipalExtents(estimator_->surface_points_O())), planar_share_(planar_share),
        inside_depth_(static_cast<float>(
            std::min(kInsideDepth, kInsideWallFraction * PoseEstimatorAccess::Model(*estimator_).thinnest_plate))) {}
  float inside_depth() const override { return inside_depth_; }
  double lowest_upward_face() const override { return PoseEstimatorAccess::Model(*estimator_).lowest_upward_face; }
  const PoseEstimatorOptions& estimator_options() const override {
    return PoseEstimatorAccess::Model(*estimator_).options;
  }
  int class_id() const override { return class_id_; }
  double diameter() const override { return estimator_->diameter(); }
  Eigen::Vector3f extents() const override { return extents_; }
  Eigen::Vector3f centroid_O() const override { return estimator_->centroid_O(); }
  std::pair<float, float> planar_share_range() const override { return planar_share_; }

  void MarkOnSurface(const Pose& X_BO, std::span<const Eigen::Vector3f> points_B, float tolerance,
                     std::vector<uint8_t>* on_surface) const override {
    estimator_->MarkOnSurface(X_BO, points_B, tolerance, on_surface);
  }
  size_t CountInside(const Pose& X_BO, std::span<const Eigen::Vector3f> points_B, float min_depth) const override {
    return estimator_->CountInside(X_BO, points_B, min_depth);
  }
  std::span<const Eigen::Vector3f> surface_points_O() const override { return estimator_->surface_points_O(); }

  bool DistinctPoses(const Pose& a, const Pose& b) const override {
    const PoseEstimatorOptions& o = estimator_options();
    return SymmetricTranslationError(a, b, estimator_->symmetry()) > o.ambiguity_translation ||
           SymmetricRotationError(a, b, estimator_->symmetry()) > o.ambiguity_rotation_deg * M_PI / 180.0;
  }
  bool has_turn_axes() const override { return !PoseEstimatorAccess::Model(*estimator_).turn_axes.empty(); }
  TurnChoice ChooseTurn(const SegmentView& view, const Pose& X_BO, std::span<const Pose> others,
                        double step_deg) const override {
    return internal::ChooseTurn(PoseEstimatorAccess::Model(*estimator_), SceneOf(view), X_BO, others, step_deg);
  }

  Result<PoseHypothesis> Score(const SegmentView& view, const Pose& X_BO) const override {
    return estimator_->Score(SceneOf(view), X_BO);
  }

  ClassEstimate Estimate(const SegmentView& view) const override {
    const SceneView scene = SceneOf(view);
    ClassEstimate out;
    const PoseSearch search = view.search ? *view.search : estimator_->default_search();
    Result<PoseEstimates> est =
        EstimatePose(PoseEstimatorAccess::Model(*estimator_), scene, search, view.reuse, &out.trace);
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
      c.free_space_fraction = seen > 0 ? static_cast<double>(h.free_space_points) / seen : 0.0;
      c.support = std::move(h.supporting_indices);
      c.alternatives = std::move(h.alternatives);
      out.hypotheses.push_back(std::move(c));
    }
    if (out.hypotheses.empty()) out.reason = est->no_result_reason;
    return out;
  }

 private:
  int class_id_;
  std::unique_ptr<PoseEstimator> estimator_;
  Eigen::Vector3f extents_;
  std::pair<float, float> planar_share_;
  float inside_depth_;
};

// Absolute and relative slack of SegmentFitsClass: depth noise and normal-
// estimation outliers at the segment border (a few mm at most).
constexpr double kFitToleranceAbs = 0.004;
constexpr double kFitToleranceRel = 0.05;
// PlanarShare: normals within this angle of a mode are on its plane.
constexpr double kPlanarShareAngleDeg = 15.0;
// The model's range: view directions, sample spacing (metres), and the
// smallest cosine between a sample's normal and the view direction for it to
// be seen (about 80 degrees, as grazing surfaces give no depth).
constexpr int kPlanarShareDirections = 64;
constexpr double kPlanarShareSampleSpacing = 0.002;
constexpr float kPlanarShareMinCos = 0.17f;

}  // namespace

SceneView SceneOf(const SegmentView& view) {
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

bool ClassModel::DistinctPoses(const Pose& a, const Pose& b) const {
  const PoseEstimatorOptions& o = estimator_options();
  const Symmetry none;
  return SymmetricTranslationError(a, b, none) > o.ambiguity_translation ||
         SymmetricRotationError(a, b, none) > o.ambiguity_rotation_deg * M_PI / 180.0;
}

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

float PlanarShare(std::span<const Eigen::Vector3f> normals, std::span<const float> weights) {
  // At most kPlanarShareSamples normals (strided), modes sought among at most
  // kPlanarShareSeeds of them.
  constexpr size_t kPlanarShareSamples = 128;
  constexpr size_t kPlanarShareSeeds = 32;
  const float min_cos = std::cos(static_cast<float>(kPlanarShareAngleDeg * M_PI / 180.0));
  const size_t stride = std::max<size_t>(1, (normals.size() + kPlanarShareSamples - 1) / kPlanarShareSamples);
  std::vector<Eigen::Vector3f> n;
  std::vector<float> w;
  for (size_t i = 0; i < normals.size(); i += stride) {
    if (!normals[i].allFinite()) continue;
    n.push_back(normals[i]);
    w.push_back(weights.empty() ? 1.f : weights[i]);
  }
  float total = 0.f;
  for (float x : w) total += x;
  if (n.size() < 2 || !(total > 0.f)) return 0.f;
  std::vector<uint8_t> taken(n.size(), 0);
  float share = 0.f;
  for (int mode = 0; mode < 2; ++mode) {
    // The free normal with the most free weight within the angle.
    const size_t seed_stride = std::max<size_t>(1, n.size() / kPlanarShareSeeds);
    float best = -1.f;
    size_t best_i = 0;
    for (size_t a = 0; a < n.size(); a += seed_stride) {
      if (taken[a]) continue;
      float sum = 0.f;
      for (size_t b = 0; b < n.size(); ++b) sum += (!taken[b] && n[a].dot(n[b]) > min_cos) ? w[b] : 0.f;
      if (sum > best) {
        best = sum;
        best_i = a;
      }
    }
    if (best <= 0.f) break;
    for (size_t b = 0; b < n.size(); ++b) {
      if (!taken[b] && n[best_i].dot(n[b]) > min_cos) taken[b] = 1;
    }
    share += best;
  }
  return share / total;
}

std::pair<float, float> ModelPlanarShareRange(std::span<const Eigen::Vector3f> normals_O, int directions) {
  float lo = 1.f, hi = 0.f;
  std::vector<Eigen::Vector3f> seen;
  std::vector<float> weight;
  // Fibonacci sphere of view directions (towards the camera, in O).
  const double golden = M_PI * (3.0 - std::sqrt(5.0));
  for (int k = 0; k < directions; ++k) {
    const double z = 1.0 - 2.0 * (k + 0.5) / directions;
    const double r = std::sqrt(std::max(0.0, 1.0 - z * z));
    const Eigen::Vector3f d(static_cast<float>(r * std::cos(golden * k)), static_cast<float>(r * std::sin(golden * k)),
                            static_cast<float>(z));
    seen.clear();
    weight.clear();
    for (const Eigen::Vector3f& nn : normals_O) {
      // Area-uniform samples: the depth image samples a face in proportion
      // to its projected area.
      const float c = nn.dot(d);
      if (c <= kPlanarShareMinCos) continue;
      seen.push_back(nn);
      weight.push_back(c);
    }
    if (seen.size() < 2) continue;
    const float f = PlanarShare(seen, weight);
    lo = std::min(lo, f);
    hi = std::max(hi, f);
  }
  return {std::min(lo, hi), hi};
}

bool SegmentFitsClass(const Eigen::Vector3f& segment_extents, double model_diameter) {
  return segment_extents.x() <= model_diameter * (1.0 + kFitToleranceRel) + kFitToleranceAbs;
}

Result<std::unique_ptr<ClassModel>> BuildClassModel(const PartSpec& part, const CameraFigures& camera,
                                                    const PoseEstimatorOptions& reference) {
  Result<TriangleMesh> mesh = LoadMesh(part.mesh);
  if (!mesh.ok()) return mesh.status();
  const PartGeometry geometry = MeasureMesh(*mesh);
  if (Status s = CheckMeshScale(geometry, MeshUnitHint(part.mesh), part.mesh); !s.ok()) {
    return Status::InvalidArgument("part '" + part.name + "': " + s.message());
  }
  const PoseEstimatorOptions options = ScaledEstimatorOptions(geometry, camera, part.perception, reference);
  auto estimator = PoseEstimator::Build(*mesh, part.symmetry, options);
  if (!estimator.ok()) {
    return Status::InvalidArgument("part '" + part.name + "': " + estimator.status().ToString());
  }
  // The planar share samples: at most as many as the estimator's dense ones.
  const double spacing = std::max(kPlanarShareSampleSpacing, options.icp_model_spacing);
  const OrientedPoints samples = SampleSurface(*mesh, spacing, /*seed=*/1);
  const std::pair<float, float> share = ModelPlanarShareRange(samples.normals, kPlanarShareDirections);
  return std::unique_ptr<ClassModel>(
      std::make_unique<PpfClassModel>(part.class_id, std::move(*estimator), share));
}

}  // namespace bp::internal
