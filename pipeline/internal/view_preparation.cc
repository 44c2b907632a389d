#include "pipeline/internal/view_preparation.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <span>

#include <Eigen/Eigenvalues>

#include "pipeline/internal/pose_model.h"

namespace bp::internal {

namespace {

using Clock = std::chrono::steady_clock;
double Ms(Clock::time_point a, Clock::time_point b) {
  return std::chrono::duration<double, std::milli>(b - a).count();
}

constexpr int kMinScenePoints = 30;
constexpr int kMinSampledPoints = 8;
// A view is planar when its points' RMS distance from their plane is below
// this, metres (depth noise on the default cell: ~0.45 mm).
constexpr double kPlanarViewRms = 0.0010;
// The share test (ViewBase::OnMostlyOnePlane, PoseEstimatorOptions::
// planar_view_min_share): points within kPlaneBand of the plane are on it (metres: the estimator's 1.5 mm
// support distance); the trimmed fit keeps, kPlaneTrims times, the points
// within the larger of kPlaneBand and kPlaneTrimSigmas x the RMS distance
// of the points it kept before, and fits again.
constexpr double kPlaneBand = 0.0015;
constexpr int kPlaneTrims = 4;
constexpr double kPlaneTrimSigmas = 2.0;

// Degenerate geometry: spread along fewer than two directions, or much
// smaller than the part (the reason; empty when the view can be searched).
std::string CheckShape(const PoseModel& m, const ViewBase& base) {
  const double min_spread = 0.05 * m.step;
  if (base.spread()[1] < min_spread) return "degenerate segment: points are (nearly) collinear";
  if (base.spread()[2] < 0.05 * m.diameter) return "segment is much smaller than the part";
  return {};
}

// Voxel subsampling at the PPF distance step: per voxel the points' centroid
// and a normal towards the camera (the view's normals averaged, or PCA over
// the full-resolution neighbours within a step when the view has none).
// @returns per finite point the index of its voxel's subsampled point, -1
// if the voxel has no normal.
std::vector<int> Subsample(const PoseModel& m, const SceneView& view, PreparedView* w) {
  const std::vector<Eigen::Vector3f>& pts = w->pts();
  const std::vector<int>& index = w->index();
  PointHash hash;  // normal estimation: radius step visits 2 x 2 x 2 cells
  if (view.normals_B.empty()) hash.Build(pts, 2.f * m.step);
  const Eigen::Vector3f cam = view.X_BC.translation().cast<float>();
  std::vector<Eigen::Vector3f>& sub_p = w->sub_p;
  std::vector<Eigen::Vector3f>& sub_n = w->sub_n;
  std::vector<int> sub_of(pts.size(), -1);
  {
    // The points per voxel of the PPF step, voxels in key order, points in index order.
    PointHash voxels;
    voxels.Build(pts, m.step);
    const std::span<const uint32_t> order = voxels.order();
    for (const auto& [k, e] : voxels.CellRunsByKey()) {
      Eigen::Vector3f sum = Eigen::Vector3f::Zero();
      Eigen::Vector3f nsum = Eigen::Vector3f::Zero();
      for (uint32_t j = k; j < e; ++j) {
        const uint32_t i = order[j];
        sum += pts[i];
        if (!view.normals_B.empty()) {
          Eigen::Vector3f n = view.normals_B[index[i]];
          if (n.allFinite()) nsum += (n.dot(cam - pts[i]) < 0 ? -n : n);
        }
      }
      const Eigen::Vector3f centre = sum / static_cast<float>(e - k);
      Eigen::Vector3f normal;
      if (!view.normals_B.empty()) {
        if (nsum.norm() < 1e-6f) continue;
        normal = nsum.normalized();
      } else {
        // PCA over full-resolution neighbours within one step.
        Eigen::Vector3d mean = Eigen::Vector3d::Zero();
        Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
        int n = 0;
        hash.ForEachWithin(centre, m.step, [&](int j, float) {
          const Eigen::Vector3d p = pts[j].cast<double>();
          mean += p;
          S += p * p.transpose();
          ++n;
        });
        if (n < 5) continue;
        mean /= n;
        S = S / n - mean * mean.transpose();
        Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(S);
        if (es.info() != Eigen::Success) continue;
        // Flat enough to carry a normal: smallest eigenvalue well below the middle one.
        if (!(es.eigenvalues()[1] > 0) || es.eigenvalues()[0] > 0.5 * es.eigenvalues()[1]) continue;
        normal = es.eigenvectors().col(0).cast<float>();
        if (normal.dot(cam - centre) < 0) normal = -normal;
      }
      if (!normal.allFinite() || !centre.allFinite()) continue;
      for (uint32_t j = k; j < e; ++j) sub_of[order[j]] = static_cast<int>(sub_p.size());
      sub_p.push_back(centre);
      sub_n.push_back(normal);
    }
  }
  return sub_of;
}

// The support structures (segment depth without a depth image, the support
// hash), the subsampled points' boundary flags, and the fine ICP points:
// every boundary point (they carry the in-plane constraints) plus the rest
// strided to about icp_max_points in all. A full-resolution point takes its
// voxel's boundary flag (the ICP boundary term is one-sided, so flagging a
// few millimetres of interior next to an edge costs nothing).
void PrepareSupport(const PoseModel& m, const SceneView& view, const std::vector<int>& sub_of, PreparedView* w) {
  const PoseEstimatorOptions& opt = m.options;
  const std::vector<Eigen::Vector3f>& pts = w->pts();
  const Eigen::Vector3f cam = view.X_BC.translation().cast<float>();
  const bool have_depth = view.depth != nullptr && !view.depth->empty() && view.intrinsics.valid();
  if (!have_depth) w->segment_depth = BuildSegmentDepth(pts, cam, 1.5f * static_cast<float>(opt.verify_model_spacing));
  // Support queries (radius support_distance) visit 2 x 2 x 2 cells of this.
  const float cell = 2.f * static_cast<float>(opt.support_distance);
  if (const SceneSupport* shared = w->base->Support(cell, view)) {
    w->support = std::shared_ptr<const SceneSupport>(w->base, shared);  // keeps the base alive
  } else {
    auto own = std::make_shared<SceneSupport>();
    own->Build(pts, cell, view);
    w->support = std::move(own);
  }
  PointHash sub_hash;
  sub_hash.Build(w->sub_p, 4.f * m.step);
  std::vector<uint8_t>& sub_boundary = w->sub_boundary;
  sub_boundary = BoundaryFlags(w->sub_p, w->sub_p, sub_hash, 2.f * m.step);
  std::vector<Eigen::Vector3f>& fine = w->fine;
  std::vector<uint8_t>& fine_boundary = w->fine_boundary;
  size_t n_boundary = 0;
  for (size_t i = 0; i < pts.size(); ++i) n_boundary += sub_of[i] < 0 || sub_boundary[sub_of[i]];
  const size_t budget = std::max<size_t>(static_cast<size_t>(opt.icp_max_points), n_boundary + 1) - n_boundary;
  const size_t interior = pts.size() - n_boundary;
  const size_t stride = std::max<size_t>(1, (interior + budget - 1) / budget);
  size_t seen = 0;
  for (size_t i = 0; i < pts.size(); ++i) {
    const bool b = sub_of[i] < 0 || sub_boundary[sub_of[i]];
    if (b || (seen++ % stride) == 0) {
      fine.push_back(pts[i]);
      fine_boundary.push_back(b ? 1 : 0);
    }
  }
}

}  // namespace

bool FitPlane(std::span<const Eigen::Vector3f> pts, std::span<const uint8_t> keep, Eigen::Vector3d* c,
              Eigen::Vector3d* n, double* rms) {
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  size_t count = 0;
  for (size_t i = 0; i < pts.size(); ++i) {
    if (keep.empty() || keep[i]) {
      mean += pts[i].cast<double>();
      ++count;
    }
  }
  if (count < 3) return false;
  mean /= static_cast<double>(count);
  Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
  for (size_t i = 0; i < pts.size(); ++i) {
    if (keep.empty() || keep[i]) {
      const Eigen::Vector3d d = pts[i].cast<double>() - mean;
      C += d * d.transpose();
    }
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C / static_cast<double>(count));
  *c = mean;
  *n = es.eigenvectors().col(0);
  *rms = std::sqrt(std::max(0.0, es.eigenvalues()[0]));
  return true;
}

std::array<double, 4> Fingerprint(std::span<const Eigen::Vector3f> points) {
  std::array<double, 4> f{static_cast<double>(points.size()), 0.0, 0.0, 0.0};
  for (const Eigen::Vector3f& p : points) {
    if (!p.allFinite()) continue;
    f[1] += p.x();
    f[2] += p.y();
    f[3] += p.z();
  }
  return f;
}

ViewBase::ViewBase(const SceneView& view)
    : view_points_(view.points_B.size()), camera_(view.X_BC.translation().cast<float>()) {
  pts_.reserve(view.points_B.size());
  index_.reserve(view.points_B.size());
  for (size_t i = 0; i < view.points_B.size(); ++i) {
    if (view.points_B[i].allFinite()) {
      pts_.push_back(view.points_B[i]);
      index_.push_back(static_cast<int>(i));
    }
  }
  if (pts_.size() < 2) return;
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& p : pts_) mean += p.cast<double>();
  mean /= static_cast<double>(pts_.size());
  Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
  for (const auto& p : pts_) {
    const Eigen::Vector3d d = p.cast<double>() - mean;
    C += d * d.transpose();
  }
  C /= static_cast<double>(pts_.size());
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C);
  const Eigen::Vector3d ev = es.eigenvalues().cwiseMax(0.0);  // ascending
  spread_ = ev.cwiseSqrt();
  if (spread_[0] < kPlanarViewRms) {
    Eigen::Vector3f n = es.eigenvectors().col(0).cast<float>();
    if (n.dot(view.X_BC.translation().cast<float>() - mean.cast<float>()) < 0) n = -n;
    view_plane_ = n;
  }
}

const ViewBase::MostlyPlanar& ViewBase::OnMostlyOnePlane() const {
  std::call_once(plane_once_, [&] {
    Eigen::Vector3d c, n;
    double rms = 0.0;
    std::vector<uint8_t> keep;
    if (!FitPlane(pts_, keep, &c, &n, &rms)) return;
    keep.assign(pts_.size(), 0);
    for (int t = 0; t < kPlaneTrims; ++t) {
      const double band = std::max(kPlaneBand, kPlaneTrimSigmas * rms);
      for (size_t i = 0; i < pts_.size(); ++i) keep[i] = std::abs(n.dot(pts_[i].cast<double>() - c)) <= band ? 1 : 0;
      if (!FitPlane(pts_, keep, &c, &n, &rms)) return;
    }
    for (const Eigen::Vector3f& p : pts_) {
      if (std::abs(n.dot(p.cast<double>() - c)) <= kPlaneBand) plane_.pts.push_back(p);
    }
    Eigen::Vector3f nf = n.cast<float>();
    if (nf.dot(camera_ - c.cast<float>()) < 0) nf = -nf;
    plane_.normal = nf;
    plane_.share = static_cast<double>(plane_.pts.size()) / static_cast<double>(pts_.size());
  });
  return plane_;
}

const SceneSupport* ViewBase::Support(float cell, const SceneView& view) const {
  std::call_once(support_once_, [&] {
    support_cell_ = cell;
    support_.Build(pts_, cell, view);
  });
  return support_cell_ == cell ? &support_ : nullptr;
}

std::vector<uint8_t> BoundaryFlags(std::span<const Eigen::Vector3f> queries, std::span<const Eigen::Vector3f> hashed,
                                   const PointHash& hash, float radius) {
  std::vector<uint8_t> flags(queries.size(), 0);
  for (size_t i = 0; i < queries.size(); ++i) {
    Eigen::Vector3f sum = Eigen::Vector3f::Zero();
    int n = 0;
    hash.ForEachWithin(queries[i], radius, [&](int j, float) {
      sum += hashed[j];
      ++n;
    });
    flags[i] = (n < 4 || (sum / static_cast<float>(n) - queries[i]).norm() > 0.25f * radius) ? 1 : 0;
  }
  return flags;
}

Preparation PrepareView(const PoseModel& m, const SceneView& view, std::shared_ptr<const ViewBase> base,
                        PreparedView* w) {
  Preparation out;
  w->model_id = m.id;
  const auto t0 = Clock::now();
  w->base = base ? std::move(base) : std::make_shared<const ViewBase>(view);
  out.scene_points = static_cast<int>(w->pts().size());
  if (static_cast<int>(w->pts().size()) < kMinScenePoints) {
    out.reason = "too few finite points in the segment (" + std::to_string(w->pts().size()) + ", need " +
                 std::to_string(kMinScenePoints) + ")";
    return out;
  }
  out.reason = CheckShape(m, *w->base);
  if (!out.reason.empty()) return out;
  const std::vector<int> sub_of = Subsample(m, view, w);
  out.sampled_points = static_cast<int>(w->sub_p.size());
  out.ms = Ms(t0, Clock::now());
  if (static_cast<int>(w->sub_p.size()) < kMinSampledPoints) {
    out.reason = "too few subsampled points with a normal (" + std::to_string(w->sub_p.size()) + ")";
    return out;
  }
  const auto t_aux = Clock::now();
  PrepareSupport(m, view, sub_of, w);
  out.ms += Ms(t_aux, Clock::now());
  out.ok = true;
  return out;
}

}  // namespace bp::internal
