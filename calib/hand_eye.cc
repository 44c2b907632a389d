#include "calib/hand_eye.h"

#include <opencv2/calib3d.hpp>

#include <Eigen/Dense>
#include <Eigen/Eigenvalues>
#include <cmath>

#include "calib/board.h"

namespace bp {
namespace {

Vec3 LogRotation(const Mat3& R) {
  const Eigen::AngleAxisd aa(R);
  return aa.angle() * aa.axis();
}

Mat3 ExpRotation(const Vec3& w) {
  const double a = w.norm();
  if (a < 1e-15) return Mat3::Identity();
  return Eigen::AngleAxisd(a, w / a).toRotationMatrix();
}

// The rotation nearest (Frobenius) to M.
Mat3 ProjectToRotation(const Mat3& M) {
  Eigen::JacobiSVD<Mat3> svd(M, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Mat3 D = Mat3::Identity();
  D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1 : 1;
  return svd.matrixU() * D * svd.matrixV().transpose();
}

// The board pose predicted by (X, Y) at robot pose X_BF.
Pose PredictX_CT(const Pose& X, const Pose& Y, const Pose& X_BF, bool eye_in_hand) {
  return eye_in_hand ? Pose(X.inverse() * X_BF.inverse() * Y) : Pose(X.inverse() * X_BF * Y);
}

Pose Perturb(const Pose& P, const Eigen::Matrix<double, 6, 1>& d) {
  return P * MakePose(ExpRotation(d.head<3>()), d.tail<3>());
}

// Robot motion A and board motion B between two views, with A X = X B.
struct MotionPair {
  Pose A, B;
};

// Every pair of views whose relative robot rotation lies in
// [min_pair_rotation_deg, 180 deg - 0.1 rad]: smaller rotations make A X = X B
// ill-conditioned, ones near 180 deg have an ill-defined axis.
std::vector<MotionPair> WellRotatedPairs(const std::vector<HandEyeSample>& samples, const HandEyeOptions& options) {
  const double min_rot = options.min_pair_rotation_deg * M_PI / 180.0;
  std::vector<MotionPair> pairs;
  for (size_t i = 0; i < samples.size(); ++i) {
    for (size_t j = i + 1; j < samples.size(); ++j) {
      const Pose& Fi = samples[i].X_BF;
      const Pose& Fj = samples[j].X_BF;
      const Pose& Ci = samples[i].X_CT;
      const Pose& Cj = samples[j].X_CT;
      MotionPair p;
      p.A = options.eye_in_hand ? Pose(Fj.inverse() * Fi) : Pose(Fi * Fj.inverse());
      p.B = options.eye_in_hand ? Pose(Cj * Ci.inverse()) : Pose(Ci * Cj.inverse());
      const double angle = RotationAngle(p.A.linear());
      if (angle < min_rot || angle > M_PI - 0.1) continue;
      pairs.push_back(p);
    }
  }
  return pairs;
}

// Park & Martin's closed form: the rotation from the log-rotations of the
// pairs, then the translation by least squares on (R_A - I) t = R_X t_B - t_A.
Result<Pose> ParkClosedForm(const std::vector<MotionPair>& pairs) {
  Mat3 M = Mat3::Zero();
  for (const MotionPair& p : pairs) M += LogRotation(p.B.linear()) * LogRotation(p.A.linear()).transpose();
  const Mat3 MtM = M.transpose() * M;
  Eigen::SelfAdjointEigenSolver<Mat3> eig(MtM);
  if (eig.eigenvalues().minCoeff() < 1e-10 * std::max(1.0, eig.eigenvalues().maxCoeff())) {
    return Status::InvalidArgument("hand-eye calibration: the robot rotations are all about one axis; "
                                      "rotate about at least two different axes");
  }
  const Mat3 inv_sqrt = eig.eigenvectors() * eig.eigenvalues().cwiseInverse().cwiseSqrt().asDiagonal() *
                        eig.eigenvectors().transpose();
  const Mat3 Rx = ProjectToRotation(inv_sqrt * M.transpose());
  Eigen::MatrixXd C(3 * pairs.size(), 3);
  Eigen::VectorXd d(3 * pairs.size());
  for (size_t i = 0; i < pairs.size(); ++i) {
    C.block<3, 3>(3 * i, 0) = pairs[i].A.linear() - Mat3::Identity();
    d.segment<3>(3 * i) = Rx * pairs[i].B.translation() - pairs[i].A.translation();
  }
  const Vec3 tx = C.colPivHouseholderQr().solve(d);
  return MakePose(Rx, tx);
}

// The board pose Y implied by X at every view, averaged (rotation projected
// back onto SO(3)).
Pose AverageBoardPose(const std::vector<HandEyeSample>& samples, const Pose& X, bool eye_in_hand) {
  Mat3 Rsum = Mat3::Zero();
  Vec3 tsum = Vec3::Zero();
  for (const HandEyeSample& s : samples) {
    const Pose Yi = eye_in_hand ? Pose(s.X_BF * X * s.X_CT) : Pose(s.X_BF.inverse() * X * s.X_CT);
    Rsum += Yi.linear();
    tsum += Yi.translation();
  }
  return MakePose(ProjectToRotation(Rsum), tsum / static_cast<double>(samples.size()));
}

// Corner reprojection residuals of every view with a full set of corners, in
// pixels (normalized image coordinates scaled by fx, fy), as a function of
// (X, Y).
class Reprojection {
 public:
  Reprojection(const std::vector<HandEyeSample>& samples, const CalibrationSpec& board, const Intrinsics& k,
               bool eye_in_hand)
      : samples_(samples), object_(BoardCorners(board)), k_(k), eye_in_hand_(eye_in_hand),
        observed_(samples.size()) {
    const cv::Mat K = (cv::Mat_<double>(3, 3) << k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1);
    const cv::Mat dist(1, 5, CV_64F, const_cast<double*>(k.distortion.data()));
    for (size_t i = 0; i < samples.size(); ++i) {
      const auto& c = samples[i].corners;
      if (c.size() != object_.size()) continue;
      std::vector<cv::Point2d> in, out;
      for (const auto& p : c) in.emplace_back(p.x(), p.y());
      cv::undistortPoints(in, out, K, dist);
      for (const auto& p : out) observed_[i].emplace_back(p.x, p.y);
      residuals_ += 2 * object_.size();
    }
  }

  size_t size() const { return residuals_; }

  void operator()(const Pose& X, const Pose& Y, Eigen::VectorXd& r) const {
    r.resize(static_cast<Eigen::Index>(residuals_));
    Eigen::Index at = 0;
    for (size_t i = 0; i < samples_.size(); ++i) {
      if (observed_[i].empty()) continue;
      const Pose X_CT = PredictX_CT(X, Y, samples_[i].X_BF, eye_in_hand_);
      for (size_t c = 0; c < object_.size(); ++c) {
        const Vec3 p = X_CT * object_[c];
        r[at++] = k_.fx * (p.x() / p.z() - observed_[i][c].x());
        r[at++] = k_.fy * (p.y() / p.z() - observed_[i][c].y());
      }
    }
  }

 private:
  const std::vector<HandEyeSample>& samples_;
  const std::vector<Vec3> object_;
  const Intrinsics& k_;
  const bool eye_in_hand_;
  std::vector<std::vector<Eigen::Vector2d>> observed_;  // undistorted, normalized
  size_t residuals_ = 0;
};

// Levenberg-Marquardt on (X, Y) jointly, with local perturbations
// (rotation vector, translation) of each and a central-difference Jacobian;
// at most 50 iterations.
void RefineOnReprojection(const Reprojection& reprojection, Pose& X, Pose& Y) {
  Eigen::VectorXd r;
  reprojection(X, Y, r);
  double cost = r.squaredNorm();
  double lambda = 1e-3;
  Eigen::MatrixXd J(r.size(), 12);
  for (int iter = 0; iter < 50; ++iter) {
    for (int p = 0; p < 12; ++p) {
      Eigen::Matrix<double, 6, 1> delta = Eigen::Matrix<double, 6, 1>::Zero();
      const double h = p % 6 < 3 ? 1e-6 : 1e-7;
      delta[p % 6] = h;
      Eigen::VectorXd rp, rm;
      reprojection(p < 6 ? Perturb(X, delta) : X, p < 6 ? Y : Perturb(Y, delta), rp);
      reprojection(p < 6 ? Perturb(X, -delta) : X, p < 6 ? Y : Perturb(Y, -delta), rm);
      J.col(p) = (rp - rm) / (2 * h);
    }
    const Eigen::MatrixXd H = J.transpose() * J;
    const Eigen::VectorXd g = J.transpose() * r;
    bool improved = false;
    bool converged = false;
    for (int tries = 0; tries < 10 && !improved; ++tries) {
      Eigen::MatrixXd Hd = H;
      Hd.diagonal() *= (1.0 + lambda);
      const Eigen::VectorXd step = -Hd.ldlt().solve(g);
      const Pose Xn = Perturb(X, step.head<6>());
      const Pose Yn = Perturb(Y, step.tail<6>());
      Eigen::VectorXd rn;
      reprojection(Xn, Yn, rn);
      const double cn = rn.squaredNorm();
      if (cn < cost) {
        improved = true;
        const double gain = (cost - cn) / cost;
        X = Xn;
        Y = Yn;
        r = rn;
        cost = cn;
        lambda = std::max(1e-9, lambda / 10);
        converged = gain < 1e-12 || step.norm() < 1e-12;
      } else {
        lambda *= 10;
      }
    }
    if (!improved || converged) break;
  }
}

// Fills the solution's consistency figures: each view's board pose predicted
// from its robot pose against the detected one (mm at the board centre,
// degrees), RMS and max, and the corner reprojection RMS.
void MeasureResiduals(const std::vector<HandEyeSample>& samples, const CalibrationSpec& board,
                      const Reprojection& reprojection, bool eye_in_hand, HandEyeSolution& sol) {
  if (reprojection.size() > 0) {
    Eigen::VectorXd r;
    reprojection(sol.X, sol.Y, r);
    sol.reprojection_rms_px = std::sqrt(r.squaredNorm() / (r.size() / 2.0));
  }
  double sum_mm = 0, sum_deg = 0;
  const Vec3 centre = BoardCentre(board);
  for (const HandEyeSample& s : samples) {
    const Pose pred = PredictX_CT(sol.X, sol.Y, s.X_BF, eye_in_hand);
    const double mm = ((pred * centre) - (s.X_CT * centre)).norm() * 1000.0;
    const double deg = RotationErrorDeg(pred, s.X_CT);
    sum_mm += mm * mm;
    sum_deg += deg * deg;
    sol.residual_max_mm = std::max(sol.residual_max_mm, mm);
    sol.residual_max_deg = std::max(sol.residual_max_deg, deg);
  }
  const double n = static_cast<double>(samples.size());
  sol.residual_rms_mm = std::sqrt(sum_mm / n);
  sol.residual_rms_deg = std::sqrt(sum_deg / n);
}

}  // namespace


double TranslationErrorMm(const Pose& a, const Pose& b) {
  return (a.translation() - b.translation()).norm() * 1000.0;
}

double RotationErrorDeg(const Pose& a, const Pose& b) {
  return RotationAngle(a.linear().transpose() * b.linear()) * 180.0 / M_PI;
}

Result<HandEyeSolution> SolveHandEye(const std::vector<HandEyeSample>& samples, const CalibrationSpec& board,
                                     const Intrinsics& k, const HandEyeOptions& options) {
  const size_t n = samples.size();
  if (n < 3) {
    return Status::InvalidArgument("hand-eye calibration needs at least 3 poses, got " + std::to_string(n));
  }
  const std::vector<MotionPair> pairs = WellRotatedPairs(samples, options);
  if (pairs.size() < 2) {
    return Status::InvalidArgument("hand-eye calibration needs robot poses rotated by at least " +
                                      std::to_string(options.min_pair_rotation_deg) +
                                      " deg from each other about two axes; " + std::to_string(pairs.size()) +
                                      " usable pair(s) among " + std::to_string(n) + " poses");
  }
  Result<Pose> X = ParkClosedForm(pairs);
  if (!X.ok()) return X.status();
  HandEyeSolution sol;
  sol.X = *X;
  sol.Y = AverageBoardPose(samples, sol.X, options.eye_in_hand);
  sol.poses = static_cast<int>(n);
  sol.pairs = static_cast<int>(pairs.size());
  sol.method = "park";

  const Reprojection reprojection(samples, board, k, options.eye_in_hand);
  // 12 unknowns (X and Y, 6 each): refine only with more residuals than that.
  if (options.refine && reprojection.size() > 12) {
    RefineOnReprojection(reprojection, sol.X, sol.Y);
    sol.method = "park+refine";
  }
  MeasureResiduals(samples, board, reprojection, options.eye_in_hand, sol);
  return sol;
}

}  // namespace bp
