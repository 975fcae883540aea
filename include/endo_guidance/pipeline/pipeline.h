// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <limits>
#include <opencv2/core.hpp>
#include <optional>
#include <string>
#include <vector>

#include "endo_guidance/geometry/constrained_axis.h"
#include "endo_guidance/geometry/cylinder_pose.h"
#include "endo_guidance/geometry/insertion_point_tracker.h"
#include "endo_guidance/geometry/shaft_tracking.h"
#include "endo_guidance/perception/rectification.h"
#include "endo_guidance/perception/segmentation.h"

namespace endo_guidance::pipeline {

struct PipelineParams {
  double radius = 0.004;                ///< instrument shaft radius, metres
  perception::SegmentationParams segmentation;
  geometry::CylinderPoseOptions pose;
  geometry::InsertionPointSetOptions insertion_points;
  /// Once an insertion point is well conditioned, a shaft whose axis passes through none
  /// (Eq. (6)) is not reported (gauze, clips, tissue folds); it still feeds the discovery of new
  /// insertion points.
  bool reject_unattached = true;
  geometry::ShaftTrackingParams tracking;         ///< frame-to-frame association of shafts
};

/// One shaft seen in one frame.
struct InstrumentObservation {
  geometry::ApparentContour contour;              ///< full-resolution pixels
  geometry::CylinderPose pose;                    ///< camera frame
  std::optional<Eigen::Vector3d> tip_c; ///< the tip pixel back-projected onto the axis
  int insertion_point = -1;
  int track = -1;
  /// The axis through its insertion point (constrained_axis.h): set when the shaft is attached
  /// to a located insertion point (InsertionPointReport::located), with the trocar's motion
  /// `insertion_points.tracker.point_motion_sigma`. `pose` stays the contour's own measurement.
  std::optional<geometry::ConstrainedAxis> constrained;
};

struct InsertionPointReport {
  int id = -1;
  geometry::InsertionPointEstimate estimate;
  Eigen::Vector3d image_point = Eigen::Vector3d::Zero();  ///< homogeneous pixel (w = 0: at infinity)
  bool well_conditioned = false;
  bool located = false;  ///< InsertionPointTracker::located(): the position can be relied on
};

struct PipelineOutput {
  std::string error;                    ///< non-empty: the frame was rejected (nothing else is set)
  std::vector<InstrumentObservation> instruments;
  std::vector<InsertionPointReport> insertion_points;
  perception::SegmentationResult segmentation;      ///< intermediate results (overlays, diagnostics)
  int rejected_unattached = 0;
  int rejected_pose = 0;
  double latency_ms = 0.0;
};

/// The per-frame stages, called alike by Pipeline::process() and by the nodelets (one stage each).
///
/// Stage 1 ([Doignon07] Sec. 3): the frame's shafts, the seed search focused by the trocars'
/// images, as contours in rectified pixels (each refitted to its rectified edge points when
/// `rectify` is set: the image is never remapped; one that cannot be is dropped), each with its
/// track id. `result`: the segmentation's own output (image pixels: overlays, diagnostics).
std::vector<geometry::ApparentContour> segmentShafts(perception::InstrumentSegmenter& segmenter, geometry::ShaftTracker& tracker,
                                                     cv::Mat const& bgr, std::vector<Eigen::Vector3d> const& trocar_images,
                                                     perception::PointRectifier const& rectify,
                                                     perception::ContourLinesParams const& contour_params,
                                                     perception::SegmentationResult& result);
/// Stage 2 ([Doignon07] Eqs. (7)-(13)): a shaft's axis from its contour, and its tip pixel
/// back-projected onto it; nullopt for degenerate geometry (flagged, not guessed).
struct ShaftPose {
  geometry::CylinderPose pose;
  std::optional<Eigen::Vector3d> tip_c;
};
std::optional<ShaftPose> shaftPose(Eigen::Matrix3d const& K, double radius, geometry::ApparentContour const& contour,
                                   geometry::CylinderPoseOptions const& options);

/// The insertion-point options with `admissible` set (unless given) to "outside the image of
/// size `size` seen through K, or behind the camera": a trocar is in the abdominal wall.
geometry::InsertionPointSetOptions outOfViewOptions(geometry::InsertionPointSetOptions options, Eigen::Matrix3d const& K, cv::Size size);
/// Stage 3 ([Doignon07] Eqs. (3)-(6)), in the functions below: the images of the trocars for
/// stage 1, each axis attached (attachAxis()), the points reported, each attached axis through
/// its located point.
///
/// Homogeneous images of the well-conditioned insertion points (they focus the seed search,
/// [Doignon07] Sec. 4) and their ids.
void wellConditionedImages(geometry::InsertionPointSet const& set, Eigen::Matrix3d const& K, std::vector<Eigen::Vector3d>* images,
                           std::vector<int>* ids = nullptr);
/// Every insertion point with an estimate, with its image through K.
std::vector<InsertionPointReport> reportInsertionPoints(geometry::InsertionPointSet const& set, Eigen::Matrix3d const& K);
/// The axis through its insertion point (constrainAxisToPoint()) of a shaft attached to
/// `insertion_point`, when that point is located in `reports`; nullopt otherwise.
std::optional<geometry::ConstrainedAxis> axisThroughInsertionPoint(geometry::CylinderPose const& pose, int insertion_point,
                                                         std::vector<InsertionPointReport> const& reports, double point_motion_sigma);
/// The attachment stage ([Doignon07] Eq. (6) + tracking): feeds the axis to the set and returns
/// the id of its insertion point (-1: none); *keep is false when the shaft must not be reported
/// (reject_unattached, an established point and no attachment). `stamp`: when the axis was seen
/// (s; NaN: 1 / 25 s after the last), for the breathing's share of the points' covariance.
int attachAxis(geometry::InsertionPointSet& set, geometry::CylinderPose const& pose, bool reject_unattached, bool established, bool* keep,
               double stamp = std::numeric_limits<double>::quiet_NaN());

/// The whole per-frame pipeline ([Doignon07]): segmentation (focused by the images of the
/// insertion points) -> cylinder pose -> attachment to insertion points / discovery -> tracks.
/// Stateful (insertion points, tracks); one instance per camera stream; not thread-safe.
class Pipeline {
 public:
  /// K: intrinsics of the rectified camera; size: the images' expected size. `rectify` (distorted
  /// pixel -> rectified pixel, perception::pointRectifier()) when the images are distorted: each
  /// contour is refitted to its rectified edge points (perception::rectifyContour(); the image
  /// is never remapped), and one that cannot be is dropped.
  Pipeline(Eigen::Matrix3d const& K, cv::Size size, PipelineParams const& params = {}, perception::PointRectifier rectify = {});
  /// One frame, seen at `stamp` (s, any origin; NaN: 1 / 25 s after the last frame).
  PipelineOutput process(cv::Mat const& bgr, double stamp = std::numeric_limits<double>::quiet_NaN());
  /// Forgets every frame seen: the segmentation's memory (seed levels, tracked shafts, field of
  /// view), the insertion points and the shaft tracks. The next process() gives what a new
  /// Pipeline with the same arguments would (unrelated stills: each on its own).
  void reset();
  geometry::InsertionPointSet& insertionPoints() { return points_; }
  Eigen::Matrix3d const& K() const { return K_; }
  cv::Size size() const { return size_; }
  PipelineParams const& params() const { return params_; }

 private:
  Eigen::Matrix3d K_;
  cv::Size size_;
  PipelineParams params_;
  perception::InstrumentSegmenter segmenter_;
  geometry::InsertionPointSet points_;
  geometry::ShaftTracker tracker_;
  perception::PointRectifier rectify_;
};

}  // namespace endo_guidance::pipeline
