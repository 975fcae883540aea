// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// rviz markers of the estimates (metres, in the header's optical frame). Each array starts with
// a DELETEALL so that shafts and trocars that disappear vanish from the display.
#pragma once

#include <std_msgs/Header.h>
#include <visualization_msgs/MarkerArray.h>

#include <Eigen/Core>
#include <optional>
#include <vector>

#include "endo_guidance/geometry/constrained_axis.h"
#include "endo_guidance/geometry/cylinder_pose.h"
#include "endo_guidance/pipeline/pipeline.h"

namespace endo_guidance::ros_io {

/// Per shaft: the cylinder (radius r) over its last `length` metres up to the tip, an arrow of
/// its direction at the tip, and its two contour generators (the lines where the rays of the
/// apparent contour graze the cylinder).
void appendShaftMarkers(std::vector<visualization_msgs::Marker>& out, std_msgs::Header const& header, int index,
                        geometry::CylinderPose const& pose, double radius, std::optional<Eigen::Vector3d> const& tip,
                        double length = 0.12);
/// Per insertion point: a sphere, its 3-sigma covariance ellipsoid, its id, and lines from it to
/// the tips of the shafts attached to it (the axes converging on it).
void appendTrocarMarkers(std::vector<visualization_msgs::Marker>& out, std_msgs::Header const& header,
                         pipeline::InsertionPointReport const& point, std::vector<Eigen::Vector3d> const& attached_points);
/// Per shaft attached to a located insertion point: its axis through that point
/// (constrained_axis.h) as a line from the fused pivot to the tip's foot on that axis (the foot of
/// the optical centre when the tip is unknown), namespace "axes_through". Nothing is added when
/// an end is not finite.
void appendThroughMarker(std::vector<visualization_msgs::Marker>& out, std_msgs::Header const& header, int index,
                         geometry::ConstrainedAxis const& through, std::optional<Eigen::Vector3d> const& tip);
visualization_msgs::Marker deleteAll(std_msgs::Header const& header);

}  // namespace endo_guidance::ros_io
