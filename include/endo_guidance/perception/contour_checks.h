// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <array>
#include <opencv2/core.hpp>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"
#include "endo_guidance/perception/contour_params.h"
#include "endo_guidance/perception/field_of_view.h"
#include "endo_guidance/perception/region_growing.h"

namespace endo_guidance::perception {

/// Full-resolution colour samples across a contour, at 39 stations evenly spaced from its entry
/// to its tip: three between the lines (at 1/4, 1/2 and 3/4 of the width) and one beside each
/// line, a third of the width (at least 3 px) outside it. Samples off the image are left out.
struct AcrossSamples {
  std::vector<float> inside;                  ///< edgeChannel() between the lines
  std::array<std::vector<float>, 2> outside;  ///< ... beside lines[0] and lines[1]
  int glare = 0;  ///< inside samples that are glare: near white (max channel >= 230) and achromatic (chroma < 30)
};
AcrossSamples acrossContour(cv::Mat const& bgr, geometry::ApparentContour const& contour);

/// Whether the contour is mostly glare between its lines (AcrossSamples::glare over the inside
/// samples > max_glare_fraction): a specular reflection on wet tissue, which the S.H feature
/// sees as low as metal, not a shaft. A shaft's highlights are streaks along it.
bool mostlyGlare(cv::Mat const& bgr, geometry::ApparentContour const& contour, ContourLinesParams const& params);
/// The same from samples already taken (acrossContour()).
bool mostlyGlare(AcrossSamples const& samples, ContourLinesParams const& params);

/// The steepest crossing of the view's border by the contour's axis or either line, as the sine of
/// its angle with the border (a shaft enters the view across it; a band along the border does
/// not). `axis_dir`: entry -> tip; `w_proc`: the width at the entry in processing px.
double enteringSine(geometry::ApparentContour const& c, FieldOfView const& fov, Eigen::Vector2d const& entry,
                    Eigen::Vector2d const& axis_dir, double w_proc, int scale);

/// Whether the region fills the strip between the contour's lines from its entry to its tip (at
/// least min_fill of the strip) and stays in it (at least min_inside of the region's pixels within
/// four widths of the axis, beside the strip's extent): a shaft does, a tissue blob with two
/// straight-ish sides does not. Rasterised at the processing scale. `width`: the mean width (px).
bool fillsStrip(geometry::ApparentContour const& c, Region const& region, Eigen::Vector2d const& axis_dir, double width, int scale,
                double min_fill, double min_inside);

}  // namespace endo_guidance::perception
