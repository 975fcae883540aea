// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// endo_guidance/VisualServo: eye-to-hand servo of one instrument about its trocar. A thin
// adapter over core TrocarServo (ViSP) and CameraBaseRotation.
//   camera side: <camera>/instruments (axes attached to estimated trocars), tf
//     <optical frame> -> trocar_<id> (the estimated trocar), camera_info (for pixel targets);
//   robot side: joint_states, tf robot_base -> <robot trocar frame>, -> <robot instrument frame>;
//   out: <arm>/command (InstrumentVelocity in the robot trocar frame), ~state (ServoState).
// Safety: zero command, within the frame that reveals it, when the instrument is lost, its tip
// jumps, tf or joint states are missing or stale, the geometry degenerates or the servo is
// disabled; a timer stops it when frames stop coming. Saturated; rates that would leave the
// workspace are removed (core limitRates); the driver's watchdog stays the last line.
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/JointState.h>
#include <std_srvs/SetBool.h>
#include <tf2_eigen/tf2_eigen.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <chrono>
#include <memory>
#include <mutex>

#include "endo_guidance/InstrumentAxisArray.h"
#include "endo_guidance/InstrumentVelocity.h"
#include "endo_guidance/ServoState.h"
#include "endo_guidance/ServoTarget.h"
#include "endo_guidance/core/rcm_arm.h"
#include "endo_guidance/core/visual_servo.h"
#include "endo_guidance/ros/conversions.h"

namespace endo_guidance {

class VisualServoNodelet : public nodelet::Nodelet {
 public:
  void onInit() override;

 private:
  void instrumentsCb(InstrumentAxisArray::ConstPtr const& msg);
  void targetCb(ServoTarget::ConstPtr const& msg);
  void jointsCb(sensor_msgs::JointState::ConstPtr const& msg);
  void infoCb(sensor_msgs::CameraInfo::ConstPtr const& msg);
  bool enableSrv(std_srvs::SetBool::Request& req, std_srvs::SetBool::Response& res);
  void watchdog(ros::SteadyTimerEvent const&);
  /// Sends a zero command (once per call) and publishes why.
  void stop(std::string const& reason, std_msgs::Header const& header);
  void send(Eigen::Vector3d const& rates, double roll_rate);
  std::optional<Eigen::Vector3d> targetTip(ServoTarget const& t, Eigen::Vector3d const& trocar, Eigen::Vector3d const& tip,
                                           std::string* why) const;

  ros::NodeHandle nh_, pnh_;
  ros::Subscriber instruments_sub_, target_sub_, joints_sub_, info_sub_;
  ros::Publisher command_pub_, state_pub_;
  ros::ServiceServer enable_srv_;
  ros::SteadyTimer timer_;
  std::unique_ptr<tf2_ros::Buffer> buffer_;
  std::unique_ptr<tf2_ros::TransformListener> listener_;

  std::mutex mutex_;  // guards everything below
  core::TrocarServo servo_;
  core::CameraBaseRotation rotation_;
  core::RcmLimits limits_;
  bool enabled_ = false, estimate_rotation_ = true, moving_ = false;
  int arm_index_ = 0, insertion_point_id_ = -1;
  std::string arm_, robot_base_, robot_trocar_frame_, robot_instrument_frame_, trocar_prefix_;
  double stale_timeout_ = 0.1, max_jump_ = 0.01, joint_timeout_ = 0.2, period_ = 0.04;
  bool use_axis_through_ = true;  // the shaft's axis through its trocar when given (InstrumentAxis.axis_through)
  ServoTarget::ConstPtr pending_target_;  // resolved against the next measurement
  double roll_rate_ = 0.0;
  sensor_msgs::JointState::ConstPtr joints_;
  ros::SteadyTime joints_time_, frame_time_;
  sensor_msgs::CameraInfo::ConstPtr info_;
  std::optional<Eigen::Vector3d> last_tip_;
  core::RcmJoints last_rate_ = core::RcmJoints::Zero();
};

void VisualServoNodelet::onInit() {
  nh_ = getNodeHandle();
  pnh_ = getPrivateNodeHandle();
  pnh_.param<std::string>("arm", arm_, "arm_0");
  pnh_.param("arm_index", arm_index_, 0);
  pnh_.param<std::string>("robot_base_frame", robot_base_, "robot_base");
  std::string robot_prefix;
  pnh_.param<std::string>("robot_frame_prefix", robot_prefix, "");
  robot_trocar_frame_ = robot_prefix + "trocar_" + std::to_string(arm_index_);
  robot_instrument_frame_ = robot_prefix + "instrument_" + std::to_string(arm_index_);
  pnh_.param<std::string>("trocar_frame_prefix", trocar_prefix_, "trocar_");
  pnh_.param("insertion_point_id", insertion_point_id_, -1);
  pnh_.param("enabled", enabled_, false);
  pnh_.param("estimate_rotation", estimate_rotation_, true);
  pnh_.param("stale_timeout", stale_timeout_, 0.1);
  pnh_.param("max_jump", max_jump_, 0.01);
  pnh_.param("use_axis_through", use_axis_through_, true);
  pnh_.param("joint_timeout", joint_timeout_, 0.2);
  pnh_.param("control_period", period_, 0.04);
  std::vector<double> rpy{0, 0, 0};
  pnh_.param("camera_base_rpy_prior", rpy, rpy);
  if (rpy.size() != 3) rpy = {0, 0, 0};
  rotation_ = core::CameraBaseRotation(
      (Eigen::AngleAxisd(rpy[2], Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(rpy[1], Eigen::Vector3d::UnitY()) *
       Eigen::AngleAxisd(rpy[0], Eigen::Vector3d::UnitX()))
          .toRotationMatrix()
          .transpose());  // prior of R_cb from the base -> camera pose guess
  core::ServoParams sp;
  pnh_.param("gain_at_zero", sp.gain_at_zero, sp.gain_at_zero);
  pnh_.param("gain_at_infinity", sp.gain_at_infinity, sp.gain_at_infinity);
  pnh_.param("gain_slope", sp.gain_slope, sp.gain_slope);
  std::vector<double> vmax{sp.max_rate(0), sp.max_rate(1), sp.max_rate(2)};
  pnh_.param("max_rate", vmax, vmax);
  if (vmax.size() == 3) sp.max_rate.head<3>() = Eigen::Vector3d(vmax[0], vmax[1], vmax[2]);
  servo_.setParams(sp);
  // The robot's workspace (the driver's limits, same parameters).
  std::string lns;
  pnh_.param<std::string>("limits_namespace", lns, "/rcm_driver/limits");
  ros::NodeHandle ln(lns);
  ln.param("max_cone", limits_.max_cone, limits_.max_cone);
  ln.param("min_depth", limits_.min_depth, limits_.min_depth);
  ln.param("max_depth", limits_.max_depth, limits_.max_depth);
  ln.param("min_roll", limits_.min_roll, limits_.min_roll);
  ln.param("max_roll", limits_.max_roll, limits_.max_roll);
  std::vector<double> acc;
  if (ln.getParam("max_acceleration", acc) && acc.size() == 4) limits_.max_acceleration = Eigen::Vector4d(acc[0], acc[1], acc[2], acc[3]);
  std::vector<double> vel;
  if (ln.getParam("max_velocity", vel) && vel.size() == 4) limits_.max_velocity = Eigen::Vector4d(vel[0], vel[1], vel[2], vel[3]);

  buffer_ = std::make_unique<tf2_ros::Buffer>();
  listener_ = std::make_unique<tf2_ros::TransformListener>(*buffer_, nh_);
  command_pub_ = nh_.advertise<InstrumentVelocity>(arm_ + "/command", 5);
  state_pub_ = pnh_.advertise<ServoState>("state", 20);
  enable_srv_ = pnh_.advertiseService("enable", &VisualServoNodelet::enableSrv, this);
  joints_sub_ = nh_.subscribe("joint_states", 5, &VisualServoNodelet::jointsCb, this);
  info_sub_ = nh_.subscribe("camera_info", 1, &VisualServoNodelet::infoCb, this);
  target_sub_ = pnh_.subscribe("target", 5, &VisualServoNodelet::targetCb, this);
  instruments_sub_ = nh_.subscribe("instruments", 5, &VisualServoNodelet::instrumentsCb, this);
  timer_ = nh_.createSteadyTimer(ros::WallDuration(0.01), &VisualServoNodelet::watchdog, this);
  NODELET_INFO_STREAM("VisualServo: " << arm_ << " (" << robot_trocar_frame_ << "), " << (enabled_ ? "enabled" : "disabled"));
}

void VisualServoNodelet::jointsCb(sensor_msgs::JointState::ConstPtr const& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  joints_ = msg;
  joints_time_ = ros::SteadyTime::now();
}

void VisualServoNodelet::infoCb(sensor_msgs::CameraInfo::ConstPtr const& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (ros_io::validateCameraInfo(*msg).empty()) info_ = msg;
}

void VisualServoNodelet::targetCb(ServoTarget::ConstPtr const& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (msg->insertion_point_id >= 0) insertion_point_id_ = msg->insertion_point_id;
  roll_rate_ = std::isfinite(msg->roll_rate) ? msg->roll_rate : 0.0;
  pending_target_ = msg;  // resolved with the next measurement (a pixel target needs the trocar)
  NODELET_INFO_STREAM("VisualServo: new target (mode " << int(msg->mode) << ") for the instrument through trocar "
                                                       << insertion_point_id_);
}

bool VisualServoNodelet::enableSrv(std_srvs::SetBool::Request& req, std_srvs::SetBool::Response& res) {
  std::lock_guard<std::mutex> lock(mutex_);
  enabled_ = req.data;
  res.success = true;
  res.message = enabled_ ? "servo enabled" : "servo disabled: arm stopped";
  if (!enabled_) {
    send(Eigen::Vector3d::Zero(), 0.0);
    moving_ = false;
  }
  NODELET_INFO_STREAM(res.message);
  return true;
}

void VisualServoNodelet::send(Eigen::Vector3d const& r, double roll) {
  InstrumentVelocity c;
  c.header.stamp = ros::Time::now();
  c.header.frame_id = robot_trocar_frame_;
  c.pan_rate = r(0);
  c.tilt_rate = r(1);
  c.insertion_rate = r(2);
  c.roll_rate = roll;
  command_pub_.publish(c);
  last_rate_ << r, roll;
}

void VisualServoNodelet::stop(std::string const& reason, std_msgs::Header const& header) {
  // A zero command when the arm was being driven; an idle servo stays silent (the arm may be
  // driven by someone else, and the driver's watchdog holds it still).
  if (moving_ || !last_rate_.isZero()) {
    send(Eigen::Vector3d::Zero(), 0.0);
    ROS_WARN_STREAM_THROTTLE(1.0, "VisualServo: stopped: " << reason);
  }
  moving_ = false;
  ServoState s;
  s.header = header;
  s.enabled = enabled_;
  s.reason = reason;
  s.insertion_point_id = insertion_point_id_;
  s.rotation_estimated = rotation_.estimated();
  state_pub_.publish(s);
}

void VisualServoNodelet::watchdog(ros::SteadyTimerEvent const&) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (enabled_ && moving_ && (ros::SteadyTime::now() - frame_time_).toSec() > stale_timeout_) {
    std_msgs::Header h;
    h.stamp = ros::Time::now();
    stop("no camera measurement for " + std::to_string(stale_timeout_) + " s", h);
  }
}

std::optional<Eigen::Vector3d> VisualServoNodelet::targetTip(ServoTarget const& t, Eigen::Vector3d const& T,
                                                             Eigen::Vector3d const& tip, std::string* why) const {
  if (t.mode == ServoTarget::TIP_3D) {
    Eigen::Vector3d const P(t.tip.x, t.tip.y, t.tip.z);
    if (!P.allFinite() || !(P.z() > 0.0)) return *why = "target tip behind the camera or not finite", std::nullopt;
    return P;
  }
  if (t.mode != ServoTarget::TIP_PIXEL) return *why = "unknown target mode", std::nullopt;
  if (!info_) return *why = "pixel target without a valid camera_info", std::nullopt;
  Eigen::Vector2d px(t.tip_px.x, t.tip_px.y);
  Eigen::Vector3d const l(t.line.a, t.line.b, t.line.c);
  if (l.head<2>().norm() > 0.0) px = core::footOnLine(l / l.head<2>().norm(), px);  // onto the desired axis line
  Eigen::Vector3d const ray = (ros_io::rectifiedK(*info_).inverse() * Eigen::Vector3d(px.x(), px.y(), 1.0)).normalized();
  double const depth = t.depth > 0.0 ? t.depth : (tip - T).norm();
  // |s ray - T| = depth: s^2 - 2 s (ray.T) + |T|^2 - depth^2 = 0; the root nearest the current tip.
  double const b = ray.dot(T), c = T.squaredNorm() - depth * depth, disc = b * b - c;
  if (!(disc >= 0.0)) return *why = "no tip on that pixel's ray is at that depth from the trocar (unreachable)", std::nullopt;
  double const s1 = b - std::sqrt(disc), s2 = b + std::sqrt(disc);
  std::optional<Eigen::Vector3d> best;
  for (double s : {s1, s2})
    if (s > 0.0 && (!best || (s * ray - tip).norm() < (*best - tip).norm())) best = s * ray;
  if (!best) return *why = "the target is behind the camera", std::nullopt;
  return best;
}

void VisualServoNodelet::instrumentsCb(InstrumentAxisArray::ConstPtr const& msg) {
  auto const t0 = std::chrono::steady_clock::now();
  std::lock_guard<std::mutex> lock(mutex_);
  frame_time_ = ros::SteadyTime::now();
  if (!enabled_) return;
  if (insertion_point_id_ < 0) return stop("no instrument chosen (target.insertion_point_id)", msg->header);
  // The instrument through our trocar in this frame.
  InstrumentAxis const* a = nullptr;
  for (auto const& x : msg->axes)
    if (x.insertion_point_id == insertion_point_id_ && x.tip_valid) a = &x;
  if (!a) return last_tip_.reset(), stop("instrument lost (no shaft through trocar " + std::to_string(insertion_point_id_) + ")", msg->header);
  Eigen::Vector3d tip(a->tip.x, a->tip.y, a->tip.z), d(a->axis.direction.x, a->axis.direction.y, a->axis.direction.z);
  // The axis through the trocar (fused with it: a short shaft's direction is fixed by its
  // trocar), and the tip on it: the point of that axis nearest the tip's viewing ray.
  if (auto const through = use_axis_through_ ? ros_io::throughFromMsg(*a) : std::nullopt)
    if (auto const t = core::backProjectOntoAxis(through->axis, tip)) {
      tip = *t;
      d = through->axis.direction();
    }
  if (last_tip_ && (tip - *last_tip_).norm() > max_jump_) {
    std::string const why = "tip jumped " + std::to_string((tip - *last_tip_).norm() * 1e3) + " mm between frames";
    last_tip_ = tip;
    return stop(why, msg->header);
  }
  last_tip_ = tip;
  // Camera -> estimated trocar (tf from the InsertionPoints nodelet), robot side from tf and joints.
  Eigen::Vector3d T;
  Eigen::Matrix3d R_bT, R_bI;
  try {
    T = tf2::transformToEigen(buffer_->lookupTransform(msg->header.frame_id, trocar_prefix_ + std::to_string(insertion_point_id_),
                                                       msg->header.stamp, ros::Duration(0.01)))
            .translation();
    R_bT = tf2::transformToEigen(buffer_->lookupTransform(robot_base_, robot_trocar_frame_, ros::Time(0))).linear();
    R_bI = tf2::transformToEigen(buffer_->lookupTransform(robot_base_, robot_instrument_frame_, ros::Time(0))).linear();
  } catch (tf2::TransformException const& e) {
    return stop(std::string("tf missing: ") + e.what(), msg->header);
  }
  if (!joints_ || (ros::SteadyTime::now() - joints_time_).toSec() > joint_timeout_) return stop("joint states missing or stale", msg->header);
  core::RcmJoints q = core::RcmJoints::Zero();
  int found = 0;
  static char const* const names[4] = {"_pan", "_tilt", "_insertion", "_roll"};
  for (std::size_t i = 0; i < joints_->name.size() && i < joints_->position.size(); ++i)
    for (int j = 0; j < 4; ++j)
      if (joints_->name[i] == arm_ + names[j]) q(j) = joints_->position[i], ++found;
  if (found != 4) return stop("joint states do not hold " + arm_ + "'s joints", msg->header);
  // Eye-to-hand rotation: paired instrument directions (camera vs robot).
  if (estimate_rotation_) rotation_.add(d, R_bI.col(2));
  if (pending_target_) {
    std::string why;
    auto const P = targetTip(*pending_target_, T, tip, &why);
    pending_target_.reset();
    if (!P) {
      NODELET_ERROR_STREAM("VisualServo: target refused: " << why);
      return stop("target refused: " + why, msg->header);
    }
    servo_.setTarget(*P);
  }
  core::ServoMeasurement m{T, tip, q(core::kPan), rotation_.rotation() * R_bT};
  std::string why;
  auto const rates = servo_.control(m, &why);
  if (!rates) return stop(why, msg->header);
  // Never command out of the workspace (nor beyond the rate and acceleration limits).
  core::RcmJoints cmd;
  cmd << *rates, roll_rate_;
  core::RcmJoints const safe = core::limitRates(q, last_rate_, cmd, period_, limits_);
  send(safe.head<3>(), safe(3));
  moving_ = true;
  ServoState s;
  s.header = msg->header;
  s.enabled = true;
  s.active = safe.head<3>().norm() > 0.0;
  s.insertion_point_id = insertion_point_id_;
  for (int i = 0; i < 3; ++i) s.feature_error[i] = servo_.error()(i), s.command[i] = safe(i);
  s.tip_error = (tip - *servo_.target()).norm();
  Eigen::Vector3d const ds = (*servo_.target() - T).normalized();
  s.axis_error = std::acos(std::clamp(d.dot(ds), -1.0, 1.0));
  s.rotation_estimated = rotation_.estimated();
  s.latency = (ros::Time::now() - msg->header.stamp).toSec();
  state_pub_.publish(s);
  double const step_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  NODELET_DEBUG_STREAM("control step " << step_ms << " ms");
}

}  // namespace endo_guidance

PLUGINLIB_EXPORT_CLASS(endo_guidance::VisualServoNodelet, nodelet::Nodelet)
