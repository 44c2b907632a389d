#include "pipeline/internal/point_to_plane_icp.h"

#include <algorithm>
#include <cmath>
#include <vector>

#include <Eigen/Cholesky>
#include <Eigen/Geometry>

namespace bp::internal {

IcpResult RefinePointToPlane(const IcpModel& model, std::span<const Eigen::Vector3f> scene_B, const Pose& X_BO_init,
                             const Vec3& camera_B, const IcpOptions& options) {
  IcpResult result;
  result.X_BO = X_BO_init;
  Pose X_OB = X_BO_init.inverse();
  const int iters = std::max(1, options.iterations);
  const int shrink_iters =
      options.shrink_iterations > 0 ? std::min(options.shrink_iterations, iters) : std::clamp(iters / 3, 1, 6);
  bool any_ok = false;
  std::vector<Eigen::Vector3f> query(scene_B.size());  // scene points in O, this iteration
  std::vector<int> nearest(scene_B.size());            // their closest sample, -1 for none
  for (int it = 0; it < iters; ++it) {
    const float t = std::min(1.f, static_cast<float>(it) / static_cast<float>(shrink_iters));
    const float gate = options.initial_distance * std::pow(options.final_distance / options.initial_distance, t);
    const float gate2 = gate * gate;
    const Eigen::Matrix3f R = X_OB.linear().cast<float>();
    const Eigen::Vector3f tr = X_OB.translation().cast<float>();
    const Eigen::Vector3f c_O = (X_OB * camera_B).cast<float>();
    // Float accumulation (a few thousand terms of similar size); solved in double.
    Eigen::Matrix<float, 6, 6> Hf = Eigen::Matrix<float, 6, 6>::Zero();
    Eigen::Matrix<float, 6, 6> Hb = Eigen::Matrix<float, 6, 6>::Zero();  // the boundary terms alone
    int boundary_count = 0;
    Eigen::Matrix<float, 6, 1> gf = Eigen::Matrix<float, 6, 1>::Zero();
    double sum_r2 = 0;
    int count = 0;
    const bool use_boundary = options.boundary.size() == scene_B.size() && options.boundary_weight > 0.f &&
                              model.edge_planes_O.size() == model.points_O.size();
    const float wb = options.boundary_weight;
    // Closest samples first, in a loop of their own: the field and sample
    // reads are cache misses, and a short loop body lets many of them be in
    // flight at once (with the accumulation below in the same loop only a
    // few were). The normals and edge planes the accumulation reads are
    // prefetched here too.
    for (size_t k = 0; k < scene_B.size(); ++k) {
      const Eigen::Vector3f q = R * scene_B[k] + tr;
      // The voxel's own sample while the gate shrinks; the best of the 8
      // surrounding voxels' samples once it is final (sub-voxel accuracy).
      const int idx = t >= 1.f ? model.field->Nearest(q, model.points_O) : model.field->Lookup(q);
      query[k] = q;
      nearest[k] = idx;
      if (idx >= 0) {
        __builtin_prefetch(model.normals_O.data() + idx);
        if (use_boundary) __builtin_prefetch(model.edge_planes_O.data() + idx);
      }
    }
    for (size_t k = 0; k < scene_B.size(); ++k) {
      const Eigen::Vector3f& q = query[k];
      const int idx = nearest[k];
      if (idx < 0) continue;
      const Eigen::Vector3f& m = model.points_O[idx];
      const Eigen::Vector3f& n = model.normals_O[idx];
      const Eigen::Vector3f d = q - m;
      if (d.squaredNorm() > gate2) continue;
      const bool facing = n.dot(c_O - m) > 0.f;  // back faces cannot be seen
      if (facing) {
        const float r = n.dot(d);
        Eigen::Matrix<float, 6, 1> J;
        J.head<3>() = q.cross(n);
        J.tail<3>() = n;
        Hf.noalias() += J * J.transpose();
        gf += J * r;
        sum_r2 += static_cast<double>(r) * r;
        ++count;
      }
      if (use_boundary && options.boundary[k] && model.edge_planes_O[idx].valid()) {
        const EdgePlane& e = model.edge_planes_O[idx];
        float s = e.n.dot(q) - e.c;
        Eigen::Vector3f nn = e.n;
        if (!facing && n.dot(d) > s) {
          s = n.dot(d);
          nn = n;
        }
        if (s > 0.f) {
          Eigen::Matrix<float, 6, 1> J;
          J.head<3>() = q.cross(nn);
          J.tail<3>() = nn;
          Hb.noalias() += wb * (J * J.transpose());
          gf += (wb * s) * J;
          ++boundary_count;
        }
      }
    }
    if (count < options.min_correspondences) break;
    any_ok = true;
    result.rms = std::sqrt(sum_r2 / count);
    result.inliers = count;
    result.iterations = it + 1;
    const Eigen::Matrix<double, 6, 6> Hp = Hf.cast<double>(), Hs = Hb.cast<double>();
    Eigen::Matrix<double, 6, 6> H = Hp + Hs;
    const Eigen::Matrix<double, 6, 1> g = gf.cast<double>();
    // Light Levenberg damping keeps directions the data does not constrain
    // (e.g. the axis of a revolute part) where they are.
    H.diagonal().array() += 1e-9 * (1.0 + H.diagonal().maxCoeff());
    const Eigen::Matrix<double, 6, 1> x = H.ldlt().solve(-g);
    if (!x.allFinite()) break;
    const Eigen::Vector3d w = x.head<3>();
    const double angle = w.norm();
    Pose delta = Pose::Identity();
    if (angle > 0) delta.linear() = Eigen::AngleAxisd(angle, w / angle).toRotationMatrix();
    delta.translation() = x.tail<3>();
    X_OB = delta * X_OB;
    // Converged once the step changes the point-to-plane residuals and the
    // boundary residuals each by less than options.convergence (RMS, from
    // x' H x): a twist in a direction the data leaves free (a revolute part's
    // axis) moves no residual and does not count; a slide only the
    // silhouette sees moves the boundary residuals.
    const double change = std::sqrt(std::max(0.0, x.dot(Hp * x)) / count);
    const double boundary_change =
        boundary_count > 0 ? std::sqrt(std::max(0.0, x.dot(Hs * x)) / boundary_count) : 0.0;
    if (change < options.convergence && boundary_change < options.convergence && t >= 1.f) break;
  }
  if (any_ok) {
    Pose X_BO = X_OB.inverse();
    // Re-orthonormalise against drift.
    X_BO.linear() = Eigen::Quaterniond(X_BO.linear()).normalized().toRotationMatrix();
    if (X_BO.matrix().allFinite()) {
      result.X_BO = X_BO;
      result.ok = true;
    }
  }
  return result;
}

}  // namespace bp::internal
