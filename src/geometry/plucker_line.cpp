// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/geometry/plucker_line.h"

#include <cmath>

namespace endo_guidance::geometry {

std::optional<PluckerLine> PluckerLine::fromDirectionMoment(Eigen::Vector3d const& d, Eigen::Vector3d const& m) {
  double const n = d.norm();
  if (!(n > 1e-12) || !d.allFinite() || !m.allFinite()) return std::nullopt;
  Eigen::Vector3d const du = d / n;
  Eigen::Vector3d const mu = m / n;
  return PluckerLine(du, mu - du * du.dot(mu), Raw{});
}

std::optional<PluckerLine> PluckerLine::fromPointDirection(Eigen::Vector3d const& p, Eigen::Vector3d const& d) {
  double const n = d.norm();
  if (!(n > 1e-12) || !d.allFinite() || !p.allFinite()) return std::nullopt;
  Eigen::Vector3d const du = d / n;
  return PluckerLine(du, p.cross(du), Raw{});
}

std::optional<PluckerLine> PluckerLine::through(Eigen::Vector3d const& p, Eigen::Vector3d const& q) {
  return fromPointDirection(p, q - p);
}

PluckerLine PluckerLine::transformed(Eigen::Isometry3d const& aMb) const {
  Eigen::Matrix3d const R = aMb.linear();
  Eigen::Vector3d const d = R * d_;
  return PluckerLine(d, R * m_ + aMb.translation().cross(d), Raw{});
}

Eigen::Matrix4d PluckerLine::dualMatrix() const {
  Eigen::Matrix4d L = Eigen::Matrix4d::Zero();
  L.topLeftCorner<3, 3>() = skew(d_);  // Eq. (2)
  L.topRightCorner<3, 1>() = m_;
  L.bottomLeftCorner<1, 3>() = -m_.transpose();
  return L;
}

std::optional<Eigen::Vector3d> PluckerLine::project(Eigen::Matrix3d const& K) const {
  if (!(m_.norm() > 1e-12)) return std::nullopt;
  Eigen::Vector3d l = K.transpose().partialPivLu().solve(m_);  // Eq. (4): l ~ K^-T m
  double const ab = l.head<2>().norm();
  if (!(ab > 1e-15)) return std::nullopt;  // the line projects to the line at infinity
  return Eigen::Vector3d(l / ab);
}

double PluckerLine::distanceTo(PluckerLine const& o) const {
  Eigen::Vector3d const c = d_.cross(o.d_);
  double const s = c.norm();
  if (s < 1e-12) {  // parallel: distance of a point of o to this line
    return distanceTo(o.closestPointToOrigin());
  }
  // Reciprocal product d1.m2 + d2.m1 divided by |d1 x d2|.
  return std::abs(d_.dot(o.m_) + o.d_.dot(m_)) / s;
}

}  // namespace endo_guidance::geometry
