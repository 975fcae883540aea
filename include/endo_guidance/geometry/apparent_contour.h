// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <optional>

namespace endo_guidance::geometry {

/// An image line l = (a, b, c): a u + b v + c = 0 in pixels, normalised so a^2 + b^2 = 1
/// (then l.(u, v, 1) is the signed distance in pixels) and oriented so that the instrument's
/// pixels are on the positive side.
using ImageLine = Eigen::Vector3d;

/// Apparent contour of one shaft: the two straight silhouette lines, [Doignon07] Sec. 3.
/// Convention: lines[0] is on the LEFT and lines[1] on the RIGHT when walking in the image
/// (u right, v down) from the entry point toward the tip; both oriented with the shaft on
/// their positive side. With this order the cylinder axis direction d ~ n0 x n1 points from
/// the entry toward the tip (see estimateCylinderPose()).
struct ApparentContour {
  std::array<ImageLine, 2> lines{ImageLine::Zero(), ImageLine::Zero()};
  /// Covariance of each line's (a, b, c) (rank 2); zero when unknown.
  std::array<Eigen::Matrix3d, 2> line_covariances{Eigen::Matrix3d::Zero(), Eigen::Matrix3d::Zero()};
  std::array<double, 2> line_residual_px{0.0, 0.0};
  double residual_px = 0.0;
  Eigen::Vector2d entry_px = Eigen::Vector2d::Zero();  ///< where the shaft crosses the FOV border (segmentation: on the image axis)
  Eigen::Vector2d tip_px = Eigen::Vector2d::Zero();    ///< farthest shaft pixel from the entry (segmentation: on the image axis)
  int insertion_point_id = -1;
  int track_id = -1;
};

/// Foot of the perpendicular from pixel q to the normalised line l.
inline Eigen::Vector2d footOnLine(ImageLine const& l, Eigen::Vector2d const& q) {
  return q - l.head<2>() * l.dot(Eigen::Vector3d(q.x(), q.y(), 1.0));
}

/// The shaft's image between its lines from `from` to `to` (full-res px): the feet of both on
/// the two lines, in order around it (from on lines[0], from on lines[1], to on lines[1], to on
/// lines[0]).
inline std::array<Eigen::Vector2d, 4> shaftQuad(ApparentContour const& c, Eigen::Vector2d const& from, Eigen::Vector2d const& to) {
  return {footOnLine(c.lines[0], from), footOnLine(c.lines[1], from), footOnLine(c.lines[1], to), footOnLine(c.lines[0], to)};
}

/// The image of the shaft's axis: the bisector of the two contour lines (their normals point
/// inward, so l0 - l1 vanishes where the distances to both are equal), normalised.
inline ImageLine imageAxis(ApparentContour const& c) {
  Eigen::Vector3d const a = c.lines[0] - c.lines[1];
  double const n = a.head<2>().norm();
  return n > 1e-12 ? ImageLine(a / n) : c.lines[0];
}

/// The shaft's image width (px) at the foot of q on its image axis: the sum of the two lines'
/// signed distances there (both positive inside).
inline double shaftWidthAt(ApparentContour const& c, Eigen::Vector2d const& q) {
  Eigen::Vector3d const f = footOnLine(imageAxis(c), q).homogeneous();
  return c.lines[0].dot(f) + c.lines[1].dot(f);
}

/// Scales l so that a^2 + b^2 = 1, keeping its orientation. nullopt if a = b = 0 or not finite.
std::optional<ImageLine> normalizeLine(Eigen::Vector3d const& l);

/// The oriented line through pixels p then q, with the positive side on the LEFT of the walk
/// p -> q in the image (u right, v down). nullopt if p ~ q.
std::optional<ImageLine> lineThrough(Eigen::Vector2d const& p, Eigen::Vector2d const& q);

/// Covariance of (a, b, c) of a normalised line from the variance of its angle (rad^2) and of its
/// offset along the normal (px^2), both measured at the point `centre` on the line (where they
/// are uncorrelated, e.g. the centroid of the fitted points). Jacobian of
/// (cos t, sin t, -(cos t, sin t).c0 - delta) w.r.t. (t, delta).
Eigen::Matrix3d lineCovariance(ImageLine const& l, Eigen::Vector2d const& centre, double var_angle, double var_offset);

/// Covariance of a line fitted to n points spread evenly over the segment p..q, each with
/// independent normal noise of standard deviation sigma_px (n = 2: the line through two noisy
/// endpoints).
Eigen::Matrix3d lineCovarianceFromSegment(ImageLine const& l, Eigen::Vector2d const& p, Eigen::Vector2d const& q,
                                          double sigma_px, int n = 2);

/// Clips an image line to the rectangle [0, width-1] x [0, height-1]; nullopt if it misses it.
std::optional<std::array<Eigen::Vector2d, 2>> clipLineToImage(ImageLine const& l, int width, int height);

}  // namespace endo_guidance::geometry
