// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <optional>

#include "endo_guidance/geometry/cylinder_pose.h"

namespace endo_guidance::geometry {

/// The axis of a shaft through its insertion point: the measured axis (4 DOF, from the two
/// contour lines, with its covariance) fused with the insertion point it is attached to.
///
/// The instrument pivots about its trocar, so its axis passes through the insertion point I of
/// that frame. I is known as the estimate Î (covariance Σ_I), about which the trocar itself moves
/// (breathing: RMS `point_motion_sigma` per axis, isotropic). The fused axis is the line
/// (d, I × d) through a point I, |d| = 1, minimising ([Doignon07] Eq. (1)-(2) for the Plücker form)
/// \f[ \| \Sigma_L^{+1/2} ( (\mathbf{d}, \mathbf{I} \times \mathbf{d}) - (\hat{\mathbf{d}}, \hat{\mathbf{m}}) ) \|^2
///   + (\mathbf{I} - \hat{\mathbf{I}})^\top (\Sigma_I + \sigma_b^2 \mathbf{1})^{-1} (\mathbf{I} - \hat{\mathbf{I}}) \f]
/// (Σ_L^+: the pseudo-inverse of the measured axis's rank-4 covariance) by Gauss-Newton over the
/// 5 parameters (2 for d in the tangent plane of d̂, 3 for I), started at (d̂, Î). The result's
/// covariance is the Gauss-Newton one propagated to (d, m). A short shaft's direction is then
/// fixed by its trocar (docs/accuracy.md measures it).
struct ConstrainedAxis {
  CylinderPose pose;              ///< the fused axis (d: entry -> tip, as measured), covariance of (d, m)
  Eigen::Vector3d pivot = Eigen::Vector3d::Zero();  ///< the fused insertion point of this frame, metres
  double chi2 = 0.0;              ///< the minimised cost: consistency of the axis with the point (5 DOF of data beyond the fit: about 2 expected)
};

/// nullopt (nothing is guessed) when the measured covariance is zero or not finite, the point or
/// its covariance is not finite, Σ_I + σ_b² 1 is not positive definite, or the iteration does not
/// converge to a finite line.
std::optional<ConstrainedAxis> constrainAxisToPoint(CylinderPose const& measured, Eigen::Vector3d const& point,
                                                    Eigen::Matrix3d const& point_covariance, double point_motion_sigma);

}  // namespace endo_guidance::geometry
