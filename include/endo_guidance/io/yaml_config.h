// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// Reading the project's YAML files outside ROS (the offline program): the camera_info YAML of
// camera_calibration_parsers and config/pipeline.yaml. The nodes read the same keys from the
// parameter server.
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "endo_guidance/pipeline/pipeline.h"

namespace endo_guidance::io {
using pipeline::PipelineParams;

/// A pinhole camera as in sensor_msgs/CameraInfo.
struct CameraModel {
  int width = 0, height = 0;
  Eigen::Matrix3d K = Eigen::Matrix3d::Zero();
  std::string distortion_model = "plumb_bob";
  std::vector<double> D;
  Eigen::Matrix<double, 3, 4> P = Eigen::Matrix<double, 3, 4>::Zero();
  bool hasDistortion() const;
  /// Intrinsics of the rectified image: P's left 3x3 block when set, else K.
  Eigen::Matrix3d rectifiedK() const;
};

/// Reads a camera_info YAML (image_width, image_height, camera_matrix, distortion_model,
/// distortion_coefficients, projection_matrix). Throws std::runtime_error with the reason
/// (missing file or key, zero focal length, size 0) -- invalid intrinsics are never accepted.
CameraModel loadCameraYaml(std::string const& path);
/// The same from YAML text.
CameraModel parseCameraYaml(std::string const& text);

/// Overrides fields of `params` with the keys present in a pipeline YAML (see config/pipeline.yaml;
/// unknown keys are an error, listed in the exception, so a typo is not silently ignored).
void loadPipelineYaml(std::string const& path, PipelineParams& params);
/// The same from YAML text.
void parsePipelineYaml(std::string const& text, PipelineParams& params);
/// segmentation/detector's values: "colour" or "learned" (std::runtime_error otherwise).
perception::SegmentationParams::Detector detectorFromString(std::string const& name);
char const* toString(perception::SegmentationParams::Detector d);

}  // namespace endo_guidance::io

namespace YAML {
class Node;
}

namespace endo_guidance::io {

/// The same from a YAML tree (the nodes convert their parameter namespace to one): returns the
/// unknown keys ("group/key") instead of throwing; throws std::runtime_error on a wrong type.
std::vector<std::string> applyPipelineParams(YAML::Node const& root, PipelineParams& params);
/// A camera model from a YAML tree (loadCameraYaml()'s rules).
CameraModel cameraFromYaml(YAML::Node const& node);

}  // namespace endo_guidance::io
