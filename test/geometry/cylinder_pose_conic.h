// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The paper's literal form of the cylinder pose, an independent model for the tests and the
// benchmark of the production closed form (geometry/cylinder_pose.h).
#pragma once

#include "endo_guidance/geometry/cylinder_pose.h"

namespace endo_guidance::test {

/// Cylinder pose by the two-step closed form of the degenerate conic, [Doignon07] Eqs. (7)-(13).
///
/// In normalised coordinates the apparent contour is the degenerate conic
/// \f[ C \propto \mathbf{n}_0\mathbf{n}_1^\top + \mathbf{n}_1\mathbf{n}_0^\top,\qquad
///     \lambda C = \mathbf{p}_0\mathbf{p}_0^\top - \tau (I - \mathbf{d}\mathbf{d}^\top),\quad \tau = \delta^2 - r_c^2 \f]
/// (Eq. (10)). Step 1: with M = p0 p0^T + tau d d^T, the 6 independent entries of
/// M - lambda C - tau I = 0 form a 6x8 homogeneous system in (vech M, lambda, tau) whose null
/// space is 2-D (Eq. (11)); rank M = 2 gives det(C + s I) = 0, a quadratic in s = tau/lambda
/// once the root s = 0 (det C = 0) is divided out (Eq. (12)); the line orientation selects the
/// root s > 0. Step 2: tr M = delta^2 + tau fixes the scale, lambda = r_c^2 / (tr(C + sI) - 2s)
/// and tau = s lambda (Eq. (9)). The axis follows from the eigenvectors of M (d for the
/// eigenvalue tau, p0 for delta^2) (Eq. (13)). Same result and checks as estimateCylinderPose(),
/// which serves as its verification; no covariance is computed here.
geometry::CylinderPoseResult estimateCylinderPoseConic(Eigen::Matrix3d const& K, double radius, geometry::ImageLine const& l0,
                                                       geometry::ImageLine const& l1,
                                                       geometry::CylinderPoseOptions const& options = {});

}  // namespace endo_guidance::test
