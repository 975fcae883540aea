// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"
#include "endo_guidance/geometry/plucker_line.h"

namespace endo_guidance::geometry {

/// Image of an insertion point: the common point of the imaged axes, [Doignon07] Eq. (5).
struct ImagePointEstimate {
  bool ok = false;
  /// Homogeneous pixel (u, v, w), |.| = 1, w >= 0; w = 0: at infinity in the direction (u, v).
  Eigen::Vector3d point = Eigen::Vector3d::Zero();
  double rms_px = 0.0;        ///< RMS distance of the (inlier) lines to a finite point, pixels
  std::vector<int> inliers;   ///< robust form: indices of the lines that agree
  bool atInfinity() const { return std::abs(point.z()) < 1e-9; }
  /// The pixel (u/w, v/w); only meaningful when !atInfinity().
  Eigen::Vector2d pixel() const { return point.head<2>() / point.z(); }
};

/// Homogeneous image point of a 3D point (camera frame): x ~ K X, unit norm, w >= 0 (w = 0 for
/// Z = 0); zero when K X is zero or not finite (no image).
Eigen::Vector3d projectPointHomogeneous(Eigen::Matrix3d const& K, Eigen::Vector3d const& X);

/// The image of an axis: the line through its projection, Eq. (4) (alias of PluckerLine::project).
std::optional<ImageLine> imageOfAxis(Eigen::Matrix3d const& K, PluckerLine const& axis);

/// Least-squares common point of n >= 2 image lines (Eq. (5)): null vector of the stacked lines
/// l_i^T x = 0, computed in coordinates centred on `centre_px` and scaled by `scale_px` (e.g. the
/// image centre and half its diagonal) so that far and infinite points stay well conditioned.
ImagePointEstimate intersectImageLines(std::vector<ImageLine> const& lines,
                                       Eigen::Vector2d const& centre_px = Eigen::Vector2d::Zero(),
                                       double scale_px = 1000.0);

/// Robust form: least median of squares over pairs of lines (residuals measured as sines on the
/// normalised projective plane, so points at infinity are handled), then Eq. (5) on the inliers.
ImagePointEstimate intersectImageLinesRobust(std::vector<ImageLine> const& lines,
                                             Eigen::Vector2d const& centre_px = Eigen::Vector2d::Zero(),
                                             double scale_px = 1000.0, double inlier_fraction = 0.5,
                                             std::uint64_t seed = 1);

}  // namespace endo_guidance::geometry
