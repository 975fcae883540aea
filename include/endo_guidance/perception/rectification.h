// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <array>
#include <functional>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"
#include "endo_guidance/perception/contour_params.h"

namespace endo_guidance::perception {

/// Distorted pixel -> pixel of the rectified camera.
using PointRectifier = std::function<Eigen::Vector2d(Eigen::Vector2d const&)>;
/// The PointRectifier of OpenCV's lens model (K, D), rectification R and new camera matrix P
/// (3x3): tabulated once at every pixel of a `size` image (one batched cv::undistortPoints, 50
/// iterations: OpenCV's default 5 leave 0.02 px at a wide-angle endoscope's corners), then
/// interpolated bilinearly per point (well under 1e-3 px); points off the image take the exact call.
PointRectifier pointRectifier(cv::Matx33d const& K, cv::Mat const& D, cv::Matx33d const& R, cv::Matx33d const& P, cv::Size size);

/// Lens distortion, the one way it is handled (the nodes and the offline program alike): the contour lines refitted (least squares, with covariance) to the edge
/// points mapped by `rectify` (distorted pixel -> pixel of the rectified camera), the entry and
/// tip mapped too. The image is never remapped: a straight shaft edge is a curve in the
/// distorted image and a line again after the mapping. nullopt when a side keeps fewer than
/// min_points mapped points or the refitted lines cross. `sigma_floor_px`: as
/// ContourLinesParams::line_sigma_floor_px.
std::optional<geometry::ApparentContour> rectifyContour(geometry::ApparentContour const& contour,
                                              std::array<std::vector<Eigen::Vector2d>, 2> const& edges,
                                              PointRectifier const& rectify,
                                              int min_points = 8, double sigma_floor_px = ContourLinesParams{}.line_sigma_floor_px);
/// rectifyContour() on each contour with its edge points (edges[i] for contours[i]), with the
/// contour fit's min_edge_points and line_sigma_floor_px; the contours that cannot be are left out.
std::vector<geometry::ApparentContour> rectifyContours(std::vector<geometry::ApparentContour> const& contours,
                                                       std::vector<std::array<std::vector<Eigen::Vector2d>, 2>> const& edges,
                                                       PointRectifier const& rectify, ContourLinesParams const& params);

}  // namespace endo_guidance::perception
