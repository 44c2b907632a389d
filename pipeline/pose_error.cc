// Symmetry-aware pose errors (declared in pipeline/pose_estimator.h).
#include <algorithm>
#include <cmath>
#include <limits>

#include "pipeline/pose_estimator.h"

namespace bp {
namespace {

// Rotation error for one 'extra' element E (identity included by the caller).
double ErrorWith(const Mat3& Ra, const Mat3& Rb_E, const Symmetry& s) {
  switch (s.kind) {
    case Symmetry::Kind::kRevolute: {
      const Vec3 a = s.axis.normalized();
      const Vec3 u = Ra * a, v = Rb_E * a;
      return std::atan2(u.cross(v).norm(), u.dot(v));
    }
    case Symmetry::Kind::kDiscrete: {
      const Vec3 a = s.axis.normalized();
      const int n = std::max(1, s.order);
      double best = std::numeric_limits<double>::infinity();
      for (int k = 0; k < n; ++k) {
        const Mat3 Rk = Eigen::AngleAxisd(2.0 * M_PI * k / n, a).toRotationMatrix();
        best = std::min(best, RotationAngle(Ra.transpose() * Rb_E * Rk));
      }
      return best;
    }
    case Symmetry::Kind::kNone:
      break;
  }
  return RotationAngle(Ra.transpose() * Rb_E);
}

// Index into {I} + extra of the element minimising the rotation error (0 = I).
size_t BestElement(const Pose& X_a, const Pose& X_b, const Symmetry& s, double* error) {
  size_t best = 0;
  double best_err = ErrorWith(X_a.linear(), X_b.linear(), s);
  for (size_t i = 0; i < s.extra.size(); ++i) {
    const double e = ErrorWith(X_a.linear(), X_b.linear() * s.extra[i].linear(), s);
    if (e < best_err - 1e-12) {
      best_err = e;
      best = i + 1;
    }
  }
  if (error) *error = best_err;
  return best;
}

}  // namespace

double SymmetricRotationError(const Pose& X_BO_a, const Pose& X_BO_b, const Symmetry& symmetry) {
  double err = 0;
  BestElement(X_BO_a, X_BO_b, symmetry, &err);
  return err;
}

double SymmetricTranslationError(const Pose& X_BO_a, const Pose& X_BO_b, const Symmetry& symmetry) {
  const size_t best = BestElement(X_BO_a, X_BO_b, symmetry, nullptr);
  const Pose X_b = best == 0 ? X_BO_b : X_BO_b * symmetry.extra[best - 1];
  return (X_BO_a.translation() - X_b.translation()).norm();
}

double AddS(std::span<const Eigen::Vector3f> points_O, const Pose& X_BO_a, const Pose& X_BO_b) {
  if (points_O.empty()) return 0;
  // Brute force, averaged over at most ~1000 of the points against all of them
  // (a few ms); ADD-S is an evaluation metric, not on the request path.
  const size_t stride = std::max<size_t>(1, points_O.size() / 1000);
  std::vector<Eigen::Vector3d> b;
  b.reserve(points_O.size());
  for (const auto& p : points_O) b.push_back(X_BO_b * p.cast<double>());
  double sum = 0;
  size_t n = 0;
  for (size_t i = 0; i < points_O.size(); i += stride) {
    const Eigen::Vector3d a = X_BO_a * points_O[i].cast<double>();
    double best = std::numeric_limits<double>::infinity();
    for (const auto& q : b) best = std::min(best, (a - q).squaredNorm());
    sum += std::sqrt(best);
    ++n;
  }
  return sum / static_cast<double>(n);
}

}  // namespace bp
