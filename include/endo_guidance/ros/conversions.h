// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The thin ROS layer: message <-> core conversions, camera_info validation and the pipeline
// parameters from the parameter server. Every conversion to a message refuses non-finite values
// (returns false) so that no NaN is ever published.
#pragma once

#include <ros/node_handle.h>
#include <sensor_msgs/CameraInfo.h>

#include <Eigen/Core>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "endo_guidance/ApparentContour.h"
#include "endo_guidance/InsertionPoint.h"
#include "endo_guidance/InstrumentAxis.h"
#include "endo_guidance/pipeline/pipeline.h"

namespace endo_guidance::ros_io {

/// Empty if the camera_info can be used for images of width x height (pass 0 to skip the size
/// check); else the reason: zero or non-finite K / P, zero size, size mismatch, unknown
/// distortion model.
std::string validateCameraInfo(sensor_msgs::CameraInfo const& info, int width = 0, int height = 0);
/// Intrinsics of the rectified image: P's left 3x3 block when set, else K.
Eigen::Matrix3d rectifiedK(sensor_msgs::CameraInfo const& info);
/// True when D has a non-zero coefficient (the edge points must be rectified).
bool hasDistortion(sensor_msgs::CameraInfo const& info);
/// True when b is the camera of a in another mode (a scaled or binned stream): K and P scaled by
/// the ratio of the image sizes, principal points with the pixel centres (x' + 1/2 = s (x + 1/2)),
/// the same distortion, rectification and frame. 3-D estimates in its optical frame still hold.
bool sameCameraScale(sensor_msgs::CameraInfo const& a, sensor_msgs::CameraInfo const& b, double tolerance = 0.01);
/// Distorted pixel -> pixel of the rectified camera (R, P of the camera_info), iterated to 1e-10
/// px (OpenCV's default 5 iterations leave 0.02 px at the corners of a wide-angle endoscope);
/// tabulated at every pixel when built (build it once per camera model), interpolated per point.
std::function<Eigen::Vector2d(Eigen::Vector2d const&)> rectifier(sensor_msgs::CameraInfo const& info);

bool toMsg(geometry::ApparentContour const& c, endo_guidance::ApparentContour& m);
geometry::ApparentContour fromMsg(endo_guidance::ApparentContour const& m);
bool toMsg(geometry::CylinderPose const& pose, double radius, double residual_px, std::optional<Eigen::Vector3d> const& tip,
           endo_guidance::InstrumentAxis& m);
/// nullopt unless the direction is unit, the moment orthogonal to it and both finite.
std::optional<geometry::CylinderPose> fromMsg(endo_guidance::InstrumentAxis const& m);
/// Fills the axis through the insertion point (through_valid, axis_through, covariance_through):
/// false (and through_valid false) when it is not finite.
bool setThrough(geometry::CylinderPose const& through, endo_guidance::InstrumentAxis& m);
/// setThrough() back: the axis through the insertion point, nullopt unless through_valid and
/// valid as fromMsg() requires.
std::optional<geometry::CylinderPose> throughFromMsg(endo_guidance::InstrumentAxis const& m);
bool toMsg(pipeline::InsertionPointReport const& r, endo_guidance::InsertionPoint& m);

/// Reads the pipeline parameters (keys of config/pipeline.yaml) from `nh`'s namespace over the
/// defaults in `params`. Keys listed in `own` belong to the node and are skipped; any other
/// unknown key is returned (the node warns: a typo is not silently ignored). Throws
/// std::runtime_error on a value of the wrong type.
std::vector<std::string> loadPipelineParams(ros::NodeHandle const& nh, pipeline::PipelineParams& params,
                                            std::vector<std::string> const& own = {});

}  // namespace endo_guidance::ros_io
