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
  // Park & Martin over every pair (i, j) with enough relative rotation:
  // A X = X B with A the robot motion and B the board motion seen by the camera.
  const double min_rot = options.min_pair_rotation_deg * M_PI / 180.0;
  std::vector<Pose> As, Bs;
  for (size_t i = 0; i < n; ++i) {
    for (size_t j = i + 1; j < n; ++j) {
      const Pose& Fi = samples[i].X_BF;
      const Pose& Fj = samples[j].X_BF;
      const Pose& Ci = samples[i].X_CT;
      const Pose& Cj = samples[j].X_CT;
      Pose A = options.eye_in_hand ? Pose(Fj.inverse() * Fi) : Pose(Fi * Fj.inverse());
      Pose B = options.eye_in_hand ? Pose(Cj * Ci.inverse()) : Pose(Ci * Cj.inverse());
      const double angle = RotationAngle(A.linear());
      if (angle < min_rot || angle > M_PI - 0.1) continue;
      As.push_back(A);
      Bs.push_back(B);
    }
  }
  if (As.size() < 2) {
    return Status::InvalidArgument("hand-eye calibration needs robot poses rotated by at least " +
                                      std::to_string(options.min_pair_rotation_deg) +
                                      " deg from each other about two axes; " + std::to_string(As.size()) +
                                      " usable pair(s) among " + std::to_string(n) + " poses");
  }
  Mat3 M = Mat3::Zero();
  for (size_t p = 0; p < As.size(); ++p) M += LogRotation(Bs[p].linear()) * LogRotation(As[p].linear()).transpose();
  const Mat3 MtM = M.transpose() * M;
  Eigen::SelfAdjointEigenSolver<Mat3> eig(MtM);
  if (eig.eigenvalues().minCoeff() < 1e-10 * std::max(1.0, eig.eigenvalues().maxCoeff())) {
    return Status::InvalidArgument("hand-eye calibration: the robot rotations are all about one axis; "
                                      "rotate about at least two different axes");
  }
  const Mat3 inv_sqrt = eig.eigenvectors() * eig.eigenvalues().cwiseInverse().cwiseSqrt().asDiagonal() *
                        eig.eigenvectors().transpose();
  const Mat3 Rx = ProjectToRotation(inv_sqrt * M.transpose());
  Eigen::MatrixXd C(3 * As.size(), 3);
  Eigen::VectorXd d(3 * As.size());
  for (size_t p = 0; p < As.size(); ++p) {
    C.block<3, 3>(3 * p, 0) = As[p].linear() - Mat3::Identity();
    d.segment<3>(3 * p) = Rx * Bs[p].translation() - As[p].translation();
  }
  const Vec3 tx = C.colPivHouseholderQr().solve(d);
  HandEyeSolution sol;
  sol.X = MakePose(Rx, tx);
  sol.poses = static_cast<int>(n);
  sol.pairs = static_cast<int>(As.size());
  sol.method = "park";

  // Y from every sample, averaged.
  auto estimate_Y = [&](const Pose& X) {
    Mat3 Rsum = Mat3::Zero();
    Vec3 tsum = Vec3::Zero();
    for (const HandEyeSample& s : samples) {
      const Pose Yi = options.eye_in_hand ? Pose(s.X_BF * X * s.X_CT) : Pose(s.X_BF.inverse() * X * s.X_CT);
      Rsum += Yi.linear();
      tsum += Yi.translation();
    }
    return MakePose(ProjectToRotation(Rsum), tsum / static_cast<double>(n));
  };
  sol.Y = estimate_Y(sol.X);

  // Observed corners, undistorted to normalized image coordinates.
  const std::vector<Vec3> object = BoardCorners(board);
  const cv::Mat K = (cv::Mat_<double>(3, 3) << k.fx, 0, k.cx, 0, k.fy, k.cy, 0, 0, 1);
  const cv::Mat dist(1, 5, CV_64F, const_cast<double*>(k.distortion.data()));
  std::vector<std::vector<Eigen::Vector2d>> observed(n);
  size_t residuals = 0;
  for (size_t i = 0; i < n; ++i) {
    const auto& c = samples[i].corners;
    if (c.size() != object.size()) continue;
    std::vector<cv::Point2d> in, out;
    for (const auto& p : c) in.emplace_back(p.x(), p.y());
    cv::undistortPoints(in, out, K, dist);
    for (const auto& p : out) observed[i].emplace_back(p.x, p.y);
    residuals += 2 * object.size();
  }
  auto reprojection = [&](const Pose& X, const Pose& Y, Eigen::VectorXd& r) {
    r.resize(static_cast<Eigen::Index>(residuals));
    Eigen::Index at = 0;
    for (size_t i = 0; i < n; ++i) {
      if (observed[i].empty()) continue;
      const Pose X_CT = PredictX_CT(X, Y, samples[i].X_BF, options.eye_in_hand);
      for (size_t c = 0; c < object.size(); ++c) {
        const Vec3 p = X_CT * object[c];
        r[at++] = k.fx * (p.x() / p.z() - observed[i][c].x());
        r[at++] = k.fy * (p.y() / p.z() - observed[i][c].y());
      }
    }
  };

  if (options.refine && residuals > 12) {
    // Levenberg-Marquardt on (X, Y) with local perturbations, numeric Jacobian.
    Pose X = sol.X, Y = sol.Y;
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
          if (gain < 1e-12 || step.norm() < 1e-12) iter = 1000;
        } else {
          lambda *= 10;
        }
      }
      if (!improved) break;
    }
    sol.X = X;
    sol.Y = Y;
    sol.method = "park+refine";
  }

  if (residuals > 0) {
    Eigen::VectorXd r;
    reprojection(sol.X, sol.Y, r);
    sol.reprojection_rms_px = std::sqrt(r.squaredNorm() / (r.size() / 2.0));
  }
  double sum_mm = 0, sum_deg = 0;
  const Vec3 centre = BoardCentre(board);
  for (const HandEyeSample& s : samples) {
    const Pose pred = PredictX_CT(sol.X, sol.Y, s.X_BF, options.eye_in_hand);
    const double mm = ((pred * centre) - (s.X_CT * centre)).norm() * 1000.0;
    const double deg = RotationErrorDeg(pred, s.X_CT);
    sum_mm += mm * mm;
    sum_deg += deg * deg;
    sol.residual_max_mm = std::max(sol.residual_max_mm, mm);
    sol.residual_max_deg = std::max(sol.residual_max_deg, deg);
  }
  sol.residual_rms_mm = std::sqrt(sum_mm / n);
  sol.residual_rms_deg = std::sqrt(sum_deg / n);
  return sol;
}

}  // namespace bp
