// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// What every node reports on /diagnostics: frames processed and rejected (with the last
// reason), input rate, processing time and input-to-output latency, a stalled input, events that
// reset the node's state, plus node-specific values. Published at 1 Hz by the steady clock, so
// that it goes on when simulated time stops or jumps back (a paused or looped bag).
#pragma once

#include <diagnostic_updater/diagnostic_updater.h>
#include <ros/ros.h>

#include <deque>
#include <mutex>
#include <string>

namespace endo_guidance::ros_io {

class FrameMonitor {
 public:
  /// `name`: the diagnostic task; `expected_hz`: the nominal input rate (0 = no rate check).
  FrameMonitor(ros::NodeHandle& nh, ros::NodeHandle& pnh, std::string const& name, double expected_hz = 0.0);
  /// A frame arrived (wall time, for the input rate).
  void received();
  /// A frame was processed: processing time and latency (now - stamp, only meaningful on live
  /// data; on a replayed bag with use_sim_time it is the lag behind /clock).
  void processed(double processing_ms, ros::Time const& stamp);
  /// A frame (or message) was rejected: logged (throttled) and counted; the node keeps running.
  void rejected(std::string const& reason);
  /// An event the node recovered from by itself (state reset on a clock jump or a new camera
  /// mode): logged and reported as a WARN for one period.
  void warn(std::string const& reason);
  /// Publish now (after an event a supervisor should see without waiting for the period).
  void forceUpdate() { updater_.force_update(); }
  /// Extra key/values and a warning level set by the node (e.g. trocar conditioning).
  void setExtra(std::function<void(diagnostic_updater::DiagnosticStatusWrapper&)> f) { extra_ = std::move(f); }
  std::size_t rejectedCount() const;

 private:
  void produce(diagnostic_updater::DiagnosticStatusWrapper& stat);
  diagnostic_updater::Updater updater_;
  ros::SteadyTimer timer_;
  std::string name_;
  double expected_hz_;
  mutable std::mutex mutex_;
  std::deque<ros::WallTime> arrivals_;
  std::size_t frames_ = 0, rejected_ = 0, rejected_since_ = 0, processed_since_ = 0, warned_since_ = 0;
  double proc_ms_ = 0.0, latency_ms_ = 0.0;
  std::string last_error_, last_warning_;
  ros::WallTime last_error_time_;
  std::function<void(diagnostic_updater::DiagnosticStatusWrapper&)> extra_;
};

}  // namespace endo_guidance::ros_io
