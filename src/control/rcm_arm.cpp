// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/control/rcm_arm.h"

#include <algorithm>
#include <cmath>

namespace endo_guidance::control {

namespace {
Eigen::Matrix3d rotation(RcmJoints const& q) {
  return (Eigen::AngleAxisd(q(kPan), Eigen::Vector3d::UnitY()) * Eigen::AngleAxisd(q(kTilt), Eigen::Vector3d::UnitX()) *
          Eigen::AngleAxisd(q(kRoll), Eigen::Vector3d::UnitZ()))
      .toRotationMatrix();
}
}  // namespace

Eigen::Isometry3d RcmKinematics::instrument(RcmJoints const& q) const {
  Eigen::Isometry3d I = trocar;
  I.linear() = trocar.linear() * rotation(q);
  return I;
}

Eigen::Isometry3d RcmKinematics::tip(RcmJoints const& q) const {
  Eigen::Isometry3d I = instrument(q);
  I.translation() += q(kDepth) * I.linear().col(2);
  return I;
}

RcmJoints RcmKinematics::inverse(Eigen::Matrix3d const& R_base_instrument, Eigen::Vector3d const& tip_base) const {
  Eigen::Matrix3d const R = trocar.linear().transpose() * R_base_instrument;  // Ry(p) Rx(t) Rz(r)
  Eigen::Vector3d const d = R.col(2);  // (cos t sin p, -sin t, cos t cos p)
  RcmJoints q;
  q(kTilt) = std::asin(std::clamp(-d.y(), -1.0, 1.0));
  q(kPan) = std::hypot(d.x(), d.z()) > 1e-12 ? std::atan2(d.x(), d.z()) : 0.0;
  Eigen::Matrix3d const Rr = (Eigen::AngleAxisd(q(kPan), Eigen::Vector3d::UnitY()) *
                              Eigen::AngleAxisd(q(kTilt), Eigen::Vector3d::UnitX())).toRotationMatrix().transpose() * R;
  q(kRoll) = std::atan2(Rr(1, 0), Rr(0, 0));
  q(kDepth) = (tip_base - trocar.translation()).dot(R_base_instrument.col(2));
  return q;
}

RcmJoints RcmLimits::clamp(RcmJoints const& q) const {
  RcmJoints c = q;
  double const cone = std::hypot(q(kPan), q(kTilt));
  if (cone > max_cone) {
    c(kPan) *= max_cone / cone;
    c(kTilt) *= max_cone / cone;
  }
  c(kDepth) = std::clamp(q(kDepth), min_depth, max_depth);
  c(kRoll) = std::clamp(q(kRoll), min_roll, max_roll);
  return c;
}

bool RcmLimits::inside(RcmJoints const& q, double tol) const {
  return q.allFinite() && std::hypot(q(kPan), q(kTilt)) <= max_cone + tol && q(kDepth) >= min_depth - tol &&
         q(kDepth) <= max_depth + tol && q(kRoll) >= min_roll - tol && q(kRoll) <= max_roll + tol;
}

RcmJoints limitRates(RcmJoints const& q, RcmJoints const& current, RcmJoints const& command, double dt, RcmLimits const& L) {
  if (!command.allFinite() || !(dt > 0.0)) return RcmJoints::Zero();
  // Velocity saturation, the direction of motion kept.
  double scale = 1.0;
  for (int i = 0; i < 4; ++i)
    if (std::abs(command(i)) > L.max_velocity(i)) scale = std::min(scale, L.max_velocity(i) / std::abs(command(i)));
  RcmJoints v = command * scale;
  // Acceleration limit on the change of rate.
  for (int i = 0; i < 4; ++i) {
    double const dv = L.max_acceleration(i) * dt;
    v(i) = std::clamp(v(i), current(i) - dv, current(i) + dv);
  }
  // Workspace: never step out of it. Depth and roll: stop the joint at its bound.
  auto stopAt = [&](int i, double lo, double hi) {
    // Brake ahead of the bound (v^2 <= 2 a distance), then never step past it.
    double const a = L.max_acceleration(i);
    v(i) = std::clamp(v(i), -std::sqrt(2.0 * a * std::max(0.0, q(i) - lo)), std::sqrt(2.0 * a * std::max(0.0, hi - q(i))));
    double const next = q(i) + v(i) * dt;
    if (next > hi) v(i) = std::max(0.0, (hi - q(i)) / dt);
    if (next < lo) v(i) = std::min(0.0, (lo - q(i)) / dt);
  };
  stopAt(kDepth, L.min_depth, L.max_depth);
  stopAt(kRoll, L.min_roll, L.max_roll);
  // Cone: brake the outward radial rate ahead of the boundary, then remove what would leave it.
  Eigen::Vector2d const p(q(kPan), q(kTilt));
  Eigen::Vector2d w(v(kPan), v(kTilt));
  if (p.norm() > 1e-12) {
    Eigen::Vector2d const radial = p.normalized();
    double const out = w.dot(radial);
    double const brake = std::sqrt(2.0 * std::min(L.max_acceleration(kPan), L.max_acceleration(kTilt)) *
                                   std::max(0.0, L.max_cone - p.norm()));
    if (out > brake) w -= (out - brake) * radial;
  }
  Eigen::Vector2d const next = p + w * dt;
  if (next.norm() > L.max_cone) {
    double const r = p.norm();
    if (r > 1e-12) {
      Eigen::Vector2d const radial = p / r;
      double const out = w.dot(radial);
      // Allowed outward rate: what reaches the cone boundary (tangential motion kept).
      Eigen::Vector2d const tangential = w - out * radial;
      double const allowed = std::max(0.0, (L.max_cone - r) / dt);
      w = tangential + std::min(out, allowed) * radial;
      // The tangential step itself moves outward a little on a circle: shrink until inside.
      for (int it = 0; it < 30 && (p + w * dt).norm() > L.max_cone; ++it) w *= 0.7;
      if ((p + w * dt).norm() > L.max_cone) w.setZero();
    } else {
      w *= L.max_cone / (w.norm() * dt);
    }
    v(kPan) = w.x();
    v(kTilt) = w.y();
  }
  return v;
}

}  // namespace endo_guidance::control
