// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// Shared helpers of the perception tests: exact contours and their distance to the truth.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>

#include "endo_guidance/geometry/apparent_contour.h"

namespace endo_guidance::test {

/// A contour along p0 -> p1 (entry -> tip) with parallel lines h px either side of its axis.
inline geometry::ApparentContour bandContour(Eigen::Vector2d const& p0, Eigen::Vector2d const& p1, double h) {
  Eigen::Vector2d const u = (p1 - p0).normalized(), n(-u.y(), u.x());
  geometry::ApparentContour c;
  for (int s = 0; s < 2; ++s) {
    Eigen::Vector2d const q = p0 + (s == 0 ? h : -h) * n;
    Eigen::Vector3d l(n.x(), n.y(), -n.dot(q));
    if (l.dot(p0.homogeneous()) < 0.0) l = -l;  // the shaft on the positive side
    c.lines[s] = l;
  }
  c.entry_px = p0;
  c.tip_px = p1;
  return c;
}

/// The larger distance of contour c's two lines to the true ones, at the feet of c's own entry
/// and tip (over the extent c reports).
inline double lineErrorOverItsExtent(geometry::ApparentContour const& c, geometry::ApparentContour const& truth) {
  double e = 0.0;
  for (int l = 0; l < 2; ++l)
    for (Eigen::Vector2d const& q : {c.entry_px, c.tip_px})
      e = std::max(e, std::abs(c.lines[l].dot(geometry::footOnLine(truth.lines[l], q).homogeneous())));
  return e;
}

}  // namespace endo_guidance::test
