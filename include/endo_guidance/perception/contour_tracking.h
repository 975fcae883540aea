// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <array>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"
#include "endo_guidance/perception/contour_fit.h"
#include "endo_guidance/perception/field_of_view.h"
#include "endo_guidance/perception/tip_location.h"

namespace endo_guidance::perception {

struct ContourTrackingParams {
  /// Frames: the full detection (seeds, regions, line pairs) runs this often; in the frames
  /// between, each shaft found is refined directly from its lines of the frame before. A shaft
  /// that cannot be followed makes that frame a detection frame at once. 1: detect every frame;
  /// 0 (default): the detector's own cadence (ShaftDetector::detectEvery(): the learned
  /// detector's network every 8th frame, the colour method every frame; docs/performance.md).
  int detect_every = 0;
  double max_width_change = 0.25;  ///< the shaft's width at the entry may change this much (relative, plus 2 px) per frame
  double coarse_step_px = 6.0;     ///< full-res: profile spacing of the wide pass (the narrow one uses refine_step_px)
};

/// A shaft followed from frame to frame: its contour, the sub-pixel edge points behind each
/// line, and the extent of the edges fitted along the axis, from the entry.
struct TrackedShaft {
  geometry::ApparentContour contour;
  std::array<std::vector<Eigen::Vector2d>, 2> edges;
  double edge_start = 0.0;    ///< full-res px from the entry along the axis: where the fitted edges begin
  double edge_end = 0.0;      ///< ... and end (at most the detection's: see trackContour)
  double detected_edge_end = 0.0;  ///< ... where the detection's edges ended
  std::optional<TipColours> tip_colours;  ///< the colours the detection located the tip with (nullopt: the tip is held)
};

/// The tracked state of a shaft found by the detection (its contour and edge points).
TrackedShaft startTrack(geometry::ApparentContour const& contour, std::array<std::vector<Eigen::Vector2d>, 2> const& edges,
                        std::optional<TipColours> const& tip_colours = std::nullopt);

/// Contour tracking: the shaft of the previous frame found again in `bgr` (full resolution)
/// without segmenting it. Each contour line is refined as in refineContour() -- a wide sub-pixel
/// pass about last frame's line, then a narrow one about its result -- over the extent of the
/// edges fitted at the detection (cut at the tip). The entry moves to where the new axis
/// leaves the field of view; the tip is located on the frame with the colours the detection
/// located it with (locateTipWithColours()), so that a servo moving the instrument in depth sees
/// it move between detections, by the same measure; where it cannot be located (or the detection
/// did not locate it), last frame's tip moved onto the new axis stands. Refused (nullopt, with the reason) when a
/// side has too few edge points or too large a residual, the lines diverge or cross, or the
/// width jumps: the caller then runs the full detection.
struct TrackingResult {
  std::optional<TrackedShaft> shaft;
  ContourRejection rejection = ContourRejection::kNone;
};
/// `fov` (optional, at processing scale `scale`): the entry is moved to where the new axis leaves it.
TrackingResult trackContour(TrackedShaft const& previous, cv::Mat const& bgr, ContourLinesParams const& params,
                            ContourTrackingParams const& tracking, FieldOfView const* fov = nullptr, int scale = 1);

}  // namespace endo_guidance::perception
