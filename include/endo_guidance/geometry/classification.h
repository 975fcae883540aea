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
  double distance = 0.0;   ///< distance to the nearest candidate (m)
  double second = 0.0;     ///< distance to the second nearest (+inf if none): ambiguity margin
};

/// 3D form of Eq. (6): the axis passes through the insertion point I_j at the smallest
/// distance, if below tau_m (metres).
Attachment classifyAxis(PluckerLine const& axis, std::vector<Eigen::Vector3d> const& points, double tau_m);

}  // namespace endo_guidance::geometry
