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

bool validCameraMatrix(Eigen::Matrix3d const& K) {
  return K.allFinite() && K(0, 0) > 0.0 && K(1, 1) > 0.0 && std::abs(K(2, 2) - 1.0) < 1e-9 && K(2, 0) == 0.0 &&
         K(2, 1) == 0.0 && K(1, 0) == 0.0;
}

std::optional<InterpretationPlanes> interpretationPlanes(Eigen::Matrix3d const& K, ImageLine const& l0, ImageLine const& l1) {
  if (!l0.allFinite() || !l1.allFinite()) return std::nullopt;
  Eigen::Vector3d n0 = K.transpose() * l0, n1 = K.transpose() * l1;
  double const a = n0.norm(), b = n1.norm();
  if (!(a > 0.0) || !(b > 0.0) || l0.head<2>().norm() == 0.0 || l1.head<2>().norm() == 0.0) return std::nullopt;
  return InterpretationPlanes{n0 / a, n1 / b};
}

CylinderPoseStatus checkAxisDistance(double delta, double radius, CylinderPoseOptions const& o) {
  if (!(delta > radius * (1.0 + 1e-9))) return CylinderPoseStatus::kCameraInsideCylinder;
  if (delta < o.min_distance) return CylinderPoseStatus::kTooClose;
  if (delta > o.max_distance) return CylinderPoseStatus::kTooFar;
  return CylinderPoseStatus::kOk;
}

namespace {

// The geometric closed form on unit plane normals; status only (no covariance).
CylinderPoseStatus axisFromPlanes(InterpretationPlanes const& P, double radius, CylinderPoseOptions const& o, PluckerLine* axis,
                                  double* delta_out) {
  Eigen::Vector3d const c = P.n0.cross(P.n1);
  double const sine = c.norm();
  if (sine < o.min_plane_sine) return CylinderPoseStatus::kIdenticalPlanes;
  Eigen::Vector3d const s = P.n0 + P.n1;
  double const sn = s.norm();
  if (!(sn > 1e-15)) return CylinderPoseStatus::kZeroWidth;
  double const delta = 2.0 * radius / sn;  // delta = r / sin(alpha/2)
  CylinderPoseStatus const st = checkAxisDistance(delta, radius, o);
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
  if (!(radius > 0.0) || !std::isfinite(radius) || !validCameraMatrix(K) || !l0 || !l1) return res;
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
