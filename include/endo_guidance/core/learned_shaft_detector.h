// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "endo_guidance/core/field_of_view.h"
#include "endo_guidance/core/region_growing.h"

namespace endo_guidance::core {

/// The package's shaft network (models/shaft_net.yaml; scripts/train_shaft_net.sh reproduces it).
std::string defaultShaftModel();

struct LearnedDetectorParams {
  std::string model;               ///< the model's YAML (input size, normalisation, ONNX file); empty: defaultShaftModel()
  int threads = 1;                 ///< OpenCV DNN threads
  double shaft_probability = 0.5;  ///< a pixel is shaft where the network gives at least this
  int min_area = 40;               ///< processing px: smaller mask components are not proposed
};

/// The per-pixel shaft network, run by OpenCV's DNN module on the CPU (no training framework at
/// run time). The YAML beside the ONNX file gives the input size, the normalisation
/// ((BGR - mean) * scale) and the class order (background, shaft, jaws). A missing or unreadable
/// model throws std::runtime_error at construction, never per frame.
class ShaftNet {
 public:
  explicit ShaftNet(std::string const& yaml_path, int threads = 1);
  ~ShaftNet();
  ShaftNet(ShaftNet const&) = delete;
  ShaftNet& operator=(ShaftNet const&) = delete;
  /// Class logits (CV_32F, 1 x classes x height x width) of one BGR frame, resized to the input.
  cv::Mat logits(cv::Mat const& bgr);
  /// The shaft class's softmax probability (CV_32F, input size) of one BGR frame.
  cv::Mat shaftProbability(cv::Mat const& bgr);
  cv::Size inputSize() const { return size_; }
  std::vector<std::string> const& classes() const { return classes_; }

 private:
  struct Impl;  // the cv::dnn::Net (opencv2/dnn.hpp stays out of this header)
  std::unique_ptr<Impl> impl_;
  cv::Size size_;
  double mean_ = 0.0, scale_ = 1.0;
  std::vector<std::string> classes_;
  int shaft_ = 1;
};

/// The learned shaft detector's proposals: the connected components of the network's shaft mask
/// (processing scale, inside the field of view), each as a Region whose seed is the middle of its
/// longest run on the view's border (the entry), or, for a component that does not reach the
/// border, its boundary point nearest to the border. The contour fit (fitSides(),
/// refineContour()) turns them into sub-pixel lines as it does the grown regions.
std::vector<Region> proposeShaftRegions(cv::Mat const& shaft_probability, FieldOfView const& fov,
                                        LearnedDetectorParams const& params, int border_margin);

}  // namespace endo_guidance::core
