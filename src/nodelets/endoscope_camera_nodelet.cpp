// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// endo_guidance/EndoscopeCamera: a real endoscope (V4L2/UVC device or frame grabber, video file,
// stream URL) -> image_raw + camera_info (camera_info_manager, camera_info_url, set_camera_info
// for cameracalibrator.py), stamped at grab time. A thin adapter over io::EndoscopeCapture, which
// reconnects with backoff, drops repeated buffers and loops or stops at a file's end.
#include <camera_info_manager/camera_info_manager.h>
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_updater/diagnostic_updater.h>
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/image_encodings.h>

#include <atomic>
#include <deque>
#include <memory>
#include <mutex>
#include <thread>

#include "endo_guidance/io/endoscope_capture.h"
#include "endo_guidance/ros/conversions.h"

namespace endo_guidance {

class EndoscopeCameraNodelet : public nodelet::Nodelet {
 public:
  ~EndoscopeCameraNodelet() override;
  void onInit() override;

 private:
  void run();
  void publish(cv::Mat const& frame, ros::Time const& stamp);
  void diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat);

  ros::NodeHandle nh_, pnh_;
  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::CameraPublisher pub_;
  std::unique_ptr<camera_info_manager::CameraInfoManager> info_manager_;
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  ros::Timer diag_timer_;
  std::unique_ptr<io::EndoscopeCapture> capture_;
  std::string frame_id_;
  std::thread thread_;
  std::atomic<bool> running_{false};

  std::mutex mutex_;  // guards the diagnostics' view below
  io::EndoscopeCapture::Status status_ = io::EndoscopeCapture::Status::kDisconnected;
  std::string error_, opened_, info_problem_;
  double retry_in_ = 0.0;
  bool connected_ = false;
  std::size_t captured_ = 0, duplicates_ = 0, undecodable_ = 0, reconnects_ = 0, loops_ = 0;
  std::size_t published_ = 0, unsubscribed_ = 0;
  std::deque<ros::WallTime> times_;  // publication times of the last seconds (rate)
  ros::Time last_stamp_;
};

EndoscopeCameraNodelet::~EndoscopeCameraNodelet() {
  running_ = false;
  if (thread_.joinable()) thread_.join();
}

void EndoscopeCameraNodelet::onInit() {
  nh_ = getNodeHandle();
  pnh_ = getPrivateNodeHandle();
  io::CaptureParams p;
  std::string camera_name, url;
  pnh_.param<std::string>("source", p.source, "0");
  pnh_.param("width", p.width, 0);
  pnh_.param("height", p.height, 0);
  pnh_.param("fps", p.fps, 0.0);
  pnh_.param<std::string>("pixel_format", p.pixel_format, "");
  pnh_.param("loop", p.loop, false);
  pnh_.param("reconnect_min", p.reconnect_min_s, 0.5);
  pnh_.param("reconnect_max", p.reconnect_max_s, 8.0);
  pnh_.param<std::string>("camera_name", camera_name, "endoscope");
  pnh_.param<std::string>("camera_info_url", url, "");
  pnh_.param<std::string>("frame_id", frame_id_, "endoscope_optical_frame");
  try {
    capture_ = std::make_unique<io::EndoscopeCapture>(p);
  } catch (std::exception const& e) {
    NODELET_FATAL_STREAM("EndoscopeCamera: bad parameters: " << e.what());
    ros::requestShutdown();
    return;
  }
  // In the camera's namespace: <ns>/set_camera_info, where cameracalibrator.py commits.
  info_manager_ = std::make_unique<camera_info_manager::CameraInfoManager>(nh_, camera_name, url);
  if (!url.empty() && !info_manager_->isCalibrated())
    NODELET_WARN_STREAM("EndoscopeCamera: no calibration loaded from '" << url << "'");
  it_ = std::make_unique<image_transport::ImageTransport>(nh_);
  pub_ = it_->advertiseCamera("image_raw", 2);
  updater_ = std::make_unique<diagnostic_updater::Updater>(nh_, pnh_, pnh_.getNamespace());
  updater_->setHardwareID(p.source);
  updater_->add("endoscope camera", this, &EndoscopeCameraNodelet::diagnose);
  diag_timer_ = nh_.createTimer(ros::Duration(1.0), [this](ros::TimerEvent const&) { updater_->update(); });
  running_ = true;
  thread_ = std::thread(&EndoscopeCameraNodelet::run, this);
}

// The capture thread: a device or stream paces itself (its reads block); a file is played at
// its own rate (or `fps`), the frame grabbed at its slot so that the stamp is the slot's time.
void EndoscopeCameraNodelet::run() {
  using Clock = std::chrono::steady_clock;
  double const file_fps = capture_->playbackFps();
  Clock::time_point slot = Clock::now();
  bool was_connected = false;
  io::EndoscopeCapture::Status last = io::EndoscopeCapture::Status::kFrame;
  while (running_ && ros::ok()) {
    if (file_fps > 0.0 && capture_->connected()) {
      std::this_thread::sleep_until(slot);
      auto const period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(1.0 / file_fps));
      slot = std::max(slot + period, Clock::now() - period);  // behind by more than a frame: no burst to catch up
    }
    cv::Mat frame;
    ros::Time stamp;
    auto const s = capture_->next(frame, [&] { stamp = ros::Time::now(); });
    {
      std::lock_guard<std::mutex> lock(mutex_);
      status_ = s;
      error_ = capture_->lastError();
      retry_in_ = capture_->retryIn();
      connected_ = capture_->connected();
      captured_ = capture_->frames();
      duplicates_ = capture_->duplicates();
      undecodable_ = capture_->undecodable();
      reconnects_ = capture_->reconnects();
      loops_ = capture_->loops();
      if (capture_->connected() && !was_connected) opened_ = capture_->describe();
    }
    if (capture_->connected() != was_connected) {
      if (capture_->connected())
        NODELET_INFO_STREAM("EndoscopeCamera: opened '" << capture_->params().source << "' (" << capture_->describe() << ")");
      was_connected = capture_->connected();
      slot = Clock::now();
    }
    switch (s) {
      case io::EndoscopeCapture::Status::kFrame: publish(frame, stamp); break;
      case io::EndoscopeCapture::Status::kDisconnected:
        NODELET_WARN_STREAM_THROTTLE(5.0, "EndoscopeCamera: " << capture_->lastError() << "; retrying in " << capture_->retryIn() << " s");
        std::this_thread::sleep_for(std::chrono::duration<double>(std::min(0.05, capture_->retryIn() + 1e-3)));
        break;
      case io::EndoscopeCapture::Status::kEnded:
        if (last != s) NODELET_INFO_STREAM("EndoscopeCamera: end of '" << capture_->params().source << "' (loop:=false): stopped");
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
        break;
      case io::EndoscopeCapture::Status::kDuplicate:
      case io::EndoscopeCapture::Status::kUndecodable: break;
    }
    last = s;
  }
}

void EndoscopeCameraNodelet::publish(cv::Mat const& frame, ros::Time const& grabbed) {
  ros::Time stamp = grabbed;
  if (!last_stamp_.isZero() && stamp <= last_stamp_) stamp = last_stamp_ + ros::Duration(0, 1000);  // stamps strictly increase
  last_stamp_ = stamp;
  if (pub_.getNumSubscribers() == 0) {
    std::lock_guard<std::mutex> lock(mutex_);
    ++unsubscribed_;
    return;
  }
  std_msgs::Header h;
  h.stamp = stamp;
  h.frame_id = frame_id_;
  std::string const enc = frame.channels() == 1 ? sensor_msgs::image_encodings::MONO8
                    : frame.channels() == 4 ? sensor_msgs::image_encodings::BGRA8
                                            : sensor_msgs::image_encodings::BGR8;
  if (frame.depth() != CV_8U) {
    std::lock_guard<std::mutex> lock(mutex_);
    error_ = "frames of depth other than 8 bit are not published";
    return;
  }
  sensor_msgs::ImagePtr img = cv_bridge::CvImage(h, enc, frame).toImageMsg();
  auto info = boost::make_shared<sensor_msgs::CameraInfo>(info_manager_->getCameraInfo());
  std::string problem;
  if (!info_manager_->isCalibrated()) {
    info->width = static_cast<std::uint32_t>(frame.cols);  // K stays 0: the pipeline says "not calibrated"
    info->height = static_cast<std::uint32_t>(frame.rows);
    problem = "not calibrated (camera_info_url; docs/camera.md)";
  } else if (info->width != static_cast<std::uint32_t>(frame.cols) || info->height != static_cast<std::uint32_t>(frame.rows)) {
    problem = "calibrated for " + std::to_string(info->width) + "x" + std::to_string(info->height) + ", frames are " +
              std::to_string(frame.cols) + "x" + std::to_string(frame.rows);
  } else {
    problem = ros_io::validateCameraInfo(*info, frame.cols, frame.rows);
  }
  info->header = h;
  pub_.publish(img, info);
  std::lock_guard<std::mutex> lock(mutex_);
  info_problem_ = problem;
  ++published_;
  ros::WallTime const now = ros::WallTime::now();
  times_.push_back(now);
  while (!times_.empty() && (now - times_.front()).toSec() > 5.0) times_.pop_front();
}

void EndoscopeCameraNodelet::diagnose(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  std::lock_guard<std::mutex> lock(mutex_);
  using S = io::EndoscopeCapture::Status;
  double rate = 0.0;
  if (times_.size() >= 2) rate = (times_.size() - 1) / std::max(1e-6, (times_.back() - times_.front()).toSec());
  if (status_ == S::kEnded)
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "end of file: stopped (loop:=false)");
  else if (!connected_)
    stat.summaryf(diagnostic_msgs::DiagnosticStatus::ERROR, "no frames: %s; retrying in %.1f s", error_.c_str(), retry_in_);
  else if (!info_problem_.empty())
    stat.summary(diagnostic_msgs::DiagnosticStatus::WARN, "streaming, camera_info " + info_problem_);
  else
    stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "streaming");
  stat.add("source", capture_->params().source);
  stat.add("opened as", opened_);
  stat.add("frames captured", captured_);
  stat.add("frames published", published_);
  stat.add("frames without subscriber", unsubscribed_);
  stat.add("repeated buffers dropped", duplicates_);
  stat.add("undecodable frames", undecodable_);
  stat.add("reconnections", reconnects_);
  stat.add("loops", loops_);
  stat.addf("publication rate (Hz)", "%.2f", rate);
  stat.add("last error", error_);
}

}  // namespace endo_guidance

PLUGINLIB_EXPORT_CLASS(endo_guidance::EndoscopeCameraNodelet, nodelet::Nodelet)
