// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The servo's safety gate: every decision between a measurement and a robot command, ROS-free so
// that it can be tested as properties (test_servo_supervisor). It wraps TrocarServo and
// limitRates and commands zero, within the step that reveals it, when
//   the servo is disabled or has no instrument; the instrument is lost or its tip jumps;
//   the camera's trocar tf is missing; the measurement's stamp is older than max_age by the ROS
//   clock, or earlier than the previous one (a clock jump back: the history is dropped);
//   the joint states arrived longer than joint_timeout ago, or the robot's instrument tf is
//   stamped older than that; the geometry degenerates or the target is unreachable;
// and, from watchdog(), when no measurement arrived for maxGap() (steady clock), the one the
// command came from is older than max_age (ROS clock), or the joint states stopped arriving for
// joint_timeout: no command outlives its data.
// Every command it returns is finite, within max_velocity, acceleration-limited from the previous
// non-zero command over the time it was held, and never leaves the workspace (limitRates).
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <optional>
#include <string>

#include "endo_guidance/control/rcm_arm.h"
#include "endo_guidance/control/visual_servo.h"

namespace endo_guidance::control {

struct SupervisorParams {
  double max_age = 0.1;         ///< s: oldest measurement (stamp age); the gap bound is maxGap()
  double max_jump = 0.01;       ///< m: largest tip displacement between consecutive frames
  double joint_timeout = 0.2;   ///< s: oldest joint states (arrival) and robot instrument tf (stamp)
  double period = 0.04;         ///< s: the control period the acceleration limit assumes
  RcmLimits limits;             ///< the robot's workspace and rate limits (the driver's)
};

/// A target as asked (ServoTarget): a tip in the camera frame, or a pixel (moved onto an optional
/// image line) and an insertion depth, resolved against the next measurement.
struct TargetRequest {
  enum Mode { kTip3d = 0, kTipPixel = 1 };
  int mode = kTip3d;
  Eigen::Vector3d tip = Eigen::Vector3d::Zero();   ///< kTip3d, m
  Eigen::Vector2d pixel = Eigen::Vector2d::Zero(); ///< kTipPixel
  Eigen::Vector3d line = Eigen::Vector3d::Zero();  ///< a x + b y + c = 0; a = b = 0: none
  double depth = 0.0;                              ///< m, trocar to tip; <= 0 keeps the current
};

/// The desired tip for a request given the trocar T and the current tip (camera frame). Pixel
/// targets need the rectified K; of the two points of the pixel's ray at that depth from T, the
/// one nearest the current tip. nullopt + why when unreachable or ill-formed.
std::optional<Eigen::Vector3d> resolveTarget(TargetRequest const& t, std::optional<Eigen::Matrix3d> const& K,
                                             Eigen::Vector3d const& trocar, Eigen::Vector3d const& tip, std::string* why);

/// One camera frame as the servo sees it.
struct ServoFrame {
  double stamp = 0.0;                        ///< s, ROS clock: the image's header stamp
  std::optional<Eigen::Vector3d> tip;        ///< the instrument's tip (nullopt: not in this frame)
  Eigen::Vector3d direction = Eigen::Vector3d::UnitZ();  ///< its axis direction
  std::optional<Eigen::Vector3d> trocar;     ///< camera -> its trocar at stamp (nullopt: tf missing)
  std::string trocar_error;                  ///< why the trocar is missing
};

/// The robot side at the same instant.
struct RobotSample {
  std::optional<RcmJoints> joints;           ///< nullopt: none, or without this arm's joints
  double joints_arrival = -1e300;            ///< s, steady clock
  std::optional<Eigen::Matrix3d> R_base_trocar, R_base_instrument;  ///< from tf (nullopt: missing)
  double instrument_stamp = 0.0;             ///< s, ROS clock; 0: static
  std::string tf_error;
};

struct ServoDecision {
  bool send = false;                         ///< publish command (a zero command is a stop)
  RcmJoints command = RcmJoints::Zero();     ///< pan, tilt (rad/s), insertion (m/s), roll (rad/s)
  std::string reason;                        ///< why stopped; empty while commanding
  bool publish_state = false;                ///< a state message is due (each frame and each stop)
  double tip_error = 0.0;                    ///< m, |P - P*| (while commanding)
  double axis_error = 0.0;                   ///< rad, measured axis vs the one through the target
};

class ServoSupervisor {
 public:
  ServoSupervisor(SupervisorParams const& params = {}, ServoParams const& servo = {},
                  CameraBaseRotation const& rotation = CameraBaseRotation());
  /// Enable or disable; disabling commands zero at once.
  ServoDecision setEnabled(bool on);
  bool enabled() const { return enabled_; }
  void setInstrument(int insertion_point_id) { instrument_ = insertion_point_id; }
  int instrument() const { return instrument_; }
  /// A new target (resolved with the next measurement) and the roll rate passed through.
  void setTarget(TargetRequest const& t, double roll_rate);
  void setEstimateRotation(bool on) { estimate_rotation_ = on; }
  /// One measurement. steady_now: s, steady clock (arrival); ros_now: s, the stamps' clock.
  ServoDecision step(ServoFrame const& f, RobotSample const& r, double steady_now, double ros_now,
                     std::optional<Eigen::Matrix3d> const& K = std::nullopt);
  /// Between measurements (call at a fixed rate): stops a moving arm when no measurement arrived
  /// for maxGap(), the one its command came from is older than max_age by the ROS clock, or the
  /// joint states last arrived (steady clock) longer than joint_timeout ago. While engaged, a
  /// camera gap is reported (publish_state) once per gap even if the arm is already stopped.
  ServoDecision watchdog(double steady_now, double ros_now, double joints_arrival);
  /// s: the longest gap between measurements a command may outlive: two control periods (one
  /// frame lost), at most max_age.
  double maxGap() const { return std::min(params_.max_age, 2.0 * params_.period); }
  /// A target was set and accepted (cleared by a refused one).
  bool hasTarget() const { return pending_.has_value() || servo_.target().has_value(); }

  TrocarServo const& servo() const { return servo_; }
  CameraBaseRotation const& rotation() const { return rotation_; }
  SupervisorParams const& params() const { return params_; }
  RcmJoints const& lastCommand() const { return last_; }
  bool moving() const { return moving_; }

 private:
  ServoDecision stop(std::string reason);

  SupervisorParams params_;
  TrocarServo servo_;
  CameraBaseRotation rotation_;
  bool enabled_ = false, moving_ = false, estimate_rotation_ = true;
  bool gap_reported_ = false;  // this camera gap's stop was reported (reset by a measurement)
  int instrument_ = -1;
  std::optional<TargetRequest> pending_;
  double roll_rate_ = 0.0;
  std::optional<Eigen::Vector3d> last_tip_;
  std::optional<double> last_stamp_;
  double last_arrival_ = -1e300, command_arrival_ = -1e300, command_stamp_ = -1e300;
  RcmJoints last_ = RcmJoints::Zero();
};

}  // namespace endo_guidance::control
