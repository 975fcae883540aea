// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/geometry/shaft_tracking.h"

#include <algorithm>
#include <cmath>

namespace endo_guidance::geometry {

void ShaftTracker::assign(std::vector<ApparentContour>& contours) {
  std::vector<bool> used(previous_.size(), false);
  for (ApparentContour& c : contours) {
    Eigen::Vector3d const l = imageAxis(c);
    int best = -1;
    double bd = params_.max_distance_px;
    for (std::size_t j = 0; j < previous_.size(); ++j) {
      if (used[j]) continue;
      Eigen::Vector3d const lp = imageAxis(previous_[j]);
      double const ang = std::acos(std::min(1.0, std::abs(l.head<2>().dot(lp.head<2>())))) * 180.0 / M_PI;
      if (ang > params_.max_angle_deg) continue;
      Eigen::Vector2d const& e = previous_[j].entry_px;
      Eigen::Vector2d const& t = previous_[j].tip_px;
      double const d = 0.5 * (std::abs(l.dot(Eigen::Vector3d(e.x(), e.y(), 1))) + std::abs(l.dot(Eigen::Vector3d(t.x(), t.y(), 1))));
      if (d < bd) {
        bd = d;
        best = static_cast<int>(j);
      }
    }
    if (best >= 0) {
      used[static_cast<std::size_t>(best)] = true;
      c.track_id = previous_[static_cast<std::size_t>(best)].track_id;
    } else {
      c.track_id = next_id_++;
    }
  }
  previous_ = contours;
}

}  // namespace endo_guidance::geometry
