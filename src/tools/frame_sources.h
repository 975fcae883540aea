// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The offline program's readers: image files, videos and bags, one frame at a time. A frame
// that cannot be decoded comes back with `error` set (the run goes on); a file that cannot be
// opened throws std::runtime_error with why. Fuzzed by test/fuzz/fuzz_readers.cpp.
#pragma once

#include <memory>
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <vector>

#include "endo_guidance/io/yaml_config.h"

namespace endo_guidance::tools {

struct Frame {
  cv::Mat image;  ///< 8-bit BGR, or empty with `error`
  std::string source;
  double stamp = 0.0;
  std::string error;
};

class Source {
 public:
  virtual ~Source() = default;
  /// The next frame; false at the end. Never throws for a bad frame (see Frame::error).
  virtual bool next(Frame& f) = 0;
  /// The camera model the source carries (a bag's camera_info), if any.
  virtual std::optional<io::CameraModel> camera() const { return std::nullopt; }
  virtual long size() const { return -1; }
};

/// Image files in the given order, stamped k / fps.
std::unique_ptr<Source> openImageFiles(std::vector<std::string> files, double fps);
/// A video file (any container OpenCV's FFmpeg backend reads), stamped k / its frame rate.
std::unique_ptr<Source> openVideo(std::string const& path, double fallback_fps);
/// The sensor_msgs/Image or CompressedImage messages of `topic` in a bag, with its camera_info.
std::unique_ptr<Source> openBag(std::string const& path, std::string const& topic);

}  // namespace endo_guidance::tools
