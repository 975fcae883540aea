// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <array>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "endo_guidance/perception/contour_params.h"
#include "endo_guidance/perception/field_of_view.h"
#include "endo_guidance/perception/region_growing.h"
#include "endo_guidance/perception/side_fit.h"

namespace endo_guidance::perception {

/// One straight side of a shaft mask (processing px): its line (a, b, c), a^2 + b^2 = 1, the
/// normal (a, b) pointing into the mask, and its boundary points where it faces the other side.
struct MaskSide {
  Eigen::Vector3d line = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector2d> points;
};

/// A shaft in a mask as the two straight sides that face each other across it (processing px).
/// `entry` and `far`: the ends of their common stretch on the axis between them; the entry is the
/// end from which the mask runs on to the view's edge (moved there), else the end nearer to it.
struct MaskLinePair {
  std::array<MaskSide, 2> sides;
  Eigen::Vector2d entry = Eigen::Vector2d::Zero(), far = Eigen::Vector2d::Zero();
  double width = 0.0;    ///< median distance between the sides (processing px)
  double support = 0.0;  ///< boundary points of the shorter side beside the other, times the fill
};

/// The shafts of a probability mask (CV_32F in [0, 1], the field of view's size) as pairs of
/// straight sides. Its boundary points (p >= 1/2, away from the view's edge; where `beyond`, the
/// instrument's probability, goes on outside, the shaft meets its own jaws: no side) give the
/// sides below; with `side_probability` (the network's side map; may be empty), a side is one only
/// where min_side_points of its points lie at p >= 1/2 there (not a tool's head, an occluder's edge
/// or the network's noise), and keeps all of its points:
/// - first, each connected part of the mask that is one shaft: its outline split by its principal
///   axis is one straight side on each half (LMedS, [Rousseeuw87]), facing each other within 35 deg
///   (a shaft near the lens narrows fast toward its tip; the border may cut it anywhere: the sides
///   of a stub that both run into the view's edge face each other up to the farther one);
/// - then, from the points left, a Hough transform of oriented lines ([Duda72]), each point voting
///   about its own gradient's direction only ([OGorman76]), so a side's votes do not mix with
///   those of the facing side. Each peak is a side: its points within 2 px, refined by total least
///   squares. Two sides pair when they face each other within max_angle_deg, overlap over
///   min_side_points and over half their distance, lie min_width_px apart or more and the strip
///   between them is mask (min_fill); the best supported pairs first, each side used once, each
///   keeping its points where the two face each other (beyond, a side's line runs on along a jaw
///   or another shaft). Unlike the components of the mask, this keeps shafts that touch or cross
///   apart and joins the pieces of a broken one.
std::vector<MaskLinePair> findMaskLinePairs(cv::Mat const& probability, FieldOfView const& fov, int scale,
                                            ContourLinesParams const& params, cv::Mat const& beyond = cv::Mat(),
                                            cv::Mat const& side_probability = cv::Mat());

/// The pair as the contour fit's input at full resolution (x_full = scale x + (scale - 1) / 2):
/// its lines with the shaft on their positive side, the points behind them, entry and far end.
SideFit sideFitOf(MaskLinePair const& pair, int scale);

/// The pair's region: the mask (CV_8U, processing px) inside the strip between its sides widened
/// by 2 px, from behind the entry to 2.5 widths past the far end (the tip), for the contour fit's
/// tip search and fill check; nullopt when no mask is there.
std::optional<Region> regionOf(MaskLinePair const& pair, cv::Mat const& mask);

}  // namespace endo_guidance::perception
