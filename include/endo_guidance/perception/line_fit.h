// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <optional>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"

namespace endo_guidance::perception {

/// A line fitted robustly to points: least median of squares over random pairs, then least squares
/// on the inliers ([Rousseeuw87]). `line` is normalised (a^2 + b^2 = 1), orientation arbitrary.
struct RobustLine {
  Eigen::Vector3d line = Eigen::Vector3d::Zero();
  std::vector<int> inliers;
  double sigma = 0.0;  ///< robust scale of the residuals
};
std::optional<RobustLine> fitLineLMedS(std::vector<Eigen::Vector2d> const& pts, int samples, std::uint64_t seed);

/// The total least-squares line through (weighted) points: normal = the scatter matrix's
/// eigenvector of the smallest eigenvalue; orientation arbitrary.
std::optional<Eigen::Vector3d> fitLineLS(std::vector<Eigen::Vector2d> const& pts, std::vector<double> const* weights = nullptr);

/// A line through sub-pixel edge points with its covariance and RMS residual.
struct RefinedLine {
  geometry::ImageLine line = geometry::ImageLine::Zero();
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  double residual_px = 0.0;
  int points = 0;
  std::vector<Eigen::Vector2d> inliers;  ///< the edge points behind the line (full-res pixels)
};
/// `line` summarised over the points of weight > 0: their RMS residual and the line's
/// covariance, the residuals' independent part plus a systematic error of sigma_floor_px at each
/// end (geometry::lineCovariance); nullopt with fewer than min_points.
std::optional<RefinedLine> summarizeLine(Eigen::Vector3d const& line, std::vector<Eigen::Vector2d> const& pts,
                                         std::vector<double> const& weights, int min_points, double sigma_floor_px);

}  // namespace endo_guidance::perception
