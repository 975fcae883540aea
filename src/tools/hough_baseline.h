// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The plain OpenCV baseline of the issue "Instrument segmentation and the offline pipeline",
// for comparison on the same scenes (endo_guidance_eval_synthetic --baseline): not part of the
// pipeline, and tuned on the synthetic scenes only, as the issue describes it.
#pragma once

#include <opencv2/core.hpp>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"

namespace endo_guidance::tools {

struct HoughBaselineParams {
  double blur_sigma = 1.0;          ///< px, Gaussian smoothing of the chroma image before Canny
  double canny_low = 15.0, canny_high = 40.0;  ///< Canny hysteresis thresholds (chroma units)
  int hough_threshold = 30;         ///< HoughLinesP accumulator votes
  double min_segment_px = 30.0;     ///< HoughLinesP minimum segment length
  double max_gap_px = 8.0;          ///< HoughLinesP maximum gap within a segment
  double max_pair_angle_deg = 5.0;  ///< the two sides of a shaft are near-parallel
  double min_width_px = 6.0, max_width_px = 250.0;  ///< distance between the two sides
  double min_overlap = 0.5;         ///< the sides overlap along the axis over this fraction of the shorter
  double max_strip_ratio = 0.5;     ///< median chroma between the sides over the tissue's beside them (grey strip)
  double refit_band_px = 1.5;       ///< Canny edge pixels within this distance of a side refit it
  double collinear_px = 2.0;        ///< segments within this distance (and the pair angle) of a side belong to it
  double max_entry_border_px = 20.0;  ///< a shaft's strip starts this close to the image border (it enters across it)
  double duplicate_px = 12.0;       ///< a pair whose axis midpoint is this close to a found shaft's axis (and parallel) is the same shaft
};

/// Shafts found by the baseline: Canny + probabilistic Hough on the chroma (max - min) image,
/// pairs of near-parallel segments around a grey strip, each side refitted by least squares on
/// the Canny edge pixels near it; a strip must start at the image border (instruments enter
/// across it: the baseline knows no field of view). Lines in ApparentContour order and
/// orientation (left side first walking from the entry, normals toward the shaft); the entry is
/// the strip's end nearer the image border. No residuals or covariances.
std::vector<geometry::ApparentContour> detectShaftsHough(cv::Mat const& bgr, HoughBaselineParams const& p = {});

}  // namespace endo_guidance::tools
