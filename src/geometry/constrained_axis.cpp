// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/geometry/constrained_axis.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <cmath>

namespace endo_guidance::geometry {
namespace {

using Mat6 = Eigen::Matrix<double, 6, 6>;

// Whitening of the measured axis: Sigma_L^{+1/2} over its rank-4 support (the two gauge
// directions, |d| and d.m, carry no information and have ~zero variance). nullopt: no support.
std::optional<Mat6> axisWhitening(Mat6 const& covariance) {
  Eigen::SelfAdjointEigenSolver<Mat6> es(0.5 * (covariance + covariance.transpose()));
  double const top = es.eigenvalues().maxCoeff();
  if (!(top > 0.0)) return std::nullopt;
  Mat6 W = Mat6::Zero();
  for (int i = 0; i < 6; ++i) {
    double const l = es.eigenvalues()(i);
    if (l > 1e-9 * top) W += es.eigenvectors().col(i) * es.eigenvectors().col(i).transpose() / std::sqrt(l);
  }
  return W;
}

// Whitening of the point: (Sigma_I + sigma_b^2 1)^{-1/2}. nullopt: not positive definite.
std::optional<Eigen::Matrix3d> pointWhitening(Eigen::Matrix3d const& covariance, double motion_sigma) {
  Eigen::Matrix3d const SI =
      0.5 * (covariance + covariance.transpose()) + motion_sigma * motion_sigma * Eigen::Matrix3d::Identity();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> ei(SI);
  if (!(ei.eigenvalues().minCoeff() > 0.0)) return std::nullopt;
  return Eigen::Matrix3d(ei.operatorInverseSqrt());
}

}  // namespace

std::optional<ConstrainedAxis> constrainAxisToPoint(CylinderPose const& measured, Eigen::Vector3d const& point,
                                                    Eigen::Matrix3d const& point_covariance, double point_motion_sigma) {
  using Vec6 = Eigen::Matrix<double, 6, 1>;
  using Mat65 = Eigen::Matrix<double, 6, 5>;
  using Mat5 = Eigen::Matrix<double, 5, 5>;
  using Vec5 = Eigen::Matrix<double, 5, 1>;
  Eigen::Vector3d const d_hat = measured.axis.direction(), m_hat = measured.axis.moment();
  if (!measured.covariance.allFinite() || !(measured.covariance.norm() > 0.0) || !point.allFinite() ||
      !point_covariance.allFinite() || !std::isfinite(point_motion_sigma) || !d_hat.allFinite() || !m_hat.allFinite())
    return std::nullopt;
  auto const W_opt = axisWhitening(measured.covariance);
  auto const WI_opt = pointWhitening(point_covariance, point_motion_sigma);
  if (!W_opt || !WI_opt) return std::nullopt;
  Mat6 const& W = *W_opt;
  Eigen::Matrix3d const& WI = *WI_opt;
  Vec6 L_hat;
  L_hat << d_hat, m_hat;
  Eigen::Vector3d d = d_hat, I = point;
  Mat65 G;     // d(d, m) / d(a, b, I) at the current estimate
  Mat5 H;      // J^T J
  double cost = 0.0;
  bool converged = false;
  for (int it = 0; it < 30; ++it) {
    // d' = normalize(d + a u1 + b u2), I' = I + dI; m = I x d = -[d]x I.
    Eigen::Vector3d const u1 = d.unitOrthogonal(), u2 = d.cross(u1);
    G.setZero();
    G.block<3, 1>(0, 0) = u1;
    G.block<3, 1>(0, 1) = u2;
    G.block<3, 1>(3, 0) = I.cross(u1);
    G.block<3, 1>(3, 1) = I.cross(u2);
    G.block<3, 3>(3, 2) = -skew(d);
    Vec6 L;
    L << d, I.cross(d);
    Vec6 const r1 = W * (L - L_hat);
    Eigen::Vector3d const r2 = WI * (I - point);
    cost = r1.squaredNorm() + r2.squaredNorm();
    Eigen::Matrix<double, 9, 5> J = Eigen::Matrix<double, 9, 5>::Zero();
    J.topRows<6>() = W * G;
    J.block<3, 3>(6, 2) = WI;
    Eigen::Matrix<double, 9, 1> r;
    r << r1, r2;
    H = J.transpose() * J;
    Eigen::LDLT<Mat5> const ldlt(H);
    if (ldlt.info() != Eigen::Success) return std::nullopt;
    Vec5 const step = ldlt.solve(-J.transpose() * r);
    if (!step.allFinite()) return std::nullopt;
    d = (d + step(0) * u1 + step(1) * u2).normalized();
    I += step.tail<3>();
    // (radians and metres: 1e-10 is far below any image-borne precision)
    if (step.norm() < 1e-10) {
      converged = true;
      break;
    }
  }
  if (!converged || !d.allFinite() || !I.allFinite()) return std::nullopt;
  auto const line = PluckerLine::fromPointDirection(I, d);
  if (!line) return std::nullopt;
  ConstrainedAxis out;
  out.pose.axis = line->direction().dot(d_hat) < 0.0 ? line->reversed() : *line;
  out.pose.distance = out.pose.axis.distanceToOrigin();
  Eigen::LDLT<Mat5> const ldlt(H);
  Mat5 const P = ldlt.solve(Mat5::Identity());
  if (!P.allFinite()) return std::nullopt;
  out.pose.covariance = G * P * G.transpose();
  out.pivot = I;
  out.chi2 = cost;
  // Covariances beyond double range (found by fuzz_geometry): nothing is guessed.
  if (!out.pose.covariance.allFinite() || !out.pose.axis.moment().allFinite() || !std::isfinite(out.chi2)) return std::nullopt;
  return out;
}

}  // namespace endo_guidance::geometry
