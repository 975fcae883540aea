// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/ros/frame_monitor.h"

namespace endo_guidance::ros_io {

FrameMonitor::FrameMonitor(ros::NodeHandle& nh, ros::NodeHandle& pnh, std::string const& name, double expected_hz)
    : updater_(nh, pnh, pnh.getNamespace()), name_(name), expected_hz_(expected_hz) {
  updater_.setHardwareID("endoscope");
  updater_.add(name, this, &FrameMonitor::produce);
  timer_ = nh.createSteadyTimer(ros::WallDuration(1.0), [this](ros::SteadyTimerEvent const&) { updater_.force_update(); });
}

void FrameMonitor::received() {
  std::lock_guard<std::mutex> lock(mutex_);
  ros::WallTime const now = ros::WallTime::now();
  arrivals_.push_back(now);
  while (!arrivals_.empty() && (now - arrivals_.front()).toSec() > 5.0) arrivals_.pop_front();
}

void FrameMonitor::processed(double processing_ms, ros::Time const& stamp) {
  std::lock_guard<std::mutex> lock(mutex_);
  ++frames_;
  ++processed_since_;
  proc_ms_ = frames_ == 1 ? processing_ms : 0.9 * proc_ms_ + 0.1 * processing_ms;
  double const lat = (ros::Time::now() - stamp).toSec() * 1e3;
  latency_ms_ = frames_ == 1 ? lat : 0.9 * latency_ms_ + 0.1 * lat;
}

void FrameMonitor::rejected(std::string const& reason) {
  ROS_ERROR_STREAM_THROTTLE(2.0, name_ << ": input rejected: " << reason);
  std::lock_guard<std::mutex> lock(mutex_);
  ++rejected_;
  ++rejected_since_;
  last_error_ = reason;
  last_error_time_ = ros::WallTime::now();
}

void FrameMonitor::warn(std::string const& reason) {
  ROS_WARN_STREAM(name_ << ": " << reason);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    ++warned_since_;
    last_warning_ = reason;
  }
  updater_.force_update();
}

std::size_t FrameMonitor::rejectedCount() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return rejected_;
}

void FrameMonitor::produce(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    using diagnostic_msgs::DiagnosticStatus;
    double rate = 0.0;
    if (arrivals_.size() >= 2) rate = (arrivals_.size() - 1) / std::max(1e-6, (arrivals_.back() - arrivals_.front()).toSec());
    // Stalled: no input for five nominal periods (at least 0.5 s) after input had come.
    double const silent = arrivals_.empty() ? 0.0 : (ros::WallTime::now() - arrivals_.back()).toSec();
    bool const stalled = silent > std::max(0.5, expected_hz_ > 0.0 ? 5.0 / expected_hz_ : 1.0);
    if (silent > 2.0) rate = 0.0;
    stat.add("frames processed", frames_);
    stat.add("inputs rejected", rejected_);
    stat.add("input rate (Hz)", rate);
    stat.add("processing time (ms)", proc_ms_);
    stat.add("latency (ms)", latency_ms_);
    stat.add("last error", last_error_.empty() ? std::string("none") : last_error_);
    stat.add("last warning", last_warning_.empty() ? std::string("none") : last_warning_);
    stat.summary(DiagnosticStatus::OK, "running");
    if (stalled) stat.summaryf(DiagnosticStatus::WARN, "no input for %.1f s (stalled)", silent);
    else if (expected_hz_ > 0.0 && rate < 0.5 * expected_hz_)
      stat.summaryf(DiagnosticStatus::WARN, "input rate %.1f Hz (expected %.1f Hz)", rate, expected_hz_);
    // Merged: an ERROR keeps the warnings of the same period in its message.
    if (warned_since_ > 0) stat.mergeSummary(DiagnosticStatus::WARN, last_warning_);
    if (rejected_since_ > 0)
      stat.mergeSummaryf(DiagnosticStatus::ERROR, "%zu input(s) rejected in the last period: %s", rejected_since_,
                         last_error_.c_str());
    rejected_since_ = processed_since_ = warned_since_ = 0;
  }
  // Outside the lock: the node's callback takes its own lock, and the node calls rejected()
  // while holding it (one lock order only).
  if (extra_) extra_(stat);
}

}  // namespace endo_guidance::ros_io
