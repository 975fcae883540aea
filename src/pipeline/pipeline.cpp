// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/pipeline/pipeline.h"

#include <chrono>
#include <cmath>

#include "endo_guidance/geometry/insertion_point_image.h"

namespace endo_guidance::pipeline {

geometry::InsertionPointSetOptions outOfViewOptions(geometry::InsertionPointSetOptions o, Eigen::Matrix3d const& K, cv::Size size) {
  if (o.admissible) return o;
  // Outside the image (or behind or level with the optical centre).
  o.admissible = [K, size](Eigen::Vector3d const& X) {
    if (X.z() <= 1e-3) return true;
    Eigen::Vector3d const x = K * X;
    double const u = x.x() / x.z(), v = x.y() / x.z();
    return u < 0.0 || v < 0.0 || u > size.width - 1.0 || v > size.height - 1.0;
  };
  return o;
}

void wellConditionedImages(geometry::InsertionPointSet const& set, Eigen::Matrix3d const& K, std::vector<Eigen::Vector3d>* images,
                           std::vector<int>* ids) {
  images->clear();
  if (ids) ids->clear();
  for (auto const& p : set.points())
    if (p.tracker.wellConditioned()) {
      images->push_back(geometry::projectPointHomogeneous(K, p.tracker.estimate().position));
      if (ids) ids->push_back(p.id);
    }
}

std::vector<InsertionPointReport> reportInsertionPoints(geometry::InsertionPointSet const& set, Eigen::Matrix3d const& K) {
  std::vector<InsertionPointReport> out;
  for (auto const& p : set.points()) {
    if (!p.tracker.estimate().ok()) continue;
    InsertionPointReport rep;
    rep.id = p.id;
    rep.estimate = p.tracker.estimate();
    rep.image_point = geometry::projectPointHomogeneous(K, rep.estimate.position);
    rep.well_conditioned = p.tracker.wellConditioned();
    rep.located = p.tracker.located();
    out.push_back(rep);
  }
  return out;
}

std::optional<geometry::ConstrainedAxis> axisThroughInsertionPoint(geometry::CylinderPose const& pose, int insertion_point,
                                                         std::vector<InsertionPointReport> const& reports, double point_motion_sigma) {
  for (InsertionPointReport const& r : reports)
    if (r.id == insertion_point && r.located && r.estimate.ok())
      return geometry::constrainAxisToPoint(pose, r.estimate.position, r.estimate.covariance, point_motion_sigma);
  return std::nullopt;
}

int attachAxis(geometry::InsertionPointSet& set, geometry::CylinderPose const& pose, bool reject_unattached, bool established, bool* keep,
               double stamp) {
  int const id = set.update(pose.axis, pose.covariance, stamp);  // Eq. (6) + tracking
  *keep = !(reject_unattached && established && id < 0);
  return id;
}

std::vector<geometry::ApparentContour> segmentShafts(perception::InstrumentSegmenter& segmenter, geometry::ShaftTracker& tracker,
                                                     cv::Mat const& bgr, std::vector<Eigen::Vector3d> const& trocar_images,
                                                     perception::PointRectifier const& rectify,
                                                     perception::ContourLinesParams const& contour_params,
                                                     perception::SegmentationResult& result) {
  result = segmenter.process(bgr, trocar_images);
  std::vector<geometry::ApparentContour> contours =
      rectify ? perception::rectifyContours(result.contours, result.edges, rectify, contour_params) : result.contours;
  tracker.assign(contours);
  return contours;
}

std::optional<ShaftPose> shaftPose(Eigen::Matrix3d const& K, double radius, geometry::ApparentContour const& contour,
                                   geometry::CylinderPoseOptions const& options) {
  geometry::CylinderPoseResult const r = geometry::estimateCylinderPose(K, radius, contour, options);
  if (!r.ok()) return std::nullopt;
  return ShaftPose{r.pose, geometry::backProjectOntoAxis(K, r.pose.axis, contour.tip_px)};
}

Pipeline::Pipeline(Eigen::Matrix3d const& K, cv::Size size, PipelineParams const& params, perception::PointRectifier rectify)
    : K_(K), size_(size), params_(params), segmenter_(params.segmentation),
      points_(outOfViewOptions(params.insertion_points, K, size)), tracker_(params.tracking), rectify_(std::move(rectify)) {}

void Pipeline::reset() {
  segmenter_.reset();
  points_ = geometry::InsertionPointSet(outOfViewOptions(params_.insertion_points, K_, size_));
  tracker_ = geometry::ShaftTracker(params_.tracking);
}

PipelineOutput Pipeline::process(cv::Mat const& bgr, double stamp) {
  auto const t0 = std::chrono::steady_clock::now();
  PipelineOutput out;
  if (bgr.empty() || bgr.type() != CV_8UC3) {
    out.error = "expected a non-empty 8-bit BGR image";
    return out;
  }
  if (bgr.size() != size_) {
    out.error = "image size " + std::to_string(bgr.cols) + "x" + std::to_string(bgr.rows) + " differs from the camera's " +
                std::to_string(size_.width) + "x" + std::to_string(size_.height);
    return out;
  }
  // Images of the known, well-conditioned insertion points focus the seed search ([Doignon07] Sec. 4).
  std::vector<Eigen::Vector3d> trocar_images;
  wellConditionedImages(points_, K_, &trocar_images);
  bool const established = !trocar_images.empty();
  std::vector<geometry::ApparentContour> const contours =
      segmentShafts(segmenter_, tracker_, bgr, trocar_images, rectify_, params_.segmentation.contours, out.segmentation);
  for (geometry::ApparentContour const& c : contours) {
    auto const shaft = shaftPose(K_, params_.radius, c, params_.pose);
    if (!shaft) {
      ++out.rejected_pose;
      continue;
    }
    InstrumentObservation o;
    o.contour = c;
    o.pose = shaft->pose;
    bool keep = true;
    o.insertion_point = attachAxis(points_, o.pose, params_.reject_unattached, established, &keep, stamp);
    o.contour.insertion_point_id = o.insertion_point;
    o.track = c.track_id;
    if (!keep) {
      ++out.rejected_unattached;
      continue;
    }
    o.tip_c = shaft->tip_c;
    out.instruments.push_back(o);
  }
  out.insertion_points = reportInsertionPoints(points_, K_);
  // Each shaft attached to a located insertion point: its axis through that point.
  for (InstrumentObservation& o : out.instruments)
    o.constrained = axisThroughInsertionPoint(o.pose, o.insertion_point, out.insertion_points,
                                              params_.insertion_points.tracker.point_motion_sigma);
  out.latency_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

}  // namespace endo_guidance::pipeline
