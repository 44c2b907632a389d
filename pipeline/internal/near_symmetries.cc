#include "pipeline/internal/near_symmetries.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "pipeline/internal/model_geometry.h"
#include "pipeline/internal/pose_model.h"

namespace bp::internal {

namespace {

constexpr double kDeg = M_PI / 180.0;
// A sample maps onto the surface under a near symmetry when its image lies
// within this of a dense sample whose normal is within kNearSymmetryDeg.
constexpr float kNearSymmetryDistance = 0.001f;
constexpr double kNearSymmetryDeg = 30.0;
// Two transforms of O are one near symmetry (or one is the identity modulo
// the declared symmetry) within this rotation and this fraction of the
// diameter at the centroid.
constexpr double kSameTransformDeg = 10.0;
constexpr double kSameTransformRelative = 0.05;
// Plates: two antiparallel faces at most this fraction of the diameter apart
// whose boxes overlap.
constexpr double kPlateRelativeThickness = 0.2;

// The fraction of the verification samples F maps within
// kNearSymmetryDistance of a dense sample whose normal is within
// kNearSymmetryDeg of the mapped one.
double Overlap(const PoseModel& m, const Pose& F) {
  const float cos_normal = static_cast<float>(std::cos(kNearSymmetryDeg * kDeg));
  const Eigen::Matrix3f R = F.linear().cast<float>();
  const Eigen::Vector3f t = F.translation().cast<float>();
  size_t on = 0;
  for (size_t i = 0; i < m.verify.size(); ++i) {
    const Eigen::Vector3f q = R * m.verify.points[i] + t;
    const int idx = m.field.Nearest(q, m.dense.points);
    if (idx < 0) continue;
    on += (q - m.dense.points[static_cast<size_t>(idx)]).squaredNorm() <= kNearSymmetryDistance * kNearSymmetryDistance &&
          (R * m.verify.normals[i]).dot(m.dense.normals[static_cast<size_t>(idx)]) >= cos_normal;
  }
  return static_cast<double>(on) / static_cast<double>(std::max<size_t>(1, m.verify.size()));
}

// The box centre of a planar face (holes pull its centroid off it).
Eigen::Vector3f BoxCentre(const PlanarFace& f) {
  return f.c + 0.5f * (f.lo.x() + f.hi.x()) * f.u + 0.5f * (f.lo.y() + f.hi.y()) * f.v;
}

// Two turn axes are one line: directions within kSameTransformDeg (either
// sense) and each point within kSameTransformRelative diameters of the
// other's line.
bool SameLine(const TurnAxis& a, const TurnAxis& b, double diameter) {
  if (std::abs(a.direction.dot(b.direction)) < std::cos(kSameTransformDeg * kDeg)) return false;
  const Eigen::Vector3f d = b.point - a.point;
  return (d - d.dot(a.direction) * a.direction).norm() < kSameTransformRelative * diameter;
}

// Arms: two large faces whose normals are near perpendicular and whose
// normal lines through their box centres meet (the ends of a tee's run and
// branch, identical arms about a common junction). The half-turn about the
// bisector of the two outward normals through that point swaps the two
// ends: a tee seen as an L (one arm hidden) fits either way.
void AppendArmSwaps(const PoseModel& m, std::vector<Pose>& candidates) {
  const float meet = static_cast<float>(kSameTransformRelative * m.diameter);
  for (size_t i = 0; i < m.faces.size(); ++i) {
    const PlanarFace& f = m.faces[i];
    if ((f.hi - f.lo).minCoeff() < kMinFaceExtent) continue;
    for (size_t j = i + 1; j < m.faces.size(); ++j) {
      const PlanarFace& g = m.faces[j];
      if ((g.hi - g.lo).minCoeff() < kMinFaceExtent) continue;
      if (std::abs(f.n.dot(g.n)) > std::sin(kSameTransformDeg * kDeg)) continue;
      // The closest points of the two lines a + s f.n, b + t g.n.
      const Eigen::Vector3f a = BoxCentre(f), b = BoxCentre(g), w = a - b;
      const float c = f.n.dot(g.n), den = 1.f - c * c;
      const float s = (c * g.n.dot(w) - f.n.dot(w)) / den, t = (g.n.dot(w) - c * f.n.dot(w)) / den;
      const Eigen::Vector3f pa = a + s * f.n, pb = b + t * g.n;
      // Both ends lie outward of the junction (s, t < 0: the lines meet
      // behind both faces), and the lines meet.
      if (!(s < 0.f && t < 0.f) || (pa - pb).norm() > meet) continue;
      candidates.push_back(HalfTurn((f.n + g.n).normalized(), 0.5f * (pa + pb)));
    }
  }
}

}  // namespace

Pose TurnAxis::Turn(double angle_rad) const {
  const Eigen::Matrix3d R = Eigen::AngleAxisd(angle_rad, direction.cast<double>().normalized()).toRotationMatrix();
  const Eigen::Vector3d c = point.cast<double>();
  return MakePose(R, c - R * c);
}

std::vector<TurnAxis> FindTurnAxes(const PoseModel& m) {
  const double step = m.options.turn_step_deg;
  if (!(step > 0) || m.faces.empty()) return {};
  const int turns = static_cast<int>(std::floor(360.0 / step - 1e-9));
  std::vector<TurnAxis> out;
  for (const PlanarFace& f : m.faces) {
    if ((f.hi - f.lo).minCoeff() < kMinFaceExtent) continue;
    const TurnAxis axis{BoxCentre(f), f.n.normalized()};
    if (std::any_of(out.begin(), out.end(), [&](const TurnAxis& a) { return SameLine(a, axis, m.diameter); })) continue;
    bool round = turns >= 1;
    for (int k = 1; k <= turns && round; ++k) {
      const Pose F = axis.Turn(k * step * kDeg);
      // A turn the declared symmetry covers is no evidence of roundness.
      round = SymmetricRotationError(F, Pose::Identity(), m.symmetry) >= kSameTransformDeg * kDeg &&
              Overlap(m, F) >= m.options.near_symmetry_min_overlap;
    }
    if (round) out.push_back(axis);
  }
  return out;
}

std::vector<Pose> FindNearSymmetries(const PoseModel& m) {
  if (m.options.max_near_symmetries <= 0 || !(m.options.near_symmetry_min_overlap > 0) || m.faces.empty()) return {};
  std::vector<Pose> candidates;
  for (const PlanarFace& f : m.faces) {
    if ((f.hi - f.lo).minCoeff() < kMinFaceExtent) continue;
    const Eigen::Vector3f box_c = BoxCentre(f);
    candidates.push_back(HalfTurn(f.n, box_c));
    // A plate: the antiparallel face nearest behind this one whose box
    // overlaps it; turns about the in-plane axes through the mid-plane.
    float thickness = std::numeric_limits<float>::infinity();
    for (const PlanarFace& g : m.faces) {
      if (f.n.dot(g.n) > -0.99f) continue;
      const float t = f.n.dot(f.c - g.c);
      if (!(t > 0.f) || t > static_cast<float>(kPlateRelativeThickness * m.diameter)) continue;
      const Eigen::Vector3f d = g.c - f.c;
      const Eigen::Vector2f gc(d.dot(f.u), d.dot(f.v));
      if ((gc.array() < f.lo.array()).any() || (gc.array() > f.hi.array()).any()) continue;
      thickness = std::min(thickness, t);
    }
    if (!std::isfinite(thickness)) continue;
    const Eigen::Vector3f mid = box_c - 0.5f * thickness * f.n;
    candidates.push_back(HalfTurn(f.u, mid));
    candidates.push_back(HalfTurn(f.v, mid));
  }
  if (m.options.arm_swaps) AppendArmSwaps(m, candidates);
  const Eigen::Vector3d centroid = m.centroid_O.cast<double>();
  const auto same = [&](const Pose& a, const Pose& b) {
    return SymmetricRotationError(a, b, m.symmetry) < kSameTransformDeg * kDeg &&
           (a * centroid - b * centroid).norm() < kSameTransformRelative * m.diameter;
  };
  std::vector<std::pair<double, Pose>> scored;
  for (const Pose& F : candidates) {
    if (same(F, Pose::Identity())) continue;
    const double overlap = Overlap(m, F);
    if (overlap >= m.options.near_symmetry_min_overlap) scored.emplace_back(overlap, F);
  }
  std::stable_sort(scored.begin(), scored.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
  std::vector<Pose> out;
  for (const auto& [overlap, F] : scored) {
    if (static_cast<int>(out.size()) >= m.options.max_near_symmetries) break;
    bool duplicate = false;
    for (const Pose& G : out) duplicate |= same(F, G);
    if (!duplicate) out.push_back(F);
  }
  return out;
}

}  // namespace bp::internal
