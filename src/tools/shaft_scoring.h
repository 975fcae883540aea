// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The strict scoring of detected shafts against mask shafts (endo_guidance_eval_real): a
// detection finds a shaft when each of the mask's two sides lies, by its median, within a few
// pixels of the detection's matching contour line.
#pragma once

#include <Eigen/Core>
#include <array>
#include <opencv2/core.hpp>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"

namespace endo_guidance::tools {

/// One mask shaft's two sides: its boundary pixels, less those within kMaskMarginPx of the image
/// border and of the jaws, split by the mask's principal axis.
struct MaskShaft {
  std::array<std::vector<Eigen::Vector2d>, 2> sides;
  int pixels = 0;
};
inline constexpr int kMaskMarginPx = 4;
/// `shaft`: CV_8U, non-zero on this shaft's pixels; `jaws`: CV_8U, non-zero on jaw pixels (may be
/// empty). A side without pixels leaves the shaft unscorable (MaskShaft::sides empty).
MaskShaft maskShaft(cv::Mat const& shaft, cv::Mat const& jaws);

/// The thresholds (px) on the median side-to-line distance at which shafts are counted found;
/// the last one decides which detections are false.
inline constexpr std::array<double, 3> kFoundPx{2.0, 5.0, 10.0};

struct StrictScore {
  int shafts = 0, detections = 0;
  std::array<int, 3> found{};   ///< per kFoundPx
  int false_detections = 0;     ///< detections that find no shaft at kFoundPx.back()
  std::vector<double> side_median_px;  ///< per side of each shaft found at kFoundPx.back(): its median distance
  std::vector<int> match;       ///< per shaft: the detection that finds it at kFoundPx.back(), or -1
  StrictScore& operator+=(StrictScore const& o);  ///< (the counts and medians; `match` stays this one's)
};

/// The median distance of the side's pixels to line l (a^2 + b^2 = 1).
double sideMedianPx(std::vector<Eigen::Vector2d> const& side, geometry::ImageLine const& l);
/// The cost of detection c finding shaft s: the larger side median with the sides paired to the
/// lines the better way round.
double findCost(MaskShaft const& s, geometry::ApparentContour const& c);
/// One-to-one matching, cheapest pairs first, separately at each threshold.
StrictScore scoreStrict(std::vector<MaskShaft> const& shafts, std::vector<geometry::ApparentContour> const& detections);

}  // namespace endo_guidance::tools
