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

/// Whether K is a camera matrix: finite, upper triangular, positive focal lengths, K(2,2) = 1.
bool validCameraMatrix(Eigen::Matrix3d const& K);

/// The unit normals of the two interpretation planes n_i = K^T l_i / |K^T l_i|, orientation kept
/// ([Doignon07] Eq. (7)); nullopt for a non-finite line or one at infinity.
struct InterpretationPlanes {
  Eigen::Vector3d n0, n1;
};
std::optional<InterpretationPlanes> interpretationPlanes(Eigen::Matrix3d const& K, ImageLine const& l0, ImageLine const& l1);

/// The checks on the distance delta of a recovered axis from the optical centre: outside the
/// cylinder, within [min_distance, max_distance].
CylinderPoseStatus checkAxisDistance(double delta, double radius, CylinderPoseOptions const& options);

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
