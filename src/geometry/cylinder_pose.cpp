// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/geometry/cylinder_pose.h"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <Eigen/SVD>
#include <cmath>

namespace endo_guidance::geometry {

char const* toString(CylinderPoseStatus s) {
  switch (s) {
    case CylinderPoseStatus::kOk: return "ok";
    case CylinderPoseStatus::kInvalidInput: return "invalid input (non-finite, zero line, radius <= 0 or bad K)";
    case CylinderPoseStatus::kIdenticalPlanes: return "the two contour lines define the same plane";
    case CylinderPoseStatus::kZeroWidth: return "the contour lines leave no width for the shaft";
    case CylinderPoseStatus::kCameraInsideCylinder: return "lines imply the camera is inside the cylinder";
    case CylinderPoseStatus::kTooClose: return "axis closer to the camera than min_distance";
    case CylinderPoseStatus::kTooFar: return "axis farther from the camera than max_distance";
    case CylinderPoseStatus::kWrongSide: return "shaft pixel not on the positive side of both lines";
    case CylinderPoseStatus::kNoRealSolution: return "no admissible root of the conic quadratic";
  }
  return "unknown";
}

namespace {

struct Planes {
  Eigen::Vector3d n0, n1;
};

bool validK(Eigen::Matrix3d const& K) {
  return K.allFinite() && K(0, 0) > 0.0 && K(1, 1) > 0.0 && std::abs(K(2, 2) - 1.0) < 1e-9 && K(2, 0) == 0.0 &&
         K(2, 1) == 0.0 && K(1, 0) == 0.0;
}

// Interpretation-plane normals n_i = K^T l_i, unit length, orientation kept ([Doignon07] Eq. (7)).
std::optional<Planes> interpretationPlanes(Eigen::Matrix3d const& K, ImageLine const& l0, ImageLine const& l1) {
  if (!l0.allFinite() || !l1.allFinite()) return std::nullopt;
  Eigen::Vector3d n0 = K.transpose() * l0, n1 = K.transpose() * l1;
  double const a = n0.norm(), b = n1.norm();
  if (!(a > 0.0) || !(b > 0.0) || l0.head<2>().norm() == 0.0 || l1.head<2>().norm() == 0.0) return std::nullopt;
  return Planes{n0 / a, n1 / b};
}

// Checks shared by both forms on the recovered distance.
CylinderPoseStatus checkDistance(double delta, double radius, CylinderPoseOptions const& o) {
  if (!(delta > radius * (1.0 + 1e-9))) return CylinderPoseStatus::kCameraInsideCylinder;
  if (delta < o.min_distance) return CylinderPoseStatus::kTooClose;
  if (delta > o.max_distance) return CylinderPoseStatus::kTooFar;
  return CylinderPoseStatus::kOk;
}

// The geometric closed form on unit plane normals; status only (no covariance).
CylinderPoseStatus axisFromPlanes(Planes const& P, double radius, CylinderPoseOptions const& o, PluckerLine* axis,
                                  double* delta_out) {
  Eigen::Vector3d const c = P.n0.cross(P.n1);
  double const sine = c.norm();
  if (sine < o.min_plane_sine) return CylinderPoseStatus::kIdenticalPlanes;
  Eigen::Vector3d const s = P.n0 + P.n1;
  double const sn = s.norm();
  if (!(sn > 1e-15)) return CylinderPoseStatus::kZeroWidth;
  double const delta = 2.0 * radius / sn;  // delta = r / sin(alpha/2)
  CylinderPoseStatus const st = checkDistance(delta, radius, o);
  if (st != CylinderPoseStatus::kOk) return st;
  Eigen::Vector3d const d = c / sine;                               // d ~ n0 x n1
  Eigen::Vector3d const p0 = (delta * delta / (2.0 * radius)) * s;  // p0 = delta^2 (n0 + n1) / (2 r)
  *axis = *PluckerLine::fromDirectionMoment(d, p0.cross(d));       // m = p0 x d
  *delta_out = delta;
  return CylinderPoseStatus::kOk;
}

Eigen::Matrix<double, 6, 1> stack(PluckerLine const& L) {
  Eigen::Matrix<double, 6, 1> x;
  x << L.direction(), L.moment();
  return x;
}

}  // namespace

CylinderPoseResult estimateCylinderPose(Eigen::Matrix3d const& K, double radius, ImageLine const& l0_in,
                                        ImageLine const& l1_in, CylinderPoseOptions const& options,
                                        std::optional<Eigen::Vector2d> const& inside_px, Eigen::Matrix3d const& cov_l0,
                                        Eigen::Matrix3d const& cov_l1) {
  CylinderPoseResult res;
  auto const l0 = normalizeLine(l0_in), l1 = normalizeLine(l1_in);
  if (!(radius > 0.0) || !std::isfinite(radius) || !validK(K) || !l0 || !l1) return res;
  if (inside_px) {
    Eigen::Vector3d const x(inside_px->x(), inside_px->y(), 1.0);
    if (!x.allFinite()) return res;
    if (l0->dot(x) <= 0.0 || l1->dot(x) <= 0.0) {
      res.status = CylinderPoseStatus::kWrongSide;
      return res;
    }
  }
  auto const P = interpretationPlanes(K, *l0, *l1);
  if (!P) return res;
  res.status = axisFromPlanes(*P, radius, options, &res.pose.axis, &res.pose.distance);
  if (!res.ok() || !options.compute_covariance) return res;
  if (cov_l0.isZero(0.0) && cov_l1.isZero(0.0)) return res;
  if (!cov_l0.allFinite() || !cov_l1.allFinite()) return res;

  // First-order propagation: central differences of the closed form w.r.t. (l0, l1).
  Eigen::Matrix<double, 6, 6> J;
  Eigen::Matrix<double, 6, 1> x0;
  x0 << *l0, *l1;
  CylinderPoseOptions loose = options;
  loose.min_distance = 0.0;
  loose.max_distance = std::numeric_limits<double>::infinity();
  for (int k = 0; k < 6; ++k) {
    double const h = 1e-7 * std::max(1.0, std::abs(x0(k)));
    Eigen::Matrix<double, 6, 1> xp = x0, xm = x0;
    xp(k) += h;
    xm(k) -= h;
    PluckerLine Lp, Lm;
    double dp, dm;
    auto const Pp = interpretationPlanes(K, xp.head<3>(), xp.tail<3>());
    auto const Pm = interpretationPlanes(K, xm.head<3>(), xm.tail<3>());
    if (!Pp || !Pm || axisFromPlanes(*Pp, radius, loose, &Lp, &dp) != CylinderPoseStatus::kOk ||
        axisFromPlanes(*Pm, radius, loose, &Lm, &dm) != CylinderPoseStatus::kOk) {
      return res;  // too close to a degeneracy to linearise: covariance left at zero
    }
    J.col(k) = (stack(Lp) - stack(Lm)) / (2.0 * h);
  }
  Eigen::Matrix<double, 6, 6> S = Eigen::Matrix<double, 6, 6>::Zero();
  S.topLeftCorner<3, 3>() = cov_l0;
  S.bottomRightCorner<3, 3>() = cov_l1;
  res.pose.covariance = J * S * J.transpose();
  // Huge line covariances overflow the product: no covariance rather than a non-finite one.
  if (!res.pose.covariance.allFinite()) res.pose.covariance.setZero();
  return res;
}

CylinderPoseResult estimateCylinderPose(Eigen::Matrix3d const& K, double radius, ApparentContour const& c,
                                        CylinderPoseOptions const& options) {
  std::optional<Eigen::Vector2d> inside;
  if (c.tip_px != c.entry_px) inside = 0.5 * (c.tip_px + c.entry_px);
  return estimateCylinderPose(K, radius, c.lines[0], c.lines[1], options, inside, c.line_covariances[0],
                              c.line_covariances[1]);
}

CylinderPoseResult estimateCylinderPoseConic(Eigen::Matrix3d const& K, double radius, ImageLine const& l0_in,
                                             ImageLine const& l1_in, CylinderPoseOptions const& options) {
  CylinderPoseResult res;
  auto const l0 = normalizeLine(l0_in), l1 = normalizeLine(l1_in);
  if (!(radius > 0.0) || !std::isfinite(radius) || !validK(K) || !l0 || !l1) return res;
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
  CylinderPoseStatus const st = checkDistance(delta, radius, options);
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

std::optional<std::array<ImageLine, 2>> projectCylinder(Eigen::Matrix3d const& K, PluckerLine const& axis, double radius) {
  double const delta = axis.distanceToOrigin();
  if (!(radius > 0.0) || !(delta > radius)) return std::nullopt;
  Eigen::Vector3d const p0_hat = axis.closestPointToOrigin() / delta;
  Eigen::Vector3d const m_hat = axis.moment() / delta;
  double const ca = radius / delta, sa = std::sqrt(1.0 - ca * ca);
  Eigen::Matrix3d const Kit = K.transpose().inverse();
  std::array<ImageLine, 2> out;
  Eigen::Vector3d const n[2] = {ca * p0_hat + sa * m_hat, ca * p0_hat - sa * m_hat};
  for (int i = 0; i < 2; ++i) {
    auto const l = normalizeLine(Kit * n[i]);  // l ~ K^-T n
    if (!l) return std::nullopt;
    out[i] = *l;
  }
  return out;
}

std::optional<Eigen::Vector3d> backProjectOntoAxis(Eigen::Matrix3d const& K, PluckerLine const& axis,
                                                   Eigen::Vector2d const& px) {
  return backProjectOntoAxis(axis, K.partialPivLu().solve(Eigen::Vector3d(px.x(), px.y(), 1.0)));
}

std::optional<Eigen::Vector3d> backProjectOntoAxis(PluckerLine const& axis, Eigen::Vector3d const& ray) {
  if (!ray.allFinite() || !(ray.norm() > 0.0)) return std::nullopt;
  Eigen::Vector3d const r = ray.normalized();
  Eigen::Vector3d const& d = axis.direction();
  Eigen::Vector3d const p0 = axis.closestPointToOrigin();
  // Minimise |p0 + t d - s r|: normal equations of the two line parameters.
  double const b = d.dot(r);
  double const den = 1.0 - b * b;
  if (den < 1e-12) return std::nullopt;
  double const t = (b * r.dot(p0) - d.dot(p0)) / den;
  return Eigen::Vector3d(p0 + t * d);
}

}  // namespace endo_guidance::geometry
