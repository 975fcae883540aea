// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "endo_guidance/perception/segmentation_params.h"
#include "endo_guidance/perception/shaft_detector.h"

namespace endo_guidance::perception {

/// The network's output as probabilities (CV_32F in [0, 1], all of one size): the shaft class's,
/// the instrument's (shaft or jaws: one less the background's) and, from a model that gives them,
/// the shaft's silhouette sides' (empty otherwise): a band about the shaft's outline where it meets
/// the background, not where it meets its jaws, an occluding tool or the view's edge.
struct ShaftProbabilities {
  cv::Mat shaft, instrument;
  cv::Mat side = cv::Mat();  ///< (may be left out of an initialiser)
};

/// The per-pixel shaft network, run by OpenCV's DNN module on the CPU (no training framework at
/// run time). The YAML beside the ONNX file gives the input size, the normalisation
/// ((BGR - mean) * scale), the class order (background, shaft, jaws) and, with `side: C`, the
/// output channel C (after the classes) of the sides' logit. A missing or unreadable model throws
/// std::runtime_error at construction, never per frame.
class ShaftNet {
 public:
  explicit ShaftNet(std::string const& yaml_path, int threads = 1);
  ~ShaftNet();
  ShaftNet(ShaftNet const&) = delete;
  ShaftNet& operator=(ShaftNet const&) = delete;
  /// Logits (CV_32F, 1 x outputs x height x width: the classes, then the side's) of one BGR frame, resized to the input
  /// (the network's own buffer: valid until the next call).
  cv::Mat logits(cv::Mat const& bgr);
  /// The softmax probabilities of one BGR frame at the input size, and the sides' (sigmoid). A
  /// model without a background class gives the shaft's as the instrument's.
  ShaftProbabilities probabilities(cv::Mat const& bgr);
  cv::Size inputSize() const { return size_; }
  std::vector<std::string> const& classes() const { return classes_; }
  bool hasSides() const { return side_ >= 0; }

 private:
  struct Impl;  // the cv::dnn::Net (opencv2/dnn.hpp stays out of this header)
  std::unique_ptr<Impl> impl_;
  cv::Size size_;
  double mean_ = 0.0, scale_ = 1.0;
  std::vector<std::string> classes_;
  int shaft_ = 1, background_ = -1, side_ = -1;
};

/// The learned detector's stage after its network, on its probabilities at the processing scale
/// (frame.fov.mask's size). The shaft class's mask proposes side pairs first, then the
/// instrument's (shaft or jaws): the dataset's shaft class is often only a stub between the view's
/// border and an insulated sheath of the same width, which together are long enough to pair. An
/// instrument pair is kept only where the shaft class holds the instrument where it enters (the
/// shaft comes in from the trocar; a tool's head alone, a stapler's, is not its shaft) and no
/// accepted shaft covers that entry. Each pair goes through the contour fit with its region (tip,
/// fill) from the instrument's mask, so its tip is the jaws' end; the duplicates are removed and
/// each tip located on the frame (locateTips()); `labels` (processing scale) gets each accepted
/// pair's region.
SegmentationResult shaftsOfProbability(DetectionFrame const& frame, ShaftProbabilities const& probability,
                                       SegmentationParams const& params, cv::Mat& labels);

/// The learned shaft detector: the network's shaft and instrument masks as pairs of straight sides
/// (findMaskLinePairs()), each pair through the contour fit (refineContour(): the lines on the
/// frame's edges beside the mask's sides; the network proposes, the frame measures); then the
/// glare check and the duplicates' removal, as the colour method's.
class LearnedShaftDetector final : public ShaftDetector {
 public:
  /// Loads the model: std::runtime_error if it cannot be.
  explicit LearnedShaftDetector(SegmentationParams const& params);
  /// (The copy shares the loaded network.)
  std::unique_ptr<ShaftDetector> clone() const override { return std::make_unique<LearnedShaftDetector>(*this); }
  SegmentationResult detect(DetectionFrame const& frame) override;
  bool followable() const override { return true; }
  /// The network every 8th frame: the whole pipeline within 4x an HSV conversion on a 720 x 576
  /// video, the closed-loop servo as every frame (the tip located on the tracked frames);
  /// docs/performance.md. (The colour method detects every frame: tracked, its false shafts stay.)
  int detectEvery() const override { return 8; }
  void setParams(SegmentationParams const& p) override;  // (reloads the model if its path or threads changed)
  void reset() override {}
  cv::Mat const& feature() const override { return feature_; }
  cv::Mat const& labels() const override { return labels_; }

 private:
  SegmentationParams params_;
  std::shared_ptr<ShaftNet> net_;
  cv::Mat feature_, labels_;
};

}  // namespace endo_guidance::perception
