// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <optional>

namespace endo_guidance::geometry {

/// An oriented 3D line in Plücker coordinates (direction d, moment m), see [Doignon07] Sec. 2.
/// \f[ \mathbf{m} = \mathbf{p} \times \mathbf{d}, \qquad \|\mathbf{d}\| = 1,\ \mathbf{d}\cdot\mathbf{m} = 0 \f]
/// for any point p on the line; |m| is the distance of the line to the origin of its frame.
/// Invariant: |d| = 1 and d.m = 0 (enforced by the factories; the raw constructor normalises).
class PluckerLine {
 public:
  PluckerLine() : d_(Eigen::Vector3d::UnitZ()), m_(Eigen::Vector3d::Zero()) {}

  /// From a direction (any non-zero length) and a moment; the pair is normalised so that
  /// |d| = 1 and the component of m along d is removed. Returns nullopt if |d| ~ 0 or not finite.
  static std::optional<PluckerLine> fromDirectionMoment(Eigen::Vector3d const& d, Eigen::Vector3d const& m);
  /// The line through point p with direction d.
  static std::optional<PluckerLine> fromPointDirection(Eigen::Vector3d const& p, Eigen::Vector3d const& d);
  /// The line through p then q (direction p -> q). nullopt if p ~ q.
  static std::optional<PluckerLine> through(Eigen::Vector3d const& p, Eigen::Vector3d const& q);

  Eigen::Vector3d const& direction() const { return d_; }
  Eigen::Vector3d const& moment() const { return m_; }

  /// Point of the line closest to the origin: p0 = d x m.
  Eigen::Vector3d closestPointToOrigin() const { return d_.cross(m_); }
  /// Distance of the line to the origin, |m|.
  double distanceToOrigin() const { return m_.norm(); }
  /// Euclidean distance of point x to the line: |d x (x - p)| = |x x d - m|.
  double distanceTo(Eigen::Vector3d const& x) const { return (x.cross(d_) - m_).norm(); }
  /// Closest point of the line to x.
  Eigen::Vector3d closestPointTo(Eigen::Vector3d const& x) const {
    Eigen::Vector3d const p0 = closestPointToOrigin();
    return p0 + d_ * d_.dot(x - p0);
  }
  /// Point at signed arc length t from the closest point to the origin.
  Eigen::Vector3d pointAt(double t) const { return closestPointToOrigin() + t * d_; }

  /// Same line, opposite orientation (-d, -m).
  PluckerLine reversed() const { return PluckerLine(-d_, -m_, Raw{}); }

  /// Line expressed in frame a, given the rigid motion aMb (this line in frame b):
  /// \f[ \mathbf{d}_a = R\mathbf{d}_b,\quad \mathbf{m}_a = R\mathbf{m}_b + \mathbf{t}\times R\mathbf{d}_b \f]
  PluckerLine transformed(Eigen::Isometry3d const& aMb) const;

  /// Dual Plücker matrix L* (4x4, skew, rank 2), [Doignon07] Eq. (2):
  /// \f[ L^* = \begin{pmatrix} [\mathbf{d}]_\times & \mathbf{m} \\ -\mathbf{m}^\top & 0 \end{pmatrix},
  ///     \qquad L^* \tilde{\mathbf{X}} = 0 \iff \mathbf{X} \in L \f]
  /// The first three rows of L* (x,1) equal d x (x - p): their norm is the distance of x to the line.
  Eigen::Matrix4d dualMatrix() const;

  /// Image of the line through the pinhole camera K (pixels), [Doignon07] Eq. (4):
  /// \f[ \mathbf{l} \propto K^{-\top} \mathbf{m} \f]
  /// The plane through the optical centre containing the line has normal m. Returns the line
  /// scaled so that a^2 + b^2 = 1 with the sign of K^{-T} m kept; nullopt if the line passes
  /// through the optical centre (|m| ~ 0, the image is a point).
  std::optional<Eigen::Vector3d> project(Eigen::Matrix3d const& K) const;

  /// Smallest distance between two lines (0 if they intersect); parallel lines handled.
  double distanceTo(PluckerLine const& other) const;

 private:
  struct Raw {};
  PluckerLine(Eigen::Vector3d const& d, Eigen::Vector3d const& m, Raw) : d_(d), m_(m) {}
  Eigen::Vector3d d_;
  Eigen::Vector3d m_;
};

/// 3x3 skew-symmetric matrix [v]x with [v]x u = v x u.
inline Eigen::Matrix3d skew(Eigen::Vector3d const& v) {
  Eigen::Matrix3d s;
  s << 0, -v.z(), v.y(), v.z(), 0, -v.x(), -v.y(), v.x(), 0;
  return s;
}

}  // namespace endo_guidance::geometry
