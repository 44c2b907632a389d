#include "pipeline/internal/resting_poses.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <optional>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include "pipeline/internal/model_geometry.h"
#include "pipeline/internal/pose_model.h"

namespace bp::internal {

namespace {

constexpr double kDeg = M_PI / 180.0;
// Resting-pose seeds: height band of the top that centres them (metres);
// upward faces are within kTiltedFaceDeg of the floor's normal; a view whose
// upward faces tilt more than kMinSeedTiltDeg also gets tilted seeds.
constexpr float kRestTopBand = 0.003f;
constexpr double kTiltedFaceDeg = 20.0;
constexpr double kMinSeedTiltDeg = 2.0;

}  // namespace

std::vector<RestingPose> RestingPoses(const TriangleMesh& mesh, std::span<const Eigen::Vector3f> pts,
                                      const Eigen::Vector3f& centroid, const Symmetry& symmetry, float tol) {
  // Face normals merged within 1 deg, with their total area, largest first:
  // where directions within 3 deg are one below, the broad face's own normal
  // stands for them, not a facet of a hole wall 2.9 deg off it (which tilted
  // an L-bracket lying on its side by 3 deg).
  std::vector<std::pair<float, Eigen::Vector3f>> by_area;
  const float cos1 = static_cast<float>(std::cos(1 * kDeg));
  for (const Eigen::Vector3i& t : mesh.triangles) {
    const Eigen::Vector3f c = (mesh.vertices[t[1]] - mesh.vertices[t[0]]).cross(mesh.vertices[t[2]] - mesh.vertices[t[0]]);
    if (!(c.norm() > 1e-12f)) continue;
    const Eigen::Vector3f n = c.normalized();
    auto same = std::find_if(by_area.begin(), by_area.end(), [&](const auto& e) { return e.second.dot(n) > cos1; });
    if (same == by_area.end()) {
      by_area.emplace_back(0.5f * c.norm(), n);
    } else {
      same->first += 0.5f * c.norm();
    }
  }
  std::stable_sort(by_area.begin(), by_area.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
  std::vector<Eigen::Vector3f> candidates;
  for (const auto& [area, n] : by_area) candidates.push_back(n);
  const Eigen::Vector3f axis = symmetry.axis.cast<float>().normalized();
  auto same_rest = [&](const Eigen::Vector3f& a, const Eigen::Vector3f& b) {
    const float cos3 = static_cast<float>(std::cos(3 * kDeg));
    if (a.dot(b) > cos3) return true;
    switch (symmetry.kind) {
      case Symmetry::Kind::kRevolute:
        return std::abs(a.dot(axis) - b.dot(axis)) < 0.05f;
      case Symmetry::Kind::kDiscrete:
        for (int k = 1; k < symmetry.order; ++k) {
          const Eigen::AngleAxisf r(static_cast<float>(2 * M_PI * k / symmetry.order), axis);
          if ((r * a).dot(b) > cos3) return true;
        }
        return false;
      default:
        return false;
    }
  };
  std::vector<RestingPose> rests;
  for (const Eigen::Vector3f& d : candidates) {
    if (std::any_of(rests.begin(), rests.end(), [&](const RestingPose& r) { return same_rest(r.down, d); })) continue;
    float depth = -std::numeric_limits<float>::infinity();
    for (const auto& p : pts) depth = std::max(depth, d.dot(p));
    const auto [u, v] = PlaneBasis(d);
    std::vector<Eigen::Vector2f> contact;
    for (const auto& p : pts) {
      if (d.dot(p) >= depth - tol) contact.emplace_back(u.dot(p), v.dot(p));
    }
    const std::vector<Eigen::Vector2f> hull = ConvexHull2(std::move(contact));
    if (hull.size() < 3) continue;
    const Eigen::Vector2f c(u.dot(centroid), v.dot(centroid));
    bool inside = true;
    for (size_t i = 0; i < hull.size() && inside; ++i) {
      const Eigen::Vector2f& a = hull[i];
      const Eigen::Vector2f& b = hull[(i + 1) % hull.size()];
      inside = (b - a).x() * (c - a).y() - (b - a).y() * (c - a).x() >= 0;
    }
    if (inside) rests.push_back({d, depth});
  }
  return rests;
}

void AnchorRestingPoses(const OrientedPoints& samples, std::vector<RestingPose>& rests) {
  const float cos_face = static_cast<float>(std::cos(kTiltedFaceDeg * kDeg));
  for (RestingPose& rest : rests) {
    // Top: samples within kRestTopBand of the highest (heights along -down).
    // Upward faces: normals within kTiltedFaceDeg of -down.
    const OrientedPoints& s = samples;
    float highest = std::numeric_limits<float>::infinity();
    for (const auto& p : s.points) highest = std::min(highest, rest.down.dot(p));
    int top = 0, up = 0;
    for (size_t i = 0; i < s.size(); ++i) {
      if (rest.down.dot(s.points[i]) <= highest + kRestTopBand) {
        rest.top_O += s.points[i];
        ++top;
      }
      if (-s.normals[i].dot(rest.down) > cos_face) {
        rest.up_O += s.points[i];
        ++up;
      }
    }
    rest.top_O /= static_cast<float>(std::max(1, top));
    rest.up_O /= static_cast<float>(std::max(1, up));
  }
}

double LowestUpwardFace(const OrientedPoints& samples, const std::vector<RestingPose>& rests, float min_up) {
  double lowest = std::numeric_limits<double>::infinity();
  for (const RestingPose& rest : rests) {
    float contact = -std::numeric_limits<float>::infinity();
    for (const Eigen::Vector3f& p : samples.points) contact = std::max(contact, rest.down.dot(p));
    for (size_t i = 0; i < samples.size(); ++i) {
      if (-samples.normals[i].dot(rest.down) < min_up) continue;
      lowest = std::min(lowest, static_cast<double>(contact - rest.down.dot(samples.points[i])));
    }
  }
  return lowest;
}

void AppendRestingSeeds(const PoseModel& m, std::span<const Eigen::Vector3f> scene,
                        std::span<const Eigen::Vector3f> sub_p, std::span<const Eigen::Vector3f> sub_n,
                        const Eigen::Vector4d& plane, std::vector<CoarsePose>& coarse) {
  const Eigen::Vector3f n = plane.head<3>().cast<float>();
  const float d = static_cast<float>(plane[3]);
  const auto [u, v] = PlaneBasis(n);
  // The segment above the floor, in plane coordinates: its centre and its
  // principal direction (angle in the (u, v) plane).
  auto principal_angle = [](const std::vector<Eigen::Vector2f>& q, Eigen::Vector2f& mean) {
    mean.setZero();
    for (const auto& p : q) mean += p;
    mean /= static_cast<float>(q.size());
    Eigen::Matrix2f C = Eigen::Matrix2f::Zero();
    for (const auto& p : q) C += (p - mean) * (p - mean).transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix2f> es(C);
    const Eigen::Vector2f e = es.eigenvectors().col(1);
    return std::atan2(e.y(), e.x());
  };
  std::vector<Eigen::Vector2f> seg;
  std::vector<float> heights;
  for (const auto& p : scene) {
    const float h = n.dot(p) + d;
    if (h > 0.5f * m.step) {
      seg.emplace_back(u.dot(p), v.dot(p));
      heights.push_back(h);
    }
  }
  if (seg.size() < 3) return;
  Eigen::Vector2f seg_mean;
  const float seg_angle = principal_angle(seg, seg_mean);
  // The seeds are centred on the segment's top: its points within
  // kRestTopBand of its top height (the 97th percentile, past outliers) are
  // laid over the part's samples within kRestTopBand of its top. The top is
  // what the camera sees whole; the segment's centre moves with the side
  // faces an off-centre camera also sees.
  std::vector<float> sorted = heights;
  const size_t q = std::min(sorted.size() - 1, static_cast<size_t>(0.97 * static_cast<double>(sorted.size())));
  std::nth_element(sorted.begin(), sorted.begin() + static_cast<std::ptrdiff_t>(q), sorted.end());
  const float seg_top = sorted[q];
  Eigen::Vector2f top_mean = Eigen::Vector2f::Zero();
  int top_count = 0;
  for (size_t i = 0; i < seg.size(); ++i) {
    if (heights[i] >= seg_top - kRestTopBand && heights[i] <= seg_top + kRestTopBand) {
      top_mean += seg[i];
      ++top_count;
    }
  }
  top_mean /= static_cast<float>(std::max(1, top_count));
  const Eigen::Vector3f top_in_plane = u * top_mean.x() + v * top_mean.y();
  // A part leaning on a neighbour or a wall rests a few degrees off the floor
  // (3-9 deg in cleared piles), which ICP from a flat seed does not recover
  // on thin edges. The mean
  // normal of the segment's upward faces (within kTiltedFaceDeg of the floor
  // normal) gives the tilt; above kMinSeedTiltDeg, every seed gets a tilted
  // copy whose upward faces' centroid sits on the segment's.
  Eigen::Vector3f up_normal = Eigen::Vector3f::Zero();
  const float cos_face = static_cast<float>(std::cos(kTiltedFaceDeg * kDeg));
  for (const auto& nn : sub_n) {
    if (nn.dot(n) > cos_face) up_normal += nn;
  }
  std::optional<Eigen::Matrix3f> R_tilt;
  Eigen::Vector3f up_centroid = Eigen::Vector3f::Zero();
  if (up_normal.norm() > 0) {
    up_normal.normalize();
    if (up_normal.dot(n) < static_cast<float>(std::cos(kMinSeedTiltDeg * kDeg))) {
      int count = 0;
      for (size_t i = 0; i < sub_p.size(); ++i) {
        if (sub_n[i].dot(up_normal) > cos_face) {
          up_centroid += sub_p[i];
          ++count;
        }
      }
      if (count >= 3) {
        up_centroid /= static_cast<float>(count);
        R_tilt = Eigen::Quaternionf::FromTwoVectors(n, up_normal).toRotationMatrix();
      }
    }
  }
  for (const RestingPose& rest : m.rests) {
    // R0 turns the resting direction onto -n.
    const Eigen::Matrix3f R0 = Eigen::Quaternionf::FromTwoVectors(rest.down, -n).toRotationMatrix();
    std::vector<Eigen::Vector2f> top;
    top.reserve(m.ppf_points.size());
    for (const auto& p : m.ppf_points.points) {
      const Eigen::Vector3f q = R0 * p;
      top.emplace_back(u.dot(q), v.dot(q));
    }
    Eigen::Vector2f model_mean;
    const float model_angle = principal_angle(top, model_mean);
    std::vector<float> yaws = {seg_angle - model_angle, seg_angle - model_angle + static_cast<float>(M_PI)};
    const bool spins_freely = m.symmetry.kind == Symmetry::Kind::kRevolute &&
                              std::abs(rest.down.dot(m.symmetry.axis.cast<float>().normalized())) > 0.999f;
    if (!spins_freely) {
      for (int k = 0; k < 36; ++k) yaws.push_back(static_cast<float>(k * 10 * kDeg));
    } else {
      yaws.resize(1);
    }
    for (const float yaw : yaws) {
      const Eigen::Matrix3f R = Eigen::AngleAxisf(yaw, n).toRotationMatrix() * R0;
      const Eigen::Vector3f c = R * rest.top_O;
      // In the plane: the part's top over the segment's. Along n: the
      // lowest samples (n . R p = -rest.depth) on the plane.
      const Eigen::Vector3f t = top_in_plane - (c - n * n.dot(c)) + n * (rest.depth - d);
      CoarsePose cp;
      cp.X_BO = Pose::Identity();
      cp.X_BO.linear() = R.cast<double>();
      cp.X_BO.translation() = t.cast<double>();
      coarse.push_back(cp);
      if (R_tilt) {
        const Eigen::Matrix3f Rt = *R_tilt * R;
        cp.X_BO.linear() = Rt.cast<double>();
        cp.X_BO.translation() = (up_centroid - Rt * rest.up_O).cast<double>();
        coarse.push_back(cp);
      }
    }
  }
}


}  // namespace bp::internal
