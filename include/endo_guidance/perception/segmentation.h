// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <memory>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"
#include "endo_guidance/perception/contour_tracking.h"
#include "endo_guidance/perception/field_of_view.h"
#include "endo_guidance/perception/segmentation_params.h"
#include "endo_guidance/perception/shaft_detector.h"

namespace endo_guidance::perception {

/// The detector `params.detector` names: std::runtime_error if it cannot be made (the learned
/// detector's model cannot be loaded).
std::unique_ptr<ShaftDetector> makeShaftDetector(SegmentationParams const& params);

/// Instrument segmentation of a stream: the frame reduced to the processing scale, its field of
/// view, one shaft detector (shaft_detector.h: the colour method of [Doignon07] Sec. 3 or the
/// learned mask), and, when it detects less often than every frame (detectEvery()), the shafts
/// found followed by contour tracking between detection frames (a lost one makes the frame a
/// detection frame). Not
/// thread-safe (one instance per stream); call reset() between unrelated images.
class InstrumentSegmenter {
 public:
  /// With the learned detector, its model is loaded here: std::runtime_error if it cannot be.
  explicit InstrumentSegmenter(SegmentationParams const& params = {});
  /// With `detector` in place of the one params.detector names (until setParams() names another
  /// kind): std::invalid_argument if it is null.
  InstrumentSegmenter(SegmentationParams const& params, std::unique_ptr<ShaftDetector> detector);
  /// A copy carries the stream's state over (the detector's memory, tracked shafts).
  InstrumentSegmenter(InstrumentSegmenter const& o);
  InstrumentSegmenter& operator=(InstrumentSegmenter const& o);
  InstrumentSegmenter(InstrumentSegmenter&&) noexcept = default;
  InstrumentSegmenter& operator=(InstrumentSegmenter&&) noexcept = default;
  ~InstrumentSegmenter();
  /// Segments one BGR frame. `trocar_images`: homogeneous images of the known insertion points
  /// in full-resolution pixels ([Doignon07] Sec. 4), focusing the seed search; may be empty.
  SegmentationResult process(cv::Mat const& bgr, std::vector<Eigen::Vector3d> const& trocar_images = {});
  /// (Loads the learned detector's model when it is selected and its path or threads changed:
  /// std::runtime_error if it cannot be, the old parameters kept.)
  void setParams(SegmentationParams const& p);
  /// Forgets the previous frames (tracked shafts, the detector's memory, field of view).
  void reset();
  SegmentationParams const& params() const { return params_; }
  /// The cadence in use: tracking.detect_every, or the detector's own when that is 0.
  int detectEvery() const { return params_.tracking.detect_every > 0 ? params_.tracking.detect_every : detector_->detectEvery(); }
  FieldOfView const& fieldOfView() const { return fov_; }
  /// Intermediate images of the last frame (processing scale), for debugging and overlays.
  cv::Mat const& feature() const { return detector_->feature(); }
  cv::Mat const& labels() const { return detector_->labels(); }

 private:
  std::optional<SegmentationResult> track(cv::Mat const& bgr);  // nullopt: detect
  void updateFieldOfView();  // on small_, every fov_refresh frames or when its size changes
  // Follows res's shafts (of a frame of `frame_size`) in the next frames when `follow` (contour tracking on).
  void startTracks(SegmentationResult const& res, bool follow, cv::Size frame_size);

  SegmentationParams params_;
  std::unique_ptr<ShaftDetector> detector_;
  FieldOfView fov_;
  cv::Size fov_size_;
  double fov_area_ = 0.0;
  int frames_since_fov_ = 0;
  std::vector<TrackedShaft> tracked_;  // the shafts of the last frame, to follow
  cv::Size tracked_size_;
  int scale_ = 1;
  int since_detection_ = 0;  // tracking frames since the last detection frame
  cv::Mat small_;
};

/// Draws contours, axes, tips, entries and the directions of the insertion points on a BGR image
/// (seed Fig. 1, 2, 6).
void drawSegmentationOverlay(cv::Mat& bgr, SegmentationResult const& result,
                             std::vector<Eigen::Vector3d> const& trocar_images = {});

}  // namespace endo_guidance::perception
