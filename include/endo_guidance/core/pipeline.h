// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <vector>

#include "endo_guidance/core/cylinder_pose.h"
#include "endo_guidance/core/insertion_point_tracker.h"
#include "endo_guidance/core/segmentation.h"

namespace endo_guidance {

struct PipelineParams {
  double radius = 0.004;                ///< instrument shaft radius, metres
  SegmentationParams segmentation;
  CylinderPoseOptions pose;
  InsertionPointSetOptions insertion_points;
  /// Once an insertion point is well conditioned, a shaft whose axis passes through none
  /// (Eq. (6)) is not reported (gauze, clips, tissue folds); it still feeds the discovery of new
  /// insertion points.
  bool reject_unattached = true;
  double track_max_angle_deg = 12.0;    ///< frame-to-frame association of shafts
  double track_max_distance_px = 25.0;
};

/// One shaft seen in one frame.
struct InstrumentObservation {
  ApparentContour contour;              ///< full-resolution pixels
  CylinderPose pose;                    ///< camera frame
  std::optional<Eigen::Vector3d> tip_c; ///< the tip pixel back-projected onto the axis
  int insertion_point = -1;
  int track = -1;
};

struct InsertionPointReport {
  int id = -1;
  InsertionPointEstimate estimate;
  Eigen::Vector3d image_point = Eigen::Vector3d::Zero();  ///< homogeneous pixel (w = 0: at infinity)
  bool well_conditioned = false;
};

struct PipelineOutput {
  std::string error;                    ///< non-empty: the frame was rejected (nothing else is set)
  std::vector<InstrumentObservation> instruments;
  std::vector<InsertionPointReport> insertion_points;
  SegmentationResult segmentation;      ///< intermediate results (overlays, diagnostics)
  int rejected_unattached = 0;
  int rejected_pose = 0;
  double latency_ms = 0.0;
};

/// The whole per-frame pipeline ([Doignon07]): segmentation (focused by the images of the
/// insertion points) -> cylinder pose -> attachment to insertion points / discovery -> tracks.
/// Stateful (insertion points, tracks); one instance per camera stream; not thread-safe.
class Pipeline {
 public:
  /// K: intrinsics of the (rectified) images; size: their expected size.
  Pipeline(Eigen::Matrix3d const& K, cv::Size size, PipelineParams const& params = {});
  PipelineOutput process(cv::Mat const& bgr);
  InsertionPointSet& insertionPoints() { return points_; }
  Eigen::Matrix3d const& K() const { return K_; }
  cv::Size size() const { return size_; }
  PipelineParams const& params() const { return params_; }

 private:
  Eigen::Matrix3d K_;
  cv::Size size_;
  PipelineParams params_;
  InstrumentSegmenter segmenter_;
  InsertionPointSet points_;
  std::vector<InstrumentObservation> previous_;
  int next_track_ = 0;
};

}  // namespace endo_guidance
