// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// endo_guidance/VisualServo: eye-to-hand servo of one instrument about its trocar. A thin
// adapter over core TrocarServo (ViSP) and CameraBaseRotation.
//   camera side: <camera>/instruments (axes attached to estimated trocars), tf
//     <optical frame> -> trocar_<id> (the estimated trocar), camera_info (for pixel targets);
//   robot side: joint_states, tf robot_base -> <robot trocar frame>, -> <robot instrument frame>;
//   out: <arm>/command (InstrumentVelocity in the robot trocar frame), ~state (ServoState),
//     /diagnostics (why it is stopped: at once on a change, else at 1 Hz by the steady clock).
// Safety: every decision is core ServoSupervisor's (tested as properties): zero command within the
// frame that reveals lost, jumping, stale or missing data; a timer stops it when frames stop
// coming; the driver's watchdog stays the last line.
#include <diagnostic_updater/diagnostic_updater.h>
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
#include "endo_guidance/control/servo_supervisor.h"
#include "endo_guidance/geometry/cylinder_pose.h"
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
  /// Carries out the supervisor's decision: the command, the state and why it stopped.
  void apply(control::ServoDecision const& d, std_msgs::Header const& header);
  void diagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat);

  ros::NodeHandle nh_, pnh_;
  ros::Subscriber instruments_sub_, target_sub_, joints_sub_, info_sub_;
  ros::Publisher command_pub_, state_pub_;
  ros::ServiceServer enable_srv_;
  ros::SteadyTimer timer_, diag_timer_;
  std::unique_ptr<diagnostic_updater::Updater> updater_;
  std::unique_ptr<tf2_ros::Buffer> buffer_;
  std::unique_ptr<tf2_ros::TransformListener> listener_;

  std::mutex mutex_;  // guards everything below
  control::ServoSupervisor supervisor_;
  std::string arm_, robot_base_, robot_trocar_frame_, robot_instrument_frame_, trocar_prefix_;
  bool use_axis_through_ = true;  // the shaft's axis through its trocar when given (InstrumentAxis.axis_through)
  std::optional<control::RcmJoints> joints_;
  double joints_arrival_ = -1e300;

  // The diagnostics' view, copied by apply() (under mutex_): the updater never takes mutex_.
  struct Status {
    bool enabled = false, moving = false, target = false, rotation_estimated = false;
    int instrument = -1;
    std::string stopped;  // the last stop's reason; empty while commanding
    std::size_t commands = 0, stops = 0;
  };
  std::mutex status_mutex_;
  Status status_;
  std::optional<Eigen::Matrix3d> K_;  // rectified, from a valid camera_info (pixel targets)
};

void VisualServoNodelet::onInit() {
  nh_ = getNodeHandle();
  pnh_ = getPrivateNodeHandle();
  pnh_.param<std::string>("arm", arm_, "arm_0");
  int arm_index = 0, insertion_point_id = -1;
  pnh_.param("arm_index", arm_index, 0);
  pnh_.param<std::string>("robot_base_frame", robot_base_, "robot_base");
  std::string robot_prefix;
  pnh_.param<std::string>("robot_frame_prefix", robot_prefix, "");
  robot_trocar_frame_ = robot_prefix + "trocar_" + std::to_string(arm_index);
  robot_instrument_frame_ = robot_prefix + "instrument_" + std::to_string(arm_index);
  pnh_.param<std::string>("trocar_frame_prefix", trocar_prefix_, "trocar_");
  pnh_.param("insertion_point_id", insertion_point_id, -1);
  bool enabled = false, estimate_rotation = true;
  pnh_.param("enabled", enabled, false);
  pnh_.param("estimate_rotation", estimate_rotation, true);
  control::SupervisorParams p;
  pnh_.param("stale_timeout", p.max_age, p.max_age);
  pnh_.param("max_jump", p.max_jump, p.max_jump);
  pnh_.param("use_axis_through", use_axis_through_, true);
  pnh_.param("joint_timeout", p.joint_timeout, p.joint_timeout);
  pnh_.param("control_period", p.period, p.period);
  std::vector<double> rpy{0, 0, 0};
  pnh_.param("camera_base_rpy_prior", rpy, rpy);
  if (rpy.size() != 3) rpy = {0, 0, 0};
  control::CameraBaseRotation const rotation(
      (Eigen::AngleAxisd(rpy[2], Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(rpy[1], Eigen::Vector3d::UnitY()) *
       Eigen::AngleAxisd(rpy[0], Eigen::Vector3d::UnitX()))
          .toRotationMatrix()
          .transpose());  // prior of R_cb from the base -> camera pose guess
  control::ServoParams sp;
  pnh_.param("gain_at_zero", sp.gain_at_zero, sp.gain_at_zero);
  pnh_.param("gain_at_infinity", sp.gain_at_infinity, sp.gain_at_infinity);
  pnh_.param("gain_slope", sp.gain_slope, sp.gain_slope);
  std::vector<double> vmax{sp.max_rate(0), sp.max_rate(1), sp.max_rate(2)};
  pnh_.param("max_rate", vmax, vmax);
  if (vmax.size() == 3) sp.max_rate.head<3>() = Eigen::Vector3d(vmax[0], vmax[1], vmax[2]);
  // The robot's workspace (the driver's limits, same parameters).
  std::string lns;
  pnh_.param<std::string>("limits_namespace", lns, "/rcm_driver/limits");
  ros::NodeHandle ln(lns);
  control::RcmLimits& L = p.limits;
  ln.param("max_cone", L.max_cone, L.max_cone);
  ln.param("min_depth", L.min_depth, L.min_depth);
  ln.param("max_depth", L.max_depth, L.max_depth);
  ln.param("min_roll", L.min_roll, L.min_roll);
  ln.param("max_roll", L.max_roll, L.max_roll);
  std::vector<double> acc;
  if (ln.getParam("max_acceleration", acc) && acc.size() == 4) L.max_acceleration = Eigen::Vector4d(acc[0], acc[1], acc[2], acc[3]);
  std::vector<double> vel;
  if (ln.getParam("max_velocity", vel) && vel.size() == 4) L.max_velocity = Eigen::Vector4d(vel[0], vel[1], vel[2], vel[3]);
  supervisor_ = control::ServoSupervisor(p, sp, rotation);
  supervisor_.setInstrument(insertion_point_id);
  supervisor_.setEstimateRotation(estimate_rotation);
  supervisor_.setEnabled(enabled);

  // Diagnostics before the subscriptions: the first stop is already reported.
  updater_ = std::make_unique<diagnostic_updater::Updater>(nh_, pnh_, getName());
  updater_->setHardwareID(arm_);
  updater_->add("visual_servo", this, &VisualServoNodelet::diagnostics);
  status_.stopped = "no measurement yet";
  diag_timer_ = nh_.createSteadyTimer(ros::WallDuration(1.0), [this](ros::SteadyTimerEvent const&) { updater_->force_update(); });

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
  NODELET_INFO_STREAM("VisualServo: " << arm_ << " (" << robot_trocar_frame_ << "), " << (enabled ? "enabled" : "disabled"));
}

void VisualServoNodelet::jointsCb(sensor_msgs::JointState::ConstPtr const& msg) {
  control::RcmJoints q = control::RcmJoints::Zero();
  int found = 0;
  static char const* const names[4] = {"_pan", "_tilt", "_insertion", "_roll"};
  for (std::size_t i = 0; i < msg->name.size() && i < msg->position.size(); ++i)
    for (int j = 0; j < 4; ++j)
      if (msg->name[i] == arm_ + names[j]) q(j) = msg->position[i], ++found;
  std::lock_guard<std::mutex> lock(mutex_);
  if (found == 4) joints_ = q, joints_arrival_ = ros::SteadyTime::now().toSec();  // others' joints: not ours
}

void VisualServoNodelet::infoCb(sensor_msgs::CameraInfo::ConstPtr const& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (ros_io::validateCameraInfo(*msg).empty()) K_ = ros_io::rectifiedK(*msg);
}

void VisualServoNodelet::targetCb(ServoTarget::ConstPtr const& msg) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (msg->insertion_point_id >= 0) supervisor_.setInstrument(msg->insertion_point_id);
  control::TargetRequest t;
  t.mode = msg->mode;
  t.tip = Eigen::Vector3d(msg->tip.x, msg->tip.y, msg->tip.z);
  t.pixel = Eigen::Vector2d(msg->tip_px.x, msg->tip_px.y);
  t.line = Eigen::Vector3d(msg->line.a, msg->line.b, msg->line.c);
  t.depth = msg->depth;
  supervisor_.setTarget(t, msg->roll_rate);  // resolved with the next measurement (a pixel target needs the trocar)
  NODELET_INFO_STREAM("VisualServo: new target (mode " << int(msg->mode) << ") for the instrument through trocar "
                                                       << supervisor_.instrument());
}

bool VisualServoNodelet::enableSrv(std_srvs::SetBool::Request& req, std_srvs::SetBool::Response& res) {
  std::lock_guard<std::mutex> lock(mutex_);
  auto const d = supervisor_.setEnabled(req.data);
  std_msgs::Header h;
  h.stamp = ros::Time::now();
  apply(d, h);
  res.success = true;
  res.message = req.data ? "servo enabled" : "servo disabled: arm stopped";
  NODELET_INFO_STREAM(res.message);
  return true;
}

void VisualServoNodelet::apply(control::ServoDecision const& d, std_msgs::Header const& header) {
  bool changed = false;
  {
    std::lock_guard<std::mutex> lock(status_mutex_);
    Status& s = status_;
    if (d.send || d.publish_state) {
      std::string const stopped = d.send && d.reason.empty() ? std::string() : d.reason;
      changed = stopped != s.stopped;
      s.stopped = stopped;
      (d.reason.empty() ? s.commands : s.stops) += d.send;
    }
    changed |= s.enabled != supervisor_.enabled() || s.instrument != supervisor_.instrument();
    s.enabled = supervisor_.enabled(), s.moving = supervisor_.moving(), s.target = supervisor_.hasTarget();
    s.instrument = supervisor_.instrument(), s.rotation_estimated = supervisor_.rotation().estimated();
  }
  if (changed) updater_->force_update();  // a stop is seen at once, not at the next period
  if (d.send) {
    InstrumentVelocity c;
    c.header.stamp = ros::Time::now();
    c.header.frame_id = robot_trocar_frame_;
    c.pan_rate = d.command(control::kPan);
    c.tilt_rate = d.command(control::kTilt);
    c.insertion_rate = d.command(control::kDepth);
    c.roll_rate = d.command(control::kRoll);
    command_pub_.publish(c);
    if (!d.reason.empty()) ROS_WARN_STREAM_THROTTLE(1.0, "VisualServo: stopped: " << d.reason);
  }
  if (!d.publish_state) return;
  ServoState s;
  s.header = header;
  s.enabled = supervisor_.enabled();
  s.reason = d.reason;
  s.insertion_point_id = supervisor_.instrument();
  s.rotation_estimated = supervisor_.rotation().estimated();
  if (d.reason.empty()) {
    s.active = d.command.head<3>().norm() > 0.0;
    for (int i = 0; i < 3; ++i) s.feature_error[i] = supervisor_.servo().error()(i), s.command[i] = d.command(i);
    s.tip_error = d.tip_error;
    s.axis_error = d.axis_error;
    s.latency = (ros::Time::now() - header.stamp).toSec();
  }
  state_pub_.publish(s);
}

void VisualServoNodelet::watchdog(ros::SteadyTimerEvent const&) {
  std::lock_guard<std::mutex> lock(mutex_);
  std_msgs::Header h;
  h.stamp = ros::Time::now();
  apply(supervisor_.watchdog(ros::SteadyTime::now().toSec(), h.stamp.toSec(), joints_arrival_), h);
}

void VisualServoNodelet::diagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  using diagnostic_msgs::DiagnosticStatus;
  std::lock_guard<std::mutex> lock(status_mutex_);
  Status const& s = status_;
  stat.add("enabled", s.enabled);
  stat.add("instrument (insertion point id)", s.instrument);
  stat.add("target set", s.target);
  stat.add("moving", s.moving);
  stat.add("commands sent", s.commands);
  stat.add("stops", s.stops);
  stat.add("camera -> base rotation estimated", s.rotation_estimated);
  if (!s.enabled)
    stat.summary(DiagnosticStatus::OK, "disabled (~enable to engage)");
  else if (s.stopped.empty())
    stat.summary(DiagnosticStatus::OK, "commanding");
  else  // engaged but not commanding: the arm is held still, and why
    stat.summary(DiagnosticStatus::WARN, "stopped: " + s.stopped);
}

void VisualServoNodelet::instrumentsCb(InstrumentAxisArray::ConstPtr const& msg) {
  auto const t0 = std::chrono::steady_clock::now();
  std::lock_guard<std::mutex> lock(mutex_);
  double const steady_now = ros::SteadyTime::now().toSec();
  control::ServoFrame f;
  f.stamp = msg->header.stamp.toSec();
  int const id = supervisor_.instrument();
  // The instrument through our trocar in this frame.
  InstrumentAxis const* a = nullptr;
  for (auto const& x : msg->axes)
    if (id >= 0 && x.insertion_point_id == id && x.tip_valid) a = &x;
  control::RobotSample r;
  if (a && supervisor_.enabled()) {
    Eigen::Vector3d tip(a->tip.x, a->tip.y, a->tip.z);
    f.direction = Eigen::Vector3d(a->axis.direction.x, a->axis.direction.y, a->axis.direction.z);
    // The axis through the trocar (fused with it: a short shaft's direction is fixed by its
    // trocar), and the tip on it: the point of that axis nearest the tip's viewing ray.
    if (auto const through = use_axis_through_ ? ros_io::throughFromMsg(*a) : std::nullopt)
      if (auto const t = geometry::backProjectOntoAxis(through->axis, tip)) {
        tip = *t;
        f.direction = through->axis.direction();
      }
    f.tip = tip;
    // Camera -> estimated trocar at the image's stamp (InsertionPoints); the robot side, newest.
    try {
      f.trocar = tf2::transformToEigen(buffer_->lookupTransform(msg->header.frame_id, trocar_prefix_ + std::to_string(id),
                                                                msg->header.stamp, ros::Duration(0.01)))
                     .translation();
    } catch (tf2::TransformException const& e) {
      f.trocar_error = e.what();
    }
    try {
      r.R_base_trocar = tf2::transformToEigen(buffer_->lookupTransform(robot_base_, robot_trocar_frame_, ros::Time(0))).linear();
      auto const bi = buffer_->lookupTransform(robot_base_, robot_instrument_frame_, ros::Time(0));
      r.R_base_instrument = tf2::transformToEigen(bi).linear();
      r.instrument_stamp = bi.header.stamp.toSec();
    } catch (tf2::TransformException const& e) {
      r.tf_error = e.what();
    }
    r.joints = joints_;
    r.joints_arrival = joints_arrival_;
  }
  apply(supervisor_.step(f, r, steady_now, ros::Time::now().toSec(), K_), msg->header);
  double const step_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  NODELET_DEBUG_STREAM("control step " << step_ms << " ms");
}

}  // namespace endo_guidance

PLUGINLIB_EXPORT_CLASS(endo_guidance::VisualServoNodelet, nodelet::Nodelet)
