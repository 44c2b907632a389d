#include "pipeline/pose_estimator.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <string>
#include <tuple>

#include "pipeline/internal/model_geometry.h"
#include "pipeline/internal/model_sampling.h"
#include "pipeline/internal/near_symmetries.h"
#include "pipeline/internal/planar_faces.h"
#include "pipeline/internal/pose_model.h"
#include "pipeline/internal/pose_search.h"
#include "pipeline/internal/resting_poses.h"
#include "pipeline/internal/verification.h"
#include "pipeline/internal/view_preparation.h"

namespace bp {

namespace {

using internal::OrientedPoints;
using internal::PoseModel;

constexpr uint64_t kSamplingSeed = 0x5eed;
// PoseModel::lowest_upward_face: faces within 18 deg of up, as the
// segmentation's floor band (SegmentationOptions::floor_min_normal_z).
constexpr float kUpwardFaceMinCos = 0.95f;
// Caps of what one part's model may take: dense samples (24 bytes each) and
// closest-point field voxels (8 bytes each while it is built). A mesh past them is far
// larger than a part or in the wrong unit.
constexpr double kMaxDenseSamples = 2e6;
constexpr double kMaxFieldVoxels = 32e6;

// PoseModel::id: one per built model, never reused in the process.
uint64_t NextModelId() {
  static std::atomic<uint64_t> next{1};
  return next.fetch_add(1, std::memory_order_relaxed);
}

// Build, step 1: the dense samples (ICP targets), the diameter, the PPF step
// and the centroid.
Status SampleModel(const TriangleMesh& mesh, PoseModel& m) {
  const PoseEstimatorOptions& options = m.options;
  const double samples = internal::SurfaceArea(mesh) / (options.icp_model_spacing * options.icp_model_spacing);
  if (!(samples <= kMaxDenseSamples)) {
    return Status::InvalidArgument("pose estimator: the mesh's surface would take " + std::to_string(samples) +
                                   " samples at " + std::to_string(options.icp_model_spacing) + " m (at most " +
                                   std::to_string(static_cast<int64_t>(kMaxDenseSamples)) +
                                   "): the mesh is far larger than a part, or not in metres");
  }
  Eigen::AlignedBox3f box;
  for (const Eigen::Vector3f& v : mesh.vertices) box.extend(v);
  const double voxel = std::max(0.001, options.icp_model_spacing);
  const double band = std::max(options.icp_initial_relative_distance * options.ppf_relative_sampling *
                                   static_cast<double>(box.diagonal().norm()),
                               2 * options.icp_final_distance);
  const Eigen::Vector3d cells = ((box.sizes().cast<double>().array() + 2 * (band + voxel)) / voxel).matrix();
  if (!(cells.prod() <= kMaxFieldVoxels)) {
    return Status::InvalidArgument("pose estimator: the closest-point field over the mesh's box would take " +
                                   std::to_string(cells.prod()) + " voxels (at most " +
                                   std::to_string(static_cast<int64_t>(kMaxFieldVoxels)) + "): not in metres?");
  }
  m.dense = internal::SampleSurface(mesh, options.icp_model_spacing, kSamplingSeed);
  if (m.dense.size() < 100) {
    return Status::InvalidArgument("pose estimator: mesh has (almost) no surface area at spacing " +
                                   std::to_string(options.icp_model_spacing) + " m");
  }
  m.diameter = internal::PointSetDiameter(m.dense.points);
  if (!(m.diameter > 0) || !std::isfinite(m.diameter)) {
    return Status::InvalidArgument("pose estimator: degenerate mesh (zero or non-finite diameter)");
  }
  m.step = static_cast<float>(options.ppf_relative_sampling * m.diameter);
  for (const auto& p : m.dense.points) m.centroid_O += p;
  m.centroid_O /= static_cast<float>(m.dense.size());
  return Status::Ok();
}

// Build, step 2: resting poses, verification and PPF samples, planar faces
// and their holes, extreme points.
void BuildShapeTables(const TriangleMesh& mesh, PoseModel& m) {
  const PoseEstimatorOptions& options = m.options;
  m.rests = internal::RestingPoses(mesh, m.dense.points, m.centroid_O, m.symmetry,
                                   static_cast<float>(2 * options.icp_model_spacing));
  m.verify = internal::VoxelDownsample(m.dense, options.verify_model_spacing, 45.0);
  m.ppf_points = internal::VoxelDownsample(m.dense, m.step, 30.0);
  m.faces = internal::PlanarFaces(mesh, m.dense, static_cast<float>(options.hole_margin), &m.holes);
  m.thinnest_plate = internal::ThinnestPlate(m.faces);
  m.ppf_extreme = internal::ExtremePoints(m.ppf_points.points);
  m.verify_extreme = internal::ExtremePoints(m.verify.points);
  internal::AnchorRestingPoses(m.ppf_points, m.rests);
  m.lowest_upward_face = internal::LowestUpwardFace(m.dense, m.rests, kUpwardFaceMinCos);
}

// Build, step 3: the ICP structures (they index the dense samples in Morton
// order): the closest-point field, the edge planes; then the holes that lie
// on or next to other parts of the surface (the bore's wall where it meets
// the face's plane) are dropped: they say nothing.
void BuildIcpTables(PoseModel& m) {
  const PoseEstimatorOptions& options = m.options;
  internal::SortByMortonCode(m.dense);
  const float band = std::max(static_cast<float>(options.icp_initial_relative_distance) * m.step,
                              static_cast<float>(2 * options.icp_final_distance));
  m.field.Build(m.dense.points, std::max(0.001f, static_cast<float>(options.icp_model_spacing)), band);
  const float margin = static_cast<float>(options.hole_margin);
  std::erase_if(m.holes, [&](const internal::HolePoint& h) { return m.OnSurface(h.p, margin); });
  m.edge_planes = internal::BuildEdgePlanes(m.dense, options.icp_model_spacing);
}

// Build, step 4: the PPF table over the PPF samples.
Status BuildPpfTable(PoseModel& m) {
  internal::PpfParams params;
  params.distance_step = m.step;
  params.angle_bins = static_cast<int>(std::lround(180.0 / m.options.ppf_angle_step_deg));
  params.alpha_bins = 2 * params.angle_bins;
  params.max_bucket_entries = m.options.ppf_max_bucket_entries;
  if (Status s = m.ppf.Build(m.ppf_points.points, m.ppf_points.normals, params, static_cast<float>(m.diameter * 1.001));
      !s.ok()) {
    return Status::InvalidArgument("pose estimator: " + s.message() + " (ppf_relative_sampling too small?)");
  }
  return Status::Ok();
}

}  // namespace

bool PoseEstimatorOptions::IsValid(std::string* error) const {
  auto fail = [&](const char* what) {
    if (error) *error = what;
    return false;
  };
  if (!(ppf_relative_sampling > 0.005 && ppf_relative_sampling <= 0.2)) return fail("ppf_relative_sampling must be in (0.005, 0.2]");
  if (!(ppf_angle_step_deg >= 3 && ppf_angle_step_deg <= 45)) return fail("ppf_angle_step_deg must be in [3, 45]");
  if (!(icp_model_spacing > 0) || !(verify_model_spacing > 0)) return fail("model spacings must be > 0");
  if (!(reference_fraction > 0 && reference_fraction <= 1)) return fail("reference_fraction must be in (0, 1]");
  if (!(coarse_stop_score >= 0 && coarse_stop_score <= 1)) return fail("coarse_stop_score must be in [0, 1]");
  if (ppf_max_bucket_entries < 1 || ppf_max_partners < 1 || max_reference_points < 1 || max_coarse_poses < 1 || max_hypotheses < 1) return fail("counts must be >= 1");
  if (icp_iterations < 1 || icp_coarse_iterations < 1 || icp_max_points < 100 || icp_shrink_iterations < 1) {
    return fail("icp_iterations, icp_coarse_iterations and icp_shrink_iterations must be >= 1, icp_max_points >= 100");
  }
  if (!(icp_convergence > 0) || !(icp_coarse_convergence > 0)) return fail("icp_convergence and icp_coarse_convergence must be > 0");
  if (!(icp_final_distance > 0) || !(icp_initial_relative_distance > 0)) return fail("icp distances must be > 0");
  if (!(support_distance > 0) || !(free_space_distance > 0)) return fail("support/free-space distances must be > 0");
  if (quick_screen_stride < 1 || !(quick_screen_min_score >= 0 && quick_screen_min_score <= 1)) {
    return fail("quick_screen_stride must be >= 1, quick_screen_min_score in [0, 1]");
  }
  if (!(visible_min_cos >= 0 && visible_min_cos < 1)) return fail("visible_min_cos must be in [0, 1)");
  if (!(near_symmetry_min_overlap >= 0 && near_symmetry_min_overlap <= 1) || max_near_symmetries < 0 ||
      !(near_symmetry_score_slack >= 0 && near_symmetry_score_slack < 1)) {
    return fail("near_symmetry_min_overlap must be in [0, 1], near_symmetry_score_slack in [0, 1), max_near_symmetries >= 0");
  }
  if (!(turn_step_deg >= 0 && turn_step_deg <= 180)) return fail("turn_step_deg must be in [0, 180]");
  if (!(ambiguity_translation > 0) || !(ambiguity_rotation_deg > 0) || !(ambiguity_slack >= 0 && ambiguity_slack < 1) ||
      max_alternatives < 0 || !(ambiguity_net_gain >= 0) || !std::isfinite(ambiguity_net_gain)) {
    return fail("ambiguity_translation and ambiguity_rotation_deg must be > 0, ambiguity_slack in [0, 1), "
                "max_alternatives >= 0, ambiguity_net_gain finite and >= 0");
  }
  if (!(hole_margin > 0) || hole_min_visible < 1 || !(hole_max_filled >= 0)) {
    return fail("hole_margin must be > 0, hole_min_visible >= 1, hole_max_filled >= 0");
  }
  if (!(planar_view_min_share >= 0 && planar_view_min_share <= 1)) {
    return fail("planar_view_min_share must be in [0, 1]");
  }
  return true;
}

struct PoseEstimator::Impl : internal::PoseModel {};

const internal::PoseModel& internal::PoseEstimatorAccess::Model(const PoseEstimator& estimator) {
  return *estimator.impl_;
}

PoseEstimator::PoseEstimator(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
PoseEstimator::~PoseEstimator() = default;

Result<std::unique_ptr<PoseEstimator>> PoseEstimator::Build(const TriangleMesh& mesh, const Symmetry& symmetry,
                                                            const PoseEstimatorOptions& options) {
  std::string error;
  if (!options.IsValid(&error)) return Status::InvalidArgument("PoseEstimatorOptions: " + error);
  if (mesh.empty()) return Status::InvalidArgument("pose estimator: empty mesh");
  if (symmetry.kind != Symmetry::Kind::kNone && !(symmetry.axis.norm() > 1e-9)) {
    return Status::InvalidArgument("pose estimator: symmetry axis is zero");
  }
  auto impl = std::make_unique<Impl>();
  impl->id = NextModelId();
  impl->options = options;
  impl->symmetry = symmetry;
  if (Status s = SampleModel(mesh, *impl); !s.ok()) return s;
  BuildShapeTables(mesh, *impl);
  BuildIcpTables(*impl);
  impl->near_symmetries = internal::FindNearSymmetries(*impl);
  impl->turn_axes = internal::FindTurnAxes(*impl);
  if (Status s = BuildPpfTable(*impl); !s.ok()) return s;
  return std::unique_ptr<PoseEstimator>(new PoseEstimator(std::move(impl)));
}

void PoseEstimator::MarkOnSurface(const Pose& X_BO, std::span<const Eigen::Vector3f> points_B, float tolerance,
                                  std::vector<uint8_t>* on_surface) const {
  const Pose X_OB = X_BO.inverse();
  const Eigen::Matrix3f R = X_OB.linear().cast<float>();
  const Eigen::Vector3f t = X_OB.translation().cast<float>();
  const auto [c_B, r2] = impl_->FieldSphere(X_BO);
  for (size_t i = 0; i < points_B.size() && i < on_surface->size(); ++i) {
    if ((*on_surface)[i] || (points_B[i] - c_B).squaredNorm() > r2) continue;
    const Eigen::Vector3f q = R * points_B[i] + t;
    if (impl_->OnSurface(q, tolerance)) (*on_surface)[i] = 1;
  }
}
size_t PoseEstimator::CountInside(const Pose& X_BO, std::span<const Eigen::Vector3f> points_B,
                                  float min_depth) const {
  const Pose X_OB = X_BO.inverse();
  const Eigen::Matrix3f R = X_OB.linear().cast<float>();
  const Eigen::Vector3f t = X_OB.translation().cast<float>();
  const auto [c_B, r2] = impl_->FieldSphere(X_BO);
  size_t inside = 0;
  for (const Eigen::Vector3f& p : points_B) {
    if ((p - c_B).squaredNorm() > r2) continue;  // no closest sample there
    const Eigen::Vector3f q = R * p + t;
    const int idx = impl_->field.Lookup(q);
    if (idx < 0) continue;
    const size_t i = static_cast<size_t>(idx);
    inside += impl_->dense.normals[i].dot(q - impl_->dense.points[i]) < -min_depth ? 1 : 0;
  }
  return inside;
}
double PoseEstimator::diameter() const { return impl_->diameter; }
double PoseEstimator::sampling_distance() const { return impl_->step; }
int PoseEstimator::model_point_count() const { return static_cast<int>(impl_->ppf_points.size()); }
const std::vector<Eigen::Vector3f>& PoseEstimator::surface_points_O() const { return impl_->verify.points; }
Eigen::Vector3f PoseEstimator::centroid_O() const { return impl_->centroid_O; }
const Symmetry& PoseEstimator::symmetry() const { return impl_->symmetry; }
const std::vector<Pose>& PoseEstimator::near_symmetries() const { return impl_->near_symmetries; }
std::vector<std::pair<Eigen::Vector3f, Eigen::Vector3f>> PoseEstimator::turn_axes() const {
  std::vector<std::pair<Eigen::Vector3f, Eigen::Vector3f>> out;
  for (const internal::TurnAxis& a : impl_->turn_axes) out.emplace_back(a.point, a.direction);
  return out;
}


Result<PoseHypothesis> PoseEstimator::Score(const SceneView& view, const Pose& X_BO) const {
  const internal::PoseModel& m = *impl_;
  if (!X_BO.matrix().allFinite()) return Status::InvalidArgument("Score: X_BO is not finite");
  std::vector<Eigen::Vector3f> pts;
  for (const Eigen::Vector3f& p : view.points_B) {
    if (p.allFinite()) pts.push_back(p);
  }
  internal::SceneSupport support;
  support.Build(pts, 2.f * static_cast<float>(m.options.support_distance), view);
  const bool have_depth = view.depth != nullptr && !view.depth->empty() && view.intrinsics.valid();
  const internal::SegmentDepth segment_depth =
      have_depth || pts.empty()
          ? internal::SegmentDepth{}
          : internal::BuildSegmentDepth(pts, view.X_BC.translation().cast<float>(), 1.5f * static_cast<float>(m.options.verify_model_spacing));
  const internal::VerifyStats st =
      internal::Verify(m, X_BO, view, support, segment_depth, 1, m.options.unmeasured_is_no_evidence);
  PoseHypothesis h;
  h.X_BO = X_BO;
  h.score = st.below_support ? -1.0 : st.score;
  h.visible_points = st.visible;
  h.occluded_points = st.occluded;
  h.supported_points = st.supported;
  h.free_space_points = st.free_space;
  h.unmeasured_points = st.unmeasured;
  std::tie(h.hole_points, h.filled_hole_points) = internal::HoleStats(m, X_BO, view);
  return h;
}

PoseSearch PoseEstimator::default_search() const {
  PoseSearch search;
  search.max_reference_points = impl_->options.max_reference_points;
  search.max_coarse_poses = impl_->options.max_coarse_poses;
  search.stop_score = impl_->options.coarse_stop_score;
  search.unmeasured_is_no_evidence = impl_->options.unmeasured_is_no_evidence;
  search.turns_below_bar = impl_->options.turns_below_bar;
  return search;
}

Result<PoseEstimates> PoseEstimator::Estimate(const SceneView& view) const {
  return Estimate(view, default_search());
}

Result<PoseEstimates> PoseEstimator::Estimate(const SceneView& view, const PoseSearch& search) const {
  return internal::EstimatePose(*impl_, view, search);
}

}  // namespace bp
