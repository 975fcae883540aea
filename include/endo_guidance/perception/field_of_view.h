// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

namespace endo_guidance::perception {

struct FieldOfViewParams {
  int dark_threshold = 24;   ///< max(B,G,R) at or below this is the black surround (0..255)
  int inset = 3;             ///< pixels: the border path runs this far inside the valid area
  double min_area_fraction = 0.2;  ///< below: the whole image is taken as the field of view
};

/// The valid (lit) image area of an endoscope: the full rectangle, a rectangle between black side
/// bars, or the disc of a circular endoscope with black surround. Instruments enter the view
/// across its border, so the seed search runs along `border`.
struct FieldOfView {
  cv::Mat mask;                     ///< CV_8U, 255 inside (eroded by `inset`)
  std::vector<cv::Point> border;    ///< closed path just inside the area, ordered, 8-connected
  cv::Rect bounds;                  ///< bounding box of the area
  bool circular = false;            ///< the area is a disc (fill ratio of its box ~ pi/4)
  cv::Point2f centre;               ///< centroid of the area
  cv::Mat depth;                    ///< CV_32F: distance (px) of each pixel to the area's edge (0 outside)
  bool valid() const { return !border.empty(); }
};

/// Detects the field of view on a (possibly down-scaled) BGR image. The area is the convex hull
/// of the largest lit region, so dark shafts crossing the border do not notch it.
FieldOfView detectFieldOfView(cv::Mat const& bgr, FieldOfViewParams const& params = {});

/// The inward direction at pixel p (clamped 3 px inside the image): the central difference of
/// `depth` over +-3 px, unnormalised; zero where the depth is flat or unknown.
Eigen::Vector2d depthGradient(FieldOfView const& fov, cv::Point p);

/// The distance (px) to the area's edge at the pixel nearest to x (processing px, clamped to the
/// image); 0 when `depth` is empty.
double depthAt(FieldOfView const& fov, Eigen::Vector2d const& x);
/// Whether pixel q lies within `margin` px (along a row or a column) of the area's edge or the
/// image's: the boundary points of a region there are its entry, not a side of a shaft.
bool nearViewEdge(FieldOfView const& fov, cv::Point q, int margin);
/// Whether the pixel nearest to x (processing px) is inside the area.
bool insideView(FieldOfView const& fov, Eigen::Vector2d const& x);

/// Where a line leaves the area: from p (processing px), a point inside walks along -dir out to
/// the area's edge, a point outside along +dir into the area, at most max_steps unit steps.
/// Returns the last point inside (nullopt if the walk in never entered); `*at_edge`: false only
/// when the walk out stopped at max_steps, still inside.
std::optional<Eigen::Vector2d> walkToEdge(FieldOfView const& fov, Eigen::Vector2d p, Eigen::Vector2d const& dir, int max_steps,
                                          bool* at_edge = nullptr);

}  // namespace endo_guidance::perception
