// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// endo_guidance/Segmentation: image + camera_info -> apparent contours of the instrument shafts
// (+ a debug overlay, drawn only when subscribed). A thin adapter over perception::InstrumentSegmenter.
#include <cv_bridge/cv_bridge.h>
#include <dynamic_reconfigure/server.h>
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/image_encodings.h>
#include <std_msgs/Header.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <memory>
#include <mutex>

#include "endo_guidance/ApparentContourArray.h"
#include "endo_guidance/InsertionPointArray.h"
#include "endo_guidance/SegmentationConfig.h"
#include "endo_guidance/geometry/shaft_tracking.h"
#include "endo_guidance/io/yaml_config.h"
#include "endo_guidance/perception/rectification.h"
#include "endo_guidance/perception/segmentation.h"
#include "endo_guidance/pipeline/pipeline.h"
#include "endo_guidance/ros/conversions.h"
#include "endo_guidance/ros/frame_monitor.h"
#include "endo_guidance/ros/reconfigure.h"
#include "endo_guidance/ros/transport_errors.h"

namespace endo_guidance {

class SegmentationNodelet : public nodelet::Nodelet {
 public:
  // Callbacks first (each shutdown waits for a running one): nodelet may still run them while the
  // members they read are destroyed.
  ~SegmentationNodelet() override {
    watchdog_.stop();
    camera_sub_.shutdown(), points_sub_.shutdown();
    monitor_.reset();
  }
  void onInit() override;

 private:
  void connectCb();
  void imageCb(sensor_msgs::ImageConstPtr const& image, sensor_msgs::CameraInfoConstPtr const& info);
  void checkStream(std_msgs::Header const& header, cv::Size size);
  void updateRectifier(sensor_msgs::CameraInfo const& info);
  void resetState();
  void pointsCb(InsertionPointArray::ConstPtr const& msg);
  void configCb(SegmentationConfig& config, uint32_t level);

  ros::NodeHandle nh_, pnh_;
  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::CameraSubscriber camera_sub_;
  image_transport::Publisher overlay_pub_;
  ros::Publisher contours_pub_;
  ros::Subscriber points_sub_;
  ros::WallTimer watchdog_;
  std::atomic<ros::WallTime> last_frame_{ros::WallTime()};  // set by imageCb, read by the watchdog
  std::unique_ptr<dynamic_reconfigure::Server<SegmentationConfig>> reconfigure_;
  boost::recursive_mutex reconfigure_mutex_;
  std::unique_ptr<ros_io::FrameMonitor> monitor_;

  std::mutex mutex_;  // guards everything below (image, points and reconfigure callbacks)
  std::mutex connect_mutex_;  // the camera subscription (lazy); never taken in imageCb: shutting the
                              // subscription down waits for a running imageCb (TSan: lock-order cycle)
  int queue_size_ = 2;
  bool reset_on_time_jump_ = true;
  pipeline::PipelineParams params_;
  perception::InstrumentSegmenter segmenter_;
  geometry::ShaftTracker tracker_;
  std::vector<Eigen::Vector3d> trocar_images_;
  std::vector<int> trocar_ids_;
  ros::Time last_stamp_;
  cv::Size last_size_;
  sensor_msgs::CameraInfo rectified_for_;  // the camera model rectify_ was built for
  std::function<Eigen::Vector2d(Eigen::Vector2d const&)> rectify_;
  // For the diagnostics: the last frame's shafts, and the strip searches (the costliest step)
  // over the frames since the last report.
  std::mutex diag_mutex_;
  int last_shafts_ = 0;
  std::size_t diag_frames_ = 0, diag_strip_searches_ = 0;
};

void SegmentationNodelet::onInit() {
  nh_ = getNodeHandle();
  pnh_ = getPrivateNodeHandle();
  pnh_.param("queue_size", queue_size_, 2);
  pnh_.param("reset_on_time_jump", reset_on_time_jump_, true);
  try {
    for (auto const& k : ros_io::loadPipelineParams(pnh_, params_, {"queue_size", "reset_on_time_jump", "image_transport", "expected_rate"}))
      if (!ros_io::isReconfigureMirror<SegmentationConfig>(k)) NODELET_WARN_STREAM("unknown parameter '" << k << "' ignored");
  } catch (std::exception const& e) {
    NODELET_ERROR_STREAM("bad parameters, using the defaults: " << e.what());
    params_ = pipeline::PipelineParams{};
  }
  try {
    segmenter_.setParams(params_.segmentation);  // (loads the learned detector's model)
  } catch (std::exception const& e) {
    NODELET_FATAL_STREAM("cannot start: " << e.what());
    ros::requestShutdown();
    return;
  }
  tracker_.setParams(params_.tracking);
  double expected_rate = 0.0;
  pnh_.param("expected_rate", expected_rate, 0.0);
  monitor_ = std::make_unique<ros_io::FrameMonitor>(nh_, pnh_, "segmentation", expected_rate);
  monitor_->setExtra([this](diagnostic_updater::DiagnosticStatusWrapper& s) {
    std::lock_guard<std::mutex> lock(diag_mutex_);
    s.add("detector", io::toString(params_.segmentation.detector));
    s.add("shafts (last frame)", last_shafts_);
    s.addf("strip searches per frame", "%.2f", diag_frames_ ? static_cast<double>(diag_strip_searches_) / diag_frames_ : 0.0);
    diag_frames_ = diag_strip_searches_ = 0;
  });

  // Live tuning starts from the loaded values, not the .cfg defaults.
  reconfigure_ = std::make_unique<dynamic_reconfigure::Server<SegmentationConfig>>(reconfigure_mutex_, pnh_);
  SegmentationConfig c = SegmentationConfig::__getDefault__();  // (every field set, groups included)
  ros_io::toReconfigure(params_, io::Live::kSegmentation, c);
  reconfigure_->updateConfig(c);
  reconfigure_->setCallback([this](SegmentationConfig& cfg, uint32_t level) { configCb(cfg, level); });

  it_ = std::make_unique<image_transport::ImageTransport>(nh_);
  points_sub_ = nh_.subscribe("insertion_points", 2, &SegmentationNodelet::pointsCb, this);
  // Lazy: the camera is subscribed only while someone listens to an output.
  std::lock_guard<std::mutex> lock(connect_mutex_);
  auto const cb = [this](ros::SingleSubscriberPublisher const&) { connectCb(); };
  auto const icb = [this](image_transport::SingleSubscriberPublisher const&) { connectCb(); };
  contours_pub_ = nh_.advertise<ApparentContourArray>("contours", 5, cb, cb);
  overlay_pub_ = it_->advertise("overlay", 1, icb, icb);
  // image_transport pairs images and camera_info by stamp: without camera_info nothing arrives.
  watchdog_ = nh_.createWallTimer(ros::WallDuration(1.0), [this](ros::WallTimerEvent const&) {
    std::lock_guard<std::mutex> lock(connect_mutex_);
    if (!camera_sub_ || camera_sub_.getNumPublishers() == 0) {
      last_frame_ = ros::WallTime::now();
      return;
    }
    // Frames the image transport could not decode never reach imageCb: report them here.
    // (the transport's topic: <image>/<transport>, which getTopic() may or may not include)
    std::string const topic = camera_sub_.getTopic(), transport = camera_sub_.getTransport();
    for (std::string const& t : {topic, topic + "/" + transport})
      if (auto const [lost, why] = ros_io::TransportErrors::instance().take(t); lost > 0)
        monitor_->rejected(std::to_string(lost) + " frame(s) not decoded by the '" + transport + "' transport: " + why);
    if ((ros::WallTime::now() - last_frame_.load()).toSec() > 3.0)
      monitor_->rejected("no image + camera_info pair for 3 s on '" + camera_sub_.getTopic() + "' and '" + camera_sub_.getInfoTopic() +
                         "': is camera_info published, with the images' stamps?");
  });
}

void SegmentationNodelet::connectCb() {
  std::lock_guard<std::mutex> lock(connect_mutex_);
  bool const wanted = contours_pub_.getNumSubscribers() > 0 || overlay_pub_.getNumSubscribers() > 0;
  if (!wanted) {
    camera_sub_.shutdown();
  } else if (!camera_sub_) {
    image_transport::TransportHints hints("raw", ros::TransportHints(), pnh_);
    camera_sub_ = it_->subscribeCamera("image", static_cast<uint32_t>(queue_size_), &SegmentationNodelet::imageCb, this, hints);
  }
}

void SegmentationNodelet::configCb(SegmentationConfig& c, uint32_t) {
  std::lock_guard<std::mutex> lock(mutex_);
  ros_io::fromReconfigure(c, io::Live::kSegmentation, params_);
  segmenter_.setParams(params_.segmentation);
}

void SegmentationNodelet::pointsCb(InsertionPointArray::ConstPtr const& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  trocar_images_.clear();
  trocar_ids_.clear();
  for (auto const& p : msg->points) {
    Eigen::Vector3d const x(p.image_point[0], p.image_point[1], p.image_point[2]);
    if (!p.well_conditioned || !x.allFinite() || x.norm() == 0.0) continue;
    trocar_images_.push_back(x);
    trocar_ids_.push_back(p.id);
  }
}

void SegmentationNodelet::imageCb(sensor_msgs::ImageConstPtr const& image, sensor_msgs::CameraInfoConstPtr const& info) {
  monitor_->received();
  last_frame_ = ros::WallTime::now();
  namespace enc = sensor_msgs::image_encodings;
  if (image->encoding != enc::BGR8 && image->encoding != enc::RGB8 && image->encoding != enc::BGRA8 &&
      image->encoding != enc::RGBA8)
    return monitor_->rejected("image encoding '" + image->encoding + "' is not 8-bit colour (bgr8, rgb8, bgra8, rgba8)");
  if (std::string const e = ros_io::validateCameraInfo(*info, static_cast<int>(image->width), static_cast<int>(image->height)); !e.empty())
    return monitor_->rejected(e);
  if (image->header.frame_id.empty()) return monitor_->rejected("image header has no frame_id (the optical frame)");
  cv_bridge::CvImageConstPtr cv;
  try {
    cv = cv_bridge::toCvShare(image, enc::BGR8);
  } catch (cv_bridge::Exception const& e) {
    return monitor_->rejected(std::string("cv_bridge: ") + e.what());
  }
  auto const t0 = std::chrono::steady_clock::now();
  std::lock_guard<std::mutex> lock(mutex_);
  checkStream(image->header, cv::Size(static_cast<int>(image->width), static_cast<int>(image->height)));
  updateRectifier(*info);
  perception::SegmentationResult seg;
  std::vector<geometry::ApparentContour> contours =
      pipeline::segmentShafts(segmenter_, tracker_, cv->image, trocar_images_, rectify_, params_.segmentation.contours, seg);
  {
    std::lock_guard<std::mutex> lock(diag_mutex_);
    last_shafts_ = static_cast<int>(seg.contours.size());
    ++diag_frames_;
    diag_strip_searches_ += static_cast<std::size_t>(seg.strip_searches);
  }
  ApparentContourArray::Ptr out(new ApparentContourArray);
  out->header = image->header;
  out->width = image->width;
  out->height = image->height;
  for (geometry::ApparentContour& c : contours) {
    // The seed search attached the region to the image of a trocar (index into trocar_images_).
    c.insertion_point_id = c.insertion_point_id >= 0 && c.insertion_point_id < static_cast<int>(trocar_ids_.size())
                               ? trocar_ids_[static_cast<std::size_t>(c.insertion_point_id)]
                               : -1;
    endo_guidance::ApparentContour m;
    if (ros_io::toMsg(c, m)) out->contours.push_back(m);
  }
  contours_pub_.publish(out);
  monitor_->processed(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count(),
                      image->header.stamp);
  if (overlay_pub_.getNumSubscribers() > 0) {
    cv_bridge::CvImage ov(image->header, enc::BGR8, cv->image.clone());
    perception::drawSegmentationOverlay(ov.image, seg, trocar_images_);
    overlay_pub_.publish(ov.toImageMsg());
  }
}

void SegmentationNodelet::resetState() {
  segmenter_.setParams(params_.segmentation);  // clears the per-seed memory
  tracker_.reset();
}

// A looped bag (time backwards) or a new camera mode resets what was tracked (caller holds mutex_).
void SegmentationNodelet::checkStream(std_msgs::Header const& header, cv::Size size) {
  if (!last_stamp_.isZero() && header.stamp < last_stamp_) {
    char b[64];
    std::snprintf(b, sizeof b, "%.2f", (last_stamp_ - header.stamp).toSec());
    monitor_->warn(std::string("time went backwards (") + b + " s, bag loop?)" + (reset_on_time_jump_ ? ": state reset" : ""));
    if (reset_on_time_jump_) resetState();
  }
  last_stamp_ = header.stamp;
  // A new camera mode: what was tracked, and the trocars' images, are in the old pixels.
  if (size == last_size_) return;
  if (!last_size_.empty()) {
    monitor_->warn("image size changed " + std::to_string(last_size_.width) + "x" + std::to_string(last_size_.height) + " -> " +
                   std::to_string(size.width) + "x" + std::to_string(size.height) + ": state reset");
    resetState();
    // The trocars' images in the new pixels until InsertionPoints sends them: u' + w/2 = s (u + w/2).
    double const sx = static_cast<double>(size.width) / last_size_.width, sy = static_cast<double>(size.height) / last_size_.height;
    for (Eigen::Vector3d& x : trocar_images_) {
      x.x() = sx * (x.x() + 0.5 * x.z()) - 0.5 * x.z();
      x.y() = sy * (x.y() + 0.5 * x.z()) - 0.5 * x.z();
      x.normalize();
    }
  }
  last_size_ = size;
}

// Lens distortion: the lines are refitted to the rectified edge points (the map is rebuilt only
// when the camera model changes).
void SegmentationNodelet::updateRectifier(sensor_msgs::CameraInfo const& info) {
  if (!ros_io::hasDistortion(info)) {
    rectify_ = nullptr;
    return;
  }
  if (!rectify_ || info.D != rectified_for_.D || info.K != rectified_for_.K || info.R != rectified_for_.R || info.P != rectified_for_.P) {
    rectify_ = ros_io::rectifier(info);
    rectified_for_ = info;
  }
}

}  // namespace endo_guidance

PLUGINLIB_EXPORT_CLASS(endo_guidance::SegmentationNodelet, nodelet::Nodelet)
