// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "cylinder_pose_conic.h"

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>

namespace endo_guidance::test {

using namespace geometry;

CylinderPoseResult estimateCylinderPoseConic(Eigen::Matrix3d const& K, double radius, ImageLine const& l0_in, ImageLine const& l1_in,
                                             CylinderPoseOptions const& options) {
  CylinderPoseResult res;
  auto const l0 = normalizeLine(l0_in), l1 = normalizeLine(l1_in);
  if (!(radius > 0.0) || !std::isfinite(radius) || !validCameraMatrix(K) || !l0 || !l1) return res;
  auto const P = interpretationPlanes(K, *l0, *l1);
  if (!P) return res;
  if (P->n0.cross(P->n1).norm() < options.min_plane_sine) {
    res.status = CylinderPoseStatus::kIdenticalPlanes;
    return res;
  }
  // Degenerate conic of the apparent contour in normalised coordinates (Eq. (10)).
  Eigen::Matrix3d const C = 0.5 * (P->n0 * P->n1.transpose() + P->n1 * P->n0.transpose());

  // Step 1 (Eq. (11)): 6x8 system  vech(M) - lambda vech(C) - tau vech(I) = 0.
  static constexpr int kI[6] = {0, 0, 0, 1, 1, 2};
  static constexpr int kJ[6] = {0, 1, 2, 1, 2, 2};
  Eigen::Matrix<double, 6, 8> A = Eigen::Matrix<double, 6, 8>::Zero();
  for (int r = 0; r < 6; ++r) {
    A(r, r) = 1.0;
    A(r, 6) = -C(kI[r], kJ[r]);
    A(r, 7) = -(kI[r] == kJ[r] ? 1.0 : 0.0);
  }
  Eigen::JacobiSVD<Eigen::Matrix<double, 6, 8>> svd(A, Eigen::ComputeFullV);
  Eigen::Matrix<double, 8, 2> const N = svd.matrixV().rightCols<2>();
  // Basis of the null space with (lambda, tau) = (1, 0) and (0, 1).
  Eigen::Matrix2d const B = N.bottomRows<2>();
  if (std::abs(B.determinant()) < 1e-12) {
    res.status = CylinderPoseStatus::kNoRealSolution;
    return res;
  }
  Eigen::Matrix<double, 8, 2> const E = N * B.inverse();
  auto toSym = [&](Eigen::Matrix<double, 8, 1> const& x) {
    Eigen::Matrix3d M;
    for (int r = 0; r < 6; ++r) M(kI[r], kJ[r]) = M(kJ[r], kI[r]) = x(r);
    return M;
  };
  Eigen::Matrix3d const Ma = toSym(E.col(0)), Mb = toSym(E.col(1));  // M = lambda (Ma + s Mb)
  // det(Ma + s Mb) = det Ma + s tr(adj(Ma) Mb) + s^2 tr(Ma adj(Mb)) + s^3 det Mb; det Ma = det C = 0,
  // so divide by s: quadratic q2 s^2 + q1 s + q0 = 0 (Eq. (12)).
  auto adjugate = [](Eigen::Matrix3d const& M) {
    Eigen::Matrix3d Adj;
    Adj.row(0) = M.col(1).cross(M.col(2)).transpose();
    Adj.row(1) = M.col(2).cross(M.col(0)).transpose();
    Adj.row(2) = M.col(0).cross(M.col(1)).transpose();
    return Adj;
  };
  double const q2 = Mb.determinant();
  double const q1 = (Ma * adjugate(Mb)).trace();
  double const q0 = (adjugate(Ma) * Mb).trace();
  double s = -1.0;
  if (std::abs(q2) > 1e-300) {
    double const disc = q1 * q1 - 4.0 * q2 * q0;
    if (disc < 0.0) {
      res.status = CylinderPoseStatus::kNoRealSolution;
      return res;
    }
    double const sq = std::sqrt(disc);
    // Numerically stable roots; keep the positive one (the wedge picked by the orientation).
    double const q = -0.5 * (q1 + std::copysign(sq, q1));
    double const r1 = q / q2, r2 = (q != 0.0) ? q0 / q : -1.0;
    s = std::max(r1, r2);
  }
  if (!(s > 0.0)) {
    res.status = CylinderPoseStatus::kNoRealSolution;
    return res;
  }
  Eigen::Matrix3d const Ms = Ma + s * Mb;  // = C + s I
  // Step 2 (Eq. (9)): tr M = delta^2 + tau, tau = delta^2 - r^2  =>  lambda (tr Ms - 2 s) = r^2.
  double const den = Ms.trace() - 2.0 * s;
  if (!(den > 0.0)) {
    res.status = CylinderPoseStatus::kZeroWidth;
    return res;
  }
  double const lambda = radius * radius / den;
  double const tau = s * lambda;
  double const delta = std::sqrt(tau + radius * radius);
  CylinderPoseStatus const st = checkAxisDistance(delta, radius, options);
  if (st != CylinderPoseStatus::kOk) {
    res.status = st;
    return res;
  }
  // Eq. (13): eigenvectors of M = lambda Ms: 0 (m), tau (d), delta^2 (p0).
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(lambda * Ms);
  Eigen::Vector3d d = es.eigenvectors().col(1);
  Eigen::Vector3d p0 = delta * es.eigenvectors().col(2);
  if (p0.dot(P->n0) < 0.0) p0 = -p0;                   // shaft on the positive side of the lines
  if (d.dot(P->n0.cross(P->n1)) < 0.0) d = -d;         // order convention: d ~ n0 x n1
  res.pose.axis = *PluckerLine::fromDirectionMoment(d, p0.cross(d));
  res.pose.distance = delta;
  res.status = CylinderPoseStatus::kOk;
  return res;
}

}  // namespace endo_guidance::test
