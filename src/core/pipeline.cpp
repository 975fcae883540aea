// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/core/pipeline.h"

#include <chrono>
#include <cmath>

#include "endo_guidance/core/insertion_point_image.h"

namespace endo_guidance {

namespace {
InsertionPointSetOptions withOutOfView(InsertionPointSetOptions o, Eigen::Matrix3d const& K, cv::Size size) {
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
}  // namespace

Pipeline::Pipeline(Eigen::Matrix3d const& K, cv::Size size, PipelineParams const& params)
    : K_(K), size_(size), params_(params), segmenter_(params.segmentation),
      points_(withOutOfView(params.insertion_points, K, size)) {}

PipelineOutput Pipeline::process(cv::Mat const& bgr) {
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
  std::vector<int> trocar_ids;
  bool established = false;
  for (auto const& p : points_.points())
    if (p.tracker.wellConditioned()) {
      trocar_images.push_back(projectPointHomogeneous(K_, p.tracker.estimate().position));
      trocar_ids.push_back(p.id);
      established = true;
    }
  out.segmentation = segmenter_.process(bgr, trocar_images);
  for (ApparentContour const& c : out.segmentation.contours) {
    CylinderPoseResult const r = estimateCylinderPose(K_, params_.radius, c, params_.pose);
    if (!r.ok()) {
      ++out.rejected_pose;
      continue;
    }
    InstrumentObservation o;
    o.contour = c;
    o.pose = r.pose;
    o.insertion_point = points_.update(r.pose.axis, r.pose.covariance);  // Eq. (6) + tracking
    o.contour.insertion_point_id = o.insertion_point;
    if (params_.reject_unattached && established && o.insertion_point < 0) {
      ++out.rejected_unattached;
      continue;
    }
    o.tip_c = backProjectOntoAxis(K_, r.pose.axis, c.tip_px);
    out.instruments.push_back(o);
  }
  // Tracks: nearest previous shaft by image axis (angle and distance of its entry and tip).
  std::vector<bool> used(previous_.size(), false);
  for (auto& o : out.instruments) {
    Eigen::Vector3d const l = imageAxis(o.contour);
    int best = -1;
    double bd = params_.track_max_distance_px;
    for (std::size_t j = 0; j < previous_.size(); ++j) {
      if (used[j]) continue;
      Eigen::Vector3d const lp = imageAxis(previous_[j].contour);
      double const ang = std::acos(std::min(1.0, std::abs(l.head<2>().dot(lp.head<2>())))) * 180.0 / M_PI;
      if (ang > params_.track_max_angle_deg) continue;
      Eigen::Vector2d const& e = previous_[j].contour.entry_px;
      Eigen::Vector2d const& t = previous_[j].contour.tip_px;
      double const d = 0.5 * (std::abs(l.dot(Eigen::Vector3d(e.x(), e.y(), 1))) + std::abs(l.dot(Eigen::Vector3d(t.x(), t.y(), 1))));
      if (d < bd) {
        bd = d;
        best = static_cast<int>(j);
      }
    }
    if (best >= 0) {
      used[best] = true;
      o.track = previous_[best].track;
    } else {
      o.track = next_track_++;
    }
    o.contour.track_id = o.track;
  }
  previous_ = out.instruments;
  for (auto const& p : points_.points()) {
    if (!p.tracker.estimate().ok()) continue;
    InsertionPointReport rep;
    rep.id = p.id;
    rep.estimate = p.tracker.estimate();
    rep.image_point = projectPointHomogeneous(K_, rep.estimate.position);
    rep.well_conditioned = p.tracker.wellConditioned();
    out.insertion_points.push_back(rep);
  }
  out.latency_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  return out;
}

}  // namespace endo_guidance
