// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// endo_guidance/CylinderPose: apparent contours + camera_info -> instrument axes (Plücker, with
// covariance) + rviz markers. A thin adapter over geometry::estimateCylinderPose().
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <visualization_msgs/MarkerArray.h>

#include <chrono>
#include <memory>
#include <mutex>

#include "endo_guidance/ApparentContourArray.h"
#include "endo_guidance/InstrumentAxisArray.h"
#include "endo_guidance/geometry/cylinder_pose.h"
#include "endo_guidance/pipeline/pipeline.h"
#include "endo_guidance/ros/conversions.h"
#include "endo_guidance/ros/frame_monitor.h"
#include "endo_guidance/ros/markers.h"

namespace endo_guidance {

class CylinderPoseNodelet : public nodelet::Nodelet {
 public:
  void onInit() override;

 private:
  void infoCb(sensor_msgs::CameraInfoConstPtr const& info);
  void contoursCb(ApparentContourArray::ConstPtr const& msg);

  ros::NodeHandle nh_, pnh_;
  ros::Subscriber contours_sub_, info_sub_;
  ros::Publisher axes_pub_, markers_pub_;
  std::unique_ptr<ros_io::FrameMonitor> monitor_;
  pipeline::PipelineParams params_;
  std::mutex mutex_;
  sensor_msgs::CameraInfoConstPtr info_;
  std::string info_error_ = "no camera_info received yet";
};

void CylinderPoseNodelet::onInit() {
  nh_ = getNodeHandle();
  pnh_ = getPrivateNodeHandle();
  try {
    for (auto const& k : ros_io::loadPipelineParams(pnh_, params_, {"expected_rate"}))
      NODELET_WARN_STREAM("unknown parameter '" << k << "' ignored");
  } catch (std::exception const& e) {
    NODELET_ERROR_STREAM("bad parameters, using the defaults: " << e.what());
    params_ = pipeline::PipelineParams{};
  }
  if (!(params_.radius > 0.0) || !std::isfinite(params_.radius)) {
    NODELET_ERROR_STREAM("radius must be > 0 m (got " << params_.radius << "); using 0.004");
    params_.radius = 0.004;
  }
  double expected_rate = 0.0;
  pnh_.param("expected_rate", expected_rate, 0.0);
  monitor_ = std::make_unique<ros_io::FrameMonitor>(nh_, pnh_, "cylinder_pose", expected_rate);
  axes_pub_ = nh_.advertise<InstrumentAxisArray>("axes", 5);
  markers_pub_ = nh_.advertise<visualization_msgs::MarkerArray>("shaft_markers", 2);
  info_sub_ = nh_.subscribe("camera_info", 2, &CylinderPoseNodelet::infoCb, this);
  contours_sub_ = nh_.subscribe("contours", 5, &CylinderPoseNodelet::contoursCb, this);
}

void CylinderPoseNodelet::infoCb(sensor_msgs::CameraInfoConstPtr const& info) {
  std::lock_guard<std::mutex> lock(mutex_);
  info_error_ = ros_io::validateCameraInfo(*info);
  info_ = info_error_.empty() ? info : nullptr;
}

void CylinderPoseNodelet::contoursCb(ApparentContourArray::ConstPtr const& msg) {
  monitor_->received();
  auto const t0 = std::chrono::steady_clock::now();
  sensor_msgs::CameraInfoConstPtr info;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (!info_) return monitor_->rejected(info_error_);
    info = info_;
  }
  if (msg->width != info->width || msg->height != info->height)
    return monitor_->rejected("contours of a " + std::to_string(msg->width) + "x" + std::to_string(msg->height) +
                              " image, camera_info is " + std::to_string(info->width) + "x" + std::to_string(info->height));
  Eigen::Matrix3d const K = ros_io::rectifiedK(*info);
  InstrumentAxisArray::Ptr out(new InstrumentAxisArray);
  out->header = msg->header;
  bool const markers = markers_pub_.getNumSubscribers() > 0;
  visualization_msgs::MarkerArray::Ptr mk(new visualization_msgs::MarkerArray);
  if (markers) mk->markers.push_back(ros_io::deleteAll(msg->header));
  int rejected = 0;
  for (auto const& cm : msg->contours) {
    geometry::ApparentContour const c = ros_io::fromMsg(cm);
    auto const shaft = pipeline::shaftPose(K, params_.radius, c, params_.pose);
    if (!shaft) {  // degenerate geometry (parallel lines, behind the camera, too near/far): flagged, not guessed
      ++rejected;
      continue;
    }
    InstrumentAxis a;
    if (!ros_io::toMsg(shaft->pose, params_.radius, c.residual_px, shaft->tip_c, a)) {
      ++rejected;
      continue;
    }
    a.insertion_point_id = c.insertion_point_id;
    a.track_id = c.track_id;
    out->axes.push_back(a);
    if (markers) ros_io::appendShaftMarkers(mk->markers, msg->header, static_cast<int>(out->axes.size()) - 1, shaft->pose,
                                             params_.radius, shaft->tip_c);
  }
  if (rejected > 0) NODELET_DEBUG_STREAM(rejected << " contours gave no valid pose");
  axes_pub_.publish(out);
  if (markers) markers_pub_.publish(mk);
  monitor_->processed(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count(), msg->header.stamp);
}

}  // namespace endo_guidance

PLUGINLIB_EXPORT_CLASS(endo_guidance::CylinderPoseNodelet, nodelet::Nodelet)
