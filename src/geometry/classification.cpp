// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/geometry/classification.h"

#include <cmath>
#include <limits>

namespace endo_guidance::geometry {

namespace {
// Keeps the nearest and second nearest; thresholds each candidate with its own tau.
struct Best {
  Attachment a{-1, std::numeric_limits<double>::infinity(), std::numeric_limits<double>::infinity()};
  int nearest = -1;
  bool nearest_ok = false;
  void offer(int j, double dist, bool within) {
    if (dist < a.distance) {
      a.second = a.distance;
      a.distance = dist;
      nearest = j;
      nearest_ok = within;
    } else if (dist < a.second) {
      a.second = dist;
    }
  }
  Attachment result() {
    a.index = nearest_ok ? nearest : -1;
    return a;
  }
};
}  // namespace

Attachment classifyImageLine(ImageLine const& l_in, std::vector<Eigen::Vector3d> const& pts, double tau_px,
                             double tau_rad) {
  Best best;
  auto const l = normalizeLine(l_in);
  if (!l) return best.result();
  for (std::size_t j = 0; j < pts.size(); ++j) {
    Eigen::Vector3d const& i = pts[j];
    double const w = i.z();
    if (std::abs(w) > 1e-12 * i.head<2>().norm()) {
      double const dist = std::abs(l->dot(i / w));  // Eq. (6), pixels
      best.offer(static_cast<int>(j), dist / tau_px, dist < tau_px);
    } else {
      double const dn = i.head<2>().norm();
      if (!(dn > 0.0)) continue;
      // Direction (u, v) must be parallel to the line: |n . dir| = |sin(angle)|.
      double const ang = std::asin(std::min(1.0, std::abs(l->head<2>().dot(i.head<2>() / dn))));
      best.offer(static_cast<int>(j), ang / tau_rad, ang < tau_rad);
    }
  }
  Attachment a = best.result();
  // Report distances in the unit of the nearest candidate (scaled by its tau above).
  if (best.nearest >= 0) {
    double const unit = std::abs(pts[static_cast<std::size_t>(best.nearest)].z()) > 0.0 ? tau_px : tau_rad;
    a.distance *= unit;
    a.second *= unit;
  }
  return a;
}

Attachment classifyAxis(PluckerLine const& axis, std::vector<Eigen::Vector3d> const& points, double tau_m) {
  Best best;
  for (std::size_t j = 0; j < points.size(); ++j) {
    double const dist = axis.distanceTo(points[j]);  // Eq. (6) in 3D
    best.offer(static_cast<int>(j), dist, dist < tau_m);
  }
  return best.result();
}

}  // namespace endo_guidance::geometry
