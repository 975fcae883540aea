// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <array>
#include <optional>

#include "endo_guidance/geometry/apparent_contour.h"
#include "endo_guidance/geometry/plucker_line.h"

namespace endo_guidance::geometry {

/// Outcome of a cylinder pose computation. Anything but kOk comes with no pose.
enum class CylinderPoseStatus {
  kOk = 0,
  kInvalidInput,          ///< non-finite numbers, a = b = 0, radius <= 0 or K not invertible
  kIdenticalPlanes,       ///< the two interpretation planes coincide (same or opposite line)
  kZeroWidth,             ///< the oriented lines leave no width for the shaft (axis at infinity)
  kCameraInsideCylinder,  ///< the planes are farther apart than a cylinder of radius r allows
  kTooClose,              ///< axis closer to the optical centre than options.min_distance
  kTooFar,                ///< axis farther than options.max_distance
  kWrongSide,             ///< the given shaft pixel is not on the positive side of both lines
  kNoRealSolution,        ///< the conic form's quadratic in s has no admissible root
};
char const* toString(CylinderPoseStatus s);

struct CylinderPoseOptions {
  double min_distance = 0.005;  ///< metres; the optical centre must be at least this far from the axis
  double max_distance = 2.0;    ///< metres; a farther axis is flagged (the shaft is then a few px wide)
  double min_plane_sine = 1e-9; ///< |n0 x n1| below this: the planes coincide
  bool compute_covariance = true;
};

/// The axis of a cylinder of revolution in the camera frame (4 DOF) and its uncertainty.
struct CylinderPose {
  PluckerLine axis;                                                      ///< d: entry -> tip, m in metres
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();  ///< of (d, m)
  double distance = 0.0;                                                 ///< |m|, metres
};

struct CylinderPoseResult {
  CylinderPoseStatus status = CylinderPoseStatus::kInvalidInput;
  CylinderPose pose;
  bool ok() const { return status == CylinderPoseStatus::kOk; }
};

/// Cylinder pose from its apparent contour, direct geometric form.
///
/// Each oriented pixel line l_i defines the interpretation plane through the optical centre with
/// unit normal n_i = K^T l_i / |K^T l_i| ([Doignon07] Eq. (7)); both planes are tangent to the
/// cylinder, so with d the axis direction, p0 = d x m its closest point to the centre and
/// delta = |m|:
/// \f[ \mathbf{n}_i \cdot \mathbf{d} = 0,\qquad \mathbf{n}_i \cdot \mathbf{p}_0 = r_c \f]
/// hence
/// \f[ \mathbf{d} = \frac{\mathbf{n}_0 \times \mathbf{n}_1}{\|\mathbf{n}_0 \times \mathbf{n}_1\|},\quad
///     \delta = \frac{2 r_c}{\|\mathbf{n}_0 + \mathbf{n}_1\|} = \frac{r_c}{\sin(\alpha/2)},\quad
///     \mathbf{p}_0 = \frac{\delta^2}{2 r_c}(\mathbf{n}_0 + \mathbf{n}_1),\quad \mathbf{m} = \mathbf{p}_0 \times \mathbf{d} \f]
/// with alpha the angle between the planes' unoriented normals (the wedge holding the shaft).
/// The orientation of the lines (shaft on the positive side) picks the wedge; their order
/// (ApparentContour convention) picks the sign of d.
/// `inside_px`, if given, is a pixel known to be on the shaft (e.g. the tip): checked against
/// both lines (kWrongSide).
/// Line covariances, if non-zero, are propagated to pose.covariance (first order).
CylinderPoseResult estimateCylinderPose(Eigen::Matrix3d const& K, double radius, ImageLine const& l0,
                                        ImageLine const& l1, CylinderPoseOptions const& options = {},
                                        std::optional<Eigen::Vector2d> const& inside_px = std::nullopt,
                                        Eigen::Matrix3d const& cov_l0 = Eigen::Matrix3d::Zero(),
                                        Eigen::Matrix3d const& cov_l1 = Eigen::Matrix3d::Zero());

/// Convenience: pose from an ApparentContour (its lines, covariances and tip as inside pixel).
CylinderPoseResult estimateCylinderPose(Eigen::Matrix3d const& K, double radius, ApparentContour const& contour,
                                        CylinderPoseOptions const& options = {});

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
CylinderPoseResult estimateCylinderPoseConic(Eigen::Matrix3d const& K, double radius, ImageLine const& l0,
                                             ImageLine const& l1, CylinderPoseOptions const& options = {});

/// Forward model: the apparent contour (two oriented pixel lines, ApparentContour order) of the
/// cylinder of the given axis and radius seen by camera K. nullopt if the optical centre is
/// inside or on the cylinder (|m| <= r) or a contour line is at infinity.
/// \f[ \mathbf{n}_{0,1} = \frac{r_c}{\delta}\hat{\mathbf{p}}_0 \pm \sqrt{1 - r_c^2/\delta^2}\,\hat{\mathbf{m}},\qquad
///     \mathbf{l}_i \propto K^{-\top}\mathbf{n}_i \f]
std::optional<std::array<ImageLine, 2>> projectCylinder(Eigen::Matrix3d const& K, PluckerLine const& axis, double radius);

/// The point of the axis nearest to the viewing ray of pixel px (e.g. the tip's 3D position).
/// nullopt if the ray is parallel to the axis.
std::optional<Eigen::Vector3d> backProjectOntoAxis(Eigen::Matrix3d const& K, PluckerLine const& axis,
                                                   Eigen::Vector2d const& px);
/// The same for a viewing ray given by its direction from the optical centre (any length; e.g.
/// a point known on that ray: a tip found on another estimate of the axis).
std::optional<Eigen::Vector3d> backProjectOntoAxis(PluckerLine const& axis, Eigen::Vector3d const& ray);

}  // namespace endo_guidance::geometry
