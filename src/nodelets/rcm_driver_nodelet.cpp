// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// endo_guidance/RcmDriver: AESOP-style instrument holders. Per arm, InstrumentVelocity commands
// (in its trocar frame) -> limited joint rates -> the hardware (ArmHardware; SimulatedArm
// ships). Watchdog: no command for watchdog_timeout -> zero rate. Publishes joint_states, tf
// base -> trocar_k -> instrument_k -> instrument_k_tip (every cycle), diagnostics. A thin adapter over
// core/rcm_arm.
#include <diagnostic_updater/diagnostic_updater.h>
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <pluginlib/class_loader.hpp>
#include <ros/ros.h>
#include <sensor_msgs/JointState.h>
#include <tf2_eigen/tf2_eigen.h>
#include <tf2_ros/transform_broadcaster.h>

#include <memory>
#include <mutex>

#include "endo_guidance/InstrumentVelocity.h"
#include "endo_guidance/control/rcm_arm.h"

namespace endo_guidance {

namespace {
Eigen::Isometry3d poseFromXyzRpy(std::vector<double> const& xyz, std::vector<double> const& rpy) {
  Eigen::Isometry3d T = Eigen::Isometry3d::Identity();
  T.translation() = Eigen::Vector3d(xyz.at(0), xyz.at(1), xyz.at(2));
  T.linear() = (Eigen::AngleAxisd(rpy.at(2), Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(rpy.at(1), Eigen::Vector3d::UnitY()) *
                Eigen::AngleAxisd(rpy.at(0), Eigen::Vector3d::UnitX()))
                   .toRotationMatrix();
  return T;
}
std::vector<double> doubles(XmlRpc::XmlRpcValue& v, std::size_t n, std::string const& what) {
  if (v.getType() != XmlRpc::XmlRpcValue::TypeArray || static_cast<std::size_t>(v.size()) != n)
    throw std::runtime_error(what + " must be a list of " + std::to_string(n) + " numbers");
  std::vector<double> out;
  for (int i = 0; i < v.size(); ++i)
    out.push_back(v[i].getType() == XmlRpc::XmlRpcValue::TypeInt ? static_cast<double>(static_cast<int>(v[i])) : static_cast<double>(v[i]));
  return out;
}
}  // namespace

class RcmDriverNodelet : public nodelet::Nodelet {
 public:
  void onInit() override;

 private:
  struct Arm {
    std::string name;
    control::RcmKinematics kinematics;
    boost::shared_ptr<control::ArmHardware> hardware;
    control::CommandWatchdog watchdog;
    control::RcmJoints command = control::RcmJoints::Zero();
    control::RcmJoints q = control::RcmJoints::Zero(), rate = control::RcmJoints::Zero();
    bool at_limit = false, watchdog_stopped = true, hardware_ok = true;
    std::string last_error;
    ros::Subscriber sub;
  };
  void commandCb(std::size_t i, InstrumentVelocity::ConstPtr const& msg);
  void step(ros::SteadyTimerEvent const& e);
  void diagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat);
  std::string frame(std::string const& what, std::size_t i) const { return prefix_ + what + "_" + std::to_string(i); }

  ros::NodeHandle nh_, pnh_;
  std::unique_ptr<pluginlib::ClassLoader<control::ArmHardware>> loader_;
  std::mutex mutex_;
  std::vector<Arm> arms_;
  control::RcmLimits limits_;
  double rate_hz_ = 100.0;
  std::string base_frame_, prefix_;
  ros::SteadyTimer timer_;
  ros::SteadyTime last_step_;
  ros::Publisher joints_pub_;
  std::unique_ptr<tf2_ros::TransformBroadcaster> tf_;
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  ros::Timer diag_timer_;
};

void RcmDriverNodelet::onInit() {
  nh_ = getNodeHandle();
  pnh_ = getPrivateNodeHandle();
  double timeout = 0.2;
  pnh_.param("rate", rate_hz_, 100.0);
  pnh_.param("watchdog_timeout", timeout, 0.2);
  pnh_.param<std::string>("base_frame", base_frame_, "robot_base");
  pnh_.param<std::string>("frame_prefix", prefix_, "");
  std::string hardware;
  pnh_.param<std::string>("hardware", hardware, "endo_guidance/SimulatedArm");
  pnh_.param("limits/max_cone", limits_.max_cone, limits_.max_cone);
  pnh_.param("limits/min_depth", limits_.min_depth, limits_.min_depth);
  pnh_.param("limits/max_depth", limits_.max_depth, limits_.max_depth);
  pnh_.param("limits/min_roll", limits_.min_roll, limits_.min_roll);
  pnh_.param("limits/max_roll", limits_.max_roll, limits_.max_roll);
  XmlRpc::XmlRpcValue v;
  try {
    if (pnh_.getParam("limits/max_velocity", v)) limits_.max_velocity = Eigen::Map<Eigen::Vector4d const>(doubles(v, 4, "limits/max_velocity").data());
    if (pnh_.getParam("limits/max_acceleration", v))
      limits_.max_acceleration = Eigen::Map<Eigen::Vector4d const>(doubles(v, 4, "limits/max_acceleration").data());
    if (!(rate_hz_ > 0.0) || !(timeout > 0.0) || !(limits_.max_velocity.array() > 0.0).all() ||
        !(limits_.max_acceleration.array() > 0.0).all() || !(limits_.min_depth < limits_.max_depth))
      throw std::runtime_error("rate, watchdog_timeout, velocity and acceleration limits must be > 0, min_depth < max_depth");
    XmlRpc::XmlRpcValue arms;
    if (!pnh_.getParam("arms", arms) || arms.getType() != XmlRpc::XmlRpcValue::TypeArray || arms.size() == 0)
      throw std::runtime_error("parameter 'arms' (a list of {name, trocar_xyz, trocar_rpy, initial}) is missing");
    for (int i = 0; i < arms.size(); ++i) {
      Arm a;
      a.name = static_cast<std::string>(arms[i]["name"]);
      a.kinematics.trocar = poseFromXyzRpy(doubles(arms[i]["trocar_xyz"], 3, a.name + ".trocar_xyz"),
                                           doubles(arms[i]["trocar_rpy"], 3, a.name + ".trocar_rpy"));
      auto const q0 = doubles(arms[i]["initial"], 4, a.name + ".initial");
      if (!loader_) loader_ = std::make_unique<pluginlib::ClassLoader<control::ArmHardware>>("endo_guidance", "endo_guidance::control::ArmHardware");
      a.hardware = loader_->createInstance(hardware);  // throws pluginlib::PluginlibException if unknown
      std::string error;
      if (!a.hardware->configure(a.name, control::RcmJoints(q0[0], q0[1], q0[2], q0[3]), limits_, &error))
        throw std::runtime_error(a.name + ": hardware '" + hardware + "' refused the configuration: " + error);
      a.watchdog = control::CommandWatchdog(timeout);
      arms_.push_back(std::move(a));
    }
  } catch (std::exception const& e) {  // incl. pluginlib::PluginlibException
    NODELET_FATAL_STREAM("RcmDriver: bad parameters or hardware, no arm is driven: " << e.what());
    return;
  }
  joints_pub_ = nh_.advertise<sensor_msgs::JointState>("joint_states", 10);
  tf_ = std::make_unique<tf2_ros::TransformBroadcaster>();
  for (std::size_t i = 0; i < arms_.size(); ++i) {
    arms_[i].sub = nh_.subscribe<InstrumentVelocity>(arms_[i].name + "/command", 5,
                                                     [this, i](InstrumentVelocity::ConstPtr const& m) { commandCb(i, m); });
  }
  updater_ = std::make_unique<diagnostic_updater::Updater>(nh_, pnh_, getName());
  updater_->setHardwareID("rcm_arms");
  updater_->add("rcm_driver", this, &RcmDriverNodelet::diagnostics);
  diag_timer_ = nh_.createTimer(ros::Duration(1.0), [this](ros::TimerEvent const&) { updater_->update(); });
  last_step_ = ros::SteadyTime::now();
  timer_ = nh_.createSteadyTimer(ros::WallDuration(1.0 / rate_hz_), &RcmDriverNodelet::step, this);
  NODELET_INFO_STREAM("RcmDriver: " << arms_.size() << " arm(s), " << rate_hz_ << " Hz, watchdog " << timeout << " s");
}

void RcmDriverNodelet::commandCb(std::size_t i, InstrumentVelocity::ConstPtr const& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  Arm& a = arms_[i];
  control::RcmJoints const c(msg->pan_rate, msg->tilt_rate, msg->insertion_rate, msg->roll_rate);
  if (!msg->header.frame_id.empty() && msg->header.frame_id != frame("trocar", i)) {
    a.last_error = "command in frame '" + msg->header.frame_id + "', expected '" + frame("trocar", i) + "': ignored";
    ROS_ERROR_STREAM_THROTTLE(2.0, a.name << ": " << a.last_error);
    return;
  }
  if (!c.allFinite()) {  // fail safe: a bad command stops the arm
    a.command.setZero();
    a.last_error = "non-finite command: arm stopped";
    ROS_ERROR_STREAM_THROTTLE(2.0, a.name << ": " << a.last_error);
    return;
  }
  a.command = c;
  a.watchdog.feed(ros::SteadyTime::now().toSec());
}

void RcmDriverNodelet::step(ros::SteadyTimerEvent const&) {
  ros::SteadyTime const now = ros::SteadyTime::now();
  double const dt = std::clamp((now - last_step_).toSec(), 1e-4, 0.1);
  last_step_ = now;
  sensor_msgs::JointState js;
  js.header.stamp = ros::Time::now();
  std::vector<geometry_msgs::TransformStamped> tfs;
  std::lock_guard<std::mutex> lock(mutex_);
  for (std::size_t i = 0; i < arms_.size(); ++i) {
    Arm& a = arms_[i];
    a.hardware_ok = a.hardware->read(a.q, a.rate);
    a.watchdog_stopped = a.watchdog.expired(now.toSec());
    control::RcmJoints const cmd = (a.watchdog_stopped || !a.hardware_ok) ? control::RcmJoints::Zero() : a.command;
    control::RcmJoints const v = control::limitRates(a.q, a.rate, cmd, dt, limits_);
    a.at_limit = (v - cmd).norm() > 1e-9 && !a.watchdog_stopped;
    if (!a.hardware->write(a.hardware_ok ? v : control::RcmJoints::Zero())) a.hardware_ok = false;
    a.hardware->step(dt);
    a.hardware_ok = a.hardware->read(a.q, a.rate) && a.hardware_ok;
    static char const* const joint[4] = {"pan", "tilt", "insertion", "roll"};
    for (int j = 0; j < 4; ++j) {
      js.name.push_back(a.name + "_" + joint[j]);
      js.position.push_back(a.q(j));
      js.velocity.push_back(a.rate(j));
    }
    // base -> trocar with every cycle (not /tf_static: several static broadcasters in one
    // nodelet manager share one latched publication, and the last one would hide the others).
    auto tb = tf2::eigenToTransform(a.kinematics.trocar);
    tb.header.stamp = js.header.stamp;
    tb.header.frame_id = base_frame_;
    tb.child_frame_id = frame("trocar", i);
    tfs.push_back(tb);
    Eigen::Isometry3d const I = a.kinematics.trocar.inverse() * a.kinematics.instrument(a.q);
    auto ti = tf2::eigenToTransform(I);
    ti.header.stamp = js.header.stamp;
    ti.header.frame_id = frame("trocar", i);
    ti.child_frame_id = frame("instrument", i);
    tfs.push_back(ti);
    geometry_msgs::TransformStamped tt;
    tt.header = ti.header;
    tt.header.frame_id = frame("instrument", i);
    tt.child_frame_id = frame("instrument", i) + "_tip";
    tt.transform.translation.z = a.q(control::kDepth);
    tt.transform.rotation.w = 1.0;
    tfs.push_back(tt);
  }
  joints_pub_.publish(js);
  tf_->sendTransform(tfs);
}

void RcmDriverNodelet::diagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  std::lock_guard<std::mutex> lock(mutex_);
  int stopped = 0, limited = 0, failed = 0;
  for (auto& a : arms_) {
    char buf[200];
    std::snprintf(buf, sizeof buf, "%s: q = (%.3f rad, %.3f rad, %.3f m, %.3f rad)%s%s%s", a.hardware->name().c_str(), a.q(0), a.q(1),
                  a.q(2), a.q(3), a.watchdog_stopped ? ", stopped by the watchdog" : "", a.at_limit ? ", limited" : "",
                  a.last_error.empty() ? "" : (", " + a.last_error).c_str());
    stat.add(a.name, buf);
    stopped += a.watchdog_stopped;
    limited += a.at_limit;
    failed += !a.hardware_ok;
    a.last_error.clear();
  }
  if (failed) stat.summaryf(diagnostic_msgs::DiagnosticStatus::ERROR, "%d arm(s) cannot be read or commanded: stopped", failed);
  else if (stopped) stat.summaryf(diagnostic_msgs::DiagnosticStatus::OK, "%d arm(s) idle (no command within the watchdog timeout)", stopped);
  else if (limited) stat.summaryf(diagnostic_msgs::DiagnosticStatus::WARN, "%d arm(s) limited (velocity, acceleration or workspace)", limited);
  else stat.summary(diagnostic_msgs::DiagnosticStatus::OK, "driving");
}

}  // namespace endo_guidance

PLUGINLIB_EXPORT_CLASS(endo_guidance::RcmDriverNodelet, nodelet::Nodelet)
PLUGINLIB_EXPORT_CLASS(endo_guidance::control::SimulatedArm, endo_guidance::control::ArmHardware)
