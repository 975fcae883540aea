// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"
#include "endo_guidance/geometry/plucker_line.h"

namespace endo_guidance::geometry {

/// Result of attaching a region to one of m insertion points, [Doignon07] Eq. (6).
struct Attachment {
  int index = -1;          ///< index into the candidates, -1 = rejected
  double distance = 0.0;   ///< distance to the nearest candidate (px, rad or m, see below)
  double second = 0.0;     ///< distance to the second nearest (+inf if none): ambiguity margin
};

/// Image form of Eq. (6): attach the image line l of an imaged axis to the image point i_j with
/// \f[ j^* = \arg\min_j |\mathbf{l}^\top \mathbf{i}_j| < \tau \f]
/// with l normalised (a^2 + b^2 = 1) so that, for a finite i_j = (u, v, 1), |l^T i_j| is the
/// distance in pixels (compared to tau_px); for an image point at infinity (w = 0) the angle
/// between the line and the direction (u, v) is compared to tau_rad instead.
Attachment classifyImageLine(ImageLine const& l, std::vector<Eigen::Vector3d> const& image_points, double tau_px,
                             double tau_rad = 0.02);

/// 3D form of Eq. (6): the axis passes through the insertion point I_j at the smallest
/// distance, if below tau_m (metres).
Attachment classifyAxis(PluckerLine const& axis, std::vector<Eigen::Vector3d> const& points, double tau_m);

}  // namespace endo_guidance::geometry
