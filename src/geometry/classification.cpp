// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/geometry/classification.h"

#include <cmath>
#include <limits>

namespace endo_guidance::geometry {

namespace {
// Keeps the nearest and second nearest candidate, and whether the nearest is within its threshold.
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

Attachment classifyAxis(PluckerLine const& axis, std::vector<Eigen::Vector3d> const& points, double tau_m) {
  Best best;
  for (std::size_t j = 0; j < points.size(); ++j) {
    double const dist = axis.distanceTo(points[j]);  // Eq. (6) in 3D
    best.offer(static_cast<int>(j), dist, dist < tau_m);
  }
  return best.result();
}

}  // namespace endo_guidance::geometry
