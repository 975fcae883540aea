// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"

namespace endo_guidance::geometry {

struct ShaftTrackingParams {
  double max_angle_deg = 12.0;    ///< between the imaged axes of one shaft in consecutive frames
  double max_distance_px = 25.0;  ///< mean distance of the previous entry and tip to the new axis
};

/// Frame-to-frame identity of the shafts: each new apparent contour takes the track id of the
/// nearest unused contour of the previous frame (imaged axes within an angle, previous entry and
/// tip near the new axis), else a new id. Greedy in the order given. Not thread-safe.
class ShaftTracker {
 public:
  explicit ShaftTracker(ShaftTrackingParams const& params = {}) : params_(params) {}
  /// Sets track_id of every contour and remembers them for the next frame.
  void assign(std::vector<ApparentContour>& contours);
  void reset() { previous_.clear(); }
  void setParams(ShaftTrackingParams const& p) { params_ = p; }

 private:
  ShaftTrackingParams params_;
  std::vector<ApparentContour> previous_;
  int next_id_ = 0;
};

}  // namespace endo_guidance::geometry
