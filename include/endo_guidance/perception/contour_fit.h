// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <array>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"
#include "endo_guidance/perception/contour_checks.h"
#include "endo_guidance/perception/contour_params.h"
#include "endo_guidance/perception/field_of_view.h"
#include "endo_guidance/perception/region_growing.h"
#include "endo_guidance/perception/side_fit.h"

namespace endo_guidance::perception {

/// [Doignon07] Sec. 3: the ordered region boundary is split in two classes at the boundary point
/// farthest from the seed (points on the FOV border excluded), a line is fitted to each class
/// (LMedS, then sub-pixel on the full-resolution image), and the region is rejected unless its
/// boundary is two straight, near-parallel lines around a shaft of some length and width.
/// `scale` maps processing pixels to full-resolution ones (p_full = scale p + (scale - 1) / 2).
struct ContourFit {
  std::optional<geometry::ApparentContour> contour;
  ContourRejection rejection = ContourRejection::kNone;
  int edge_points = 0;  ///< sub-pixel edge points behind both lines
  std::array<std::vector<Eigen::Vector2d>, 2> edges;  ///< those points, per contour line (contour order)
};
ContourFit fitApparentContour(Region const& region, FieldOfView const& fov, cv::Mat const& bgr_full, int scale,
                              ContourLinesParams const& params);

/// Cheap quality of a side pair for choosing between candidate regions: one wide, sparse edge
/// pass per side; (edge points) / (1 + RMS residual), or -1 when a side has no edge.
double scoreSides(SideFit& sides, cv::Mat const& bgr_full, ContourLinesParams const& params);
/// The second half: sub-pixel lines, order, tip and the length/width checks.
ContourFit refineContour(SideFit const& sides, Region const& region, FieldOfView const& fov, cv::Mat const& bgr_full,
                         int scale, ContourLinesParams const& params);

}  // namespace endo_guidance::perception
