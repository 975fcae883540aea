// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// endo_guidance/MotionScript: a scripted "surgeon" for the simulation: smooth sinusoidal
// InstrumentVelocity commands (pan, tilt, insertion, roll) to each arm, so that the shafts sweep
// about their trocars as in surgery (the vision pipeline needs that angular spread); with
// `duration` > 0 it stops after that many seconds (then another commander, e.g. the servo, takes over);
// ~restart (std_srvs/Trigger) plays it again from the start (e.g. to re-locate the trocars).
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <std_srvs/Trigger.h>

#include <cmath>
#include <mutex>

#include "endo_guidance/InstrumentVelocity.h"

namespace endo_guidance {

class MotionScriptNodelet : public nodelet::Nodelet {
 public:
  void onInit() override {
    ros::NodeHandle& nh = getNodeHandle();
    ros::NodeHandle& pnh = getPrivateNodeHandle();
    double rate = 50.0;
    pnh.param("rate", rate, 50.0);
    pnh.param("arms", arms_, std::vector<std::string>{"arm_0"});
    pnh.param<std::string>("frame_prefix", prefix_, "");
    pnh.param("amplitude", amplitude_, std::vector<double>{0.12, 0.12, 0.012, 0.3});
    pnh.param("period", period_, std::vector<double>{7.0, 5.3, 9.1, 11.0});
    pnh.param("duration", duration_, 0.0);
    if (amplitude_.size() != 4 || period_.size() != 4 || !(rate > 0.0)) {
      NODELET_FATAL("MotionScript: amplitude and period need 4 values, rate > 0");
      return;
    }
    for (auto const& a : arms_) pubs_.push_back(nh.advertise<InstrumentVelocity>(a + "/command", 5));
    start_ = ros::WallTime::now();
    restart_srv_ = pnh.advertiseService("restart", &MotionScriptNodelet::restart, this);
    timer_ = nh.createWallTimer(ros::WallDuration(1.0 / rate), [this](ros::WallTimerEvent const&) { tick(); });
  }

 private:
  bool restart(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    std::lock_guard<std::mutex> lock(mutex_);
    start_ = ros::WallTime::now();
    finished_ = false;
    res.success = true;
    res.message = "motion script restarted";
    NODELET_INFO("MotionScript: restarted");
    return true;
  }
  void tick() {
    std::lock_guard<std::mutex> lock(mutex_);
    double const t = (ros::WallTime::now() - start_).toSec();
    if (duration_ > 0.0 && t > duration_) {  // done: hand the arms over (one zero command, then silence)
      if (!finished_) {
        for (std::size_t i = 0; i < pubs_.size(); ++i) {
          InstrumentVelocity c;
          c.header.stamp = ros::Time::now();
          c.header.frame_id = prefix_ + "trocar_" + std::to_string(i);
          pubs_[i].publish(c);
        }
        NODELET_INFO("MotionScript: done after %.1f s", duration_);
      }
      finished_ = true;
      return;
    }
    for (std::size_t i = 0; i < pubs_.size(); ++i) {
      // q_j(t) = A_j sin(w_j t + phase): the commanded rate is its derivative.
      auto rate = [&](int j) {
        double const w = 2.0 * M_PI / period_[j];
        return amplitude_[j] * w * std::cos(w * t + 1.3 * i + j);
      };
      InstrumentVelocity c;
      c.header.stamp = ros::Time::now();
      c.header.frame_id = prefix_ + "trocar_" + std::to_string(i);
      c.pan_rate = rate(0);
      c.tilt_rate = rate(1);
      c.insertion_rate = rate(2);
      c.roll_rate = rate(3);
      pubs_[i].publish(c);
    }
  }
  std::vector<std::string> arms_;
  std::string prefix_;
  std::vector<double> amplitude_, period_;
  double duration_ = 0.0;  // s, 0 = forever
  bool finished_ = false;
  std::vector<ros::Publisher> pubs_;
  ros::WallTimer timer_;
  ros::ServiceServer restart_srv_;
  std::mutex mutex_;  // guards start_ and finished_ (timer and service callbacks)
  ros::WallTime start_;
};

}  // namespace endo_guidance

PLUGINLIB_EXPORT_CLASS(endo_guidance::MotionScriptNodelet, nodelet::Nodelet)
