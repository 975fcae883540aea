// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The loaders on arbitrary text and bytes: the pipeline parameters YAML and camera YAML (a
// refusal is std::runtime_error, nothing else escapes; what is accepted is usable), and a
// sensor_msgs/CameraInfo with arbitrary fields through the nodes' validation (valid means a
// finite, invertible K).
#include <sensor_msgs/CameraInfo.h>

#include <stdexcept>
#include <string>

#include "endo_guidance/io/yaml_config.h"
#include "endo_guidance/ros/conversions.h"
#include "fuzz_input.h"

using endo_guidance::fuzz::fail;
namespace io = endo_guidance::io;

extern "C" int LLVMFuzzerTestOneInput(std::uint8_t const* data, std::size_t size) {
  std::string const text(reinterpret_cast<char const*>(data), size);
  try {
    io::PipelineParams p;
    io::parsePipelineYaml(text, p);
    if (!(p.radius > 0.0) || p.segmentation.processing_width < 32) fail("pipeline YAML accepted out of range");
  } catch (std::runtime_error const&) {
  }
  try {
    io::CameraModel const c = io::parseCameraYaml(text);
    if (c.width <= 0 || c.height <= 0 || !c.K.allFinite() || !(c.K(0, 0) > 0.0)) fail("camera YAML accepted invalid");
  } catch (std::runtime_error const&) {
  }
  // A camera_info with arbitrary fields (read from the same bytes as typed values).
  endo_guidance::fuzz::Input in(data, size);
  sensor_msgs::CameraInfo info;
  info.width = in.u32() % 4096, info.height = in.u32() % 4096;
  static char const* const models[] = {"plumb_bob", "rational_polynomial", "equidistant", ""};
  info.distortion_model = models[in.byte() % 4];
  info.D.resize(in.byte() % 15);
  for (double& d : info.D) d = in.real(-1, 1);
  for (double& k : info.K) k = in.byte() < 128 ? 0.0 : in.real(-2000, 2000);
  for (double& p : info.P) p = in.byte() < 128 ? 0.0 : in.real(-2000, 2000);
  if (endo_guidance::ros_io::validateCameraInfo(info).empty()) {
    Eigen::Matrix3d const K = endo_guidance::ros_io::rectifiedK(info);
    if (!K.allFinite() || !(std::abs(K.determinant()) > 0.0)) fail("camera_info accepted with a singular or non-finite K");
  }
  return 0;
}
