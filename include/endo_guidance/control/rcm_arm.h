// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// An AESOP-style instrument holder: the shaft pivots about the trocar (remote centre of motion),
// 4 DOF q = (pan, tilt, depth, roll). Kinematics, limits, the command watchdog and the hardware
// seam (ArmHardware) with the simulated arm that ships.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <string>

namespace endo_guidance::control {

/// Joint vector: pan (rad), tilt (rad), insertion depth (m, trocar to tip), roll (rad).
using RcmJoints = Eigen::Vector4d;
enum RcmJoint { kPan = 0, kTilt = 1, kDepth = 2, kRoll = 3 };

/// Forward/inverse kinematics about the trocar. The trocar frame T (pose in the robot base) has
/// its z axis along the shaft at pan = tilt = 0, pointing into the body. The instrument frame
///   R_I = R_T Ry(pan) Rx(tilt) Rz(roll),  origin at the trocar,
/// has its z axis along the shaft toward the tip: d = R_T (cos t sin p, -sin t, cos t cos p);
///   tip = o_T + depth d.
struct RcmKinematics {
  Eigen::Isometry3d trocar = Eigen::Isometry3d::Identity();  ///< robot base -> trocar frame
  /// robot base -> instrument frame (at the trocar, z along the shaft).
  Eigen::Isometry3d instrument(RcmJoints const& q) const;
  /// robot base -> tip frame (instrument frame moved by depth along z).
  Eigen::Isometry3d tip(RcmJoints const& q) const;
  /// Joints of an instrument frame orientation (z: shaft direction) and a tip position.
  /// Pan in (-pi, pi], tilt in [-pi/2, pi/2]; pan and roll are undefined at tilt = +-pi/2
  /// (returned as 0 and the remaining rotation).
  RcmJoints inverse(Eigen::Matrix3d const& R_base_instrument, Eigen::Vector3d const& tip_base) const;
};

/// Joint-space limits. The pan/tilt workspace is a cone: pan^2 + tilt^2 <= max_cone^2.
struct RcmLimits {
  double max_cone = 0.8;                    ///< rad, half-angle of the pan/tilt cone
  double min_depth = 0.03, max_depth = 0.25;  ///< m
  double min_roll = -M_PI, max_roll = M_PI;   ///< rad
  RcmJoints max_velocity{0.5, 0.5, 0.05, 1.5};      ///< rad/s, m/s
  RcmJoints max_acceleration{2.0, 2.0, 0.2, 6.0};   ///< rad/s^2, m/s^2
  /// The nearest position inside the limits (cone: radial projection).
  RcmJoints clamp(RcmJoints const& q) const;
  bool inside(RcmJoints const& q, double tolerance = 1e-9) const;
};

/// Velocity command -> the rate actually applied over dt: each joint saturated to its velocity
/// limit (the vector scaled as a whole, so the direction of motion is kept), then the change from
/// the current rate limited by the acceleration, then any rate that would leave the workspace
/// within dt removed (the arm stops at the limit, never crosses it).
RcmJoints limitRates(RcmJoints const& q, RcmJoints const& current_rate, RcmJoints const& command, double dt,
                     RcmLimits const& limits);

/// No command for longer than timeout -> stop (zero rate). Times in seconds, any clock.
class CommandWatchdog {
 public:
  explicit CommandWatchdog(double timeout = 0.2) : timeout_(timeout) {}
  void feed(double now) { last_ = now; }
  bool expired(double now) const { return last_ < 0.0 || now - last_ > timeout_; }
  double timeout() const { return timeout_; }

 private:
  double timeout_;
  double last_ = -1.0;
};

/// The hardware seam: what the driver needs of an arm. A real AESOP (serial) driver implements
/// this and is exported as a pluginlib class of base endo_guidance::control::ArmHardware (the
/// RcmDriver loads it by name from its `hardware` parameter); SimulatedArm ships.
class ArmHardware {
 public:
  virtual ~ArmHardware() = default;
  /// Called once before any other call: the arm's name (its parameter namespace, e.g. for a
  /// serial port), its initial joints (a simulation starts there; a real arm ignores them) and
  /// the limits it must enforce itself as a second line of defence. false + *error on failure.
  virtual bool configure(std::string const& name, RcmJoints const& initial, RcmLimits const& limits, std::string* error) = 0;
  /// Measured joints and rates; false if the arm cannot be read (the driver then stops it).
  virtual bool read(RcmJoints& q, RcmJoints& rate) = 0;
  /// Commands joint rates (already limited by the driver); false on a communication error.
  virtual bool write(RcmJoints const& rate) = 0;
  /// Advances the hardware by dt seconds (a real arm ignores it: it moves by itself).
  virtual void step(double dt) = 0;
  virtual std::string name() const = 0;
};

/// An ideal arm: the commanded rate is integrated exactly, positions clamped to the limits.
class SimulatedArm : public ArmHardware {
 public:
  SimulatedArm() = default;
  SimulatedArm(RcmJoints const& initial, RcmLimits const& limits) : q_(limits.clamp(initial)), limits_(limits) {}
  bool configure(std::string const&, RcmJoints const& initial, RcmLimits const& limits, std::string* error) override {
    if (!initial.allFinite()) {
      if (error) *error = "non-finite initial joints";
      return false;
    }
    limits_ = limits;
    q_ = limits.clamp(initial);
    rate_.setZero();
    return true;
  }
  bool read(RcmJoints& q, RcmJoints& rate) override {
    q = q_;
    rate = rate_;
    return true;
  }
  bool write(RcmJoints const& rate) override {
    rate_ = rate;
    return rate.allFinite();
  }
  void step(double dt) override { q_ = limits_.clamp(q_ + rate_ * dt); }
  std::string name() const override { return "simulated"; }

 private:
  RcmJoints q_ = RcmJoints::Zero(), rate_ = RcmJoints::Zero();
  RcmLimits limits_;
};

}  // namespace endo_guidance::control
