// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// Eye-to-hand visual servo of one instrument about its trocar (ViSP vpServo).
//
// Features of the tip P = (X, Y, Z) in the (stationary) camera frame: its image point
// (x, y) = (X/Z, Y/Z) (vpFeaturePoint) and its depth log(Z/Z*) (vpFeatureDepth) -- a 2.5D
// set: image-based for the two pivoting DOF, the depth of the back-projected tip for insertion.
//
// Trocar constraint: the shaft only pivots about T and slides along itself, so with
// q_dot = (pan rate, tilt rate, insertion rate) (the driver's joints, RcmKinematics)
//   P_dot = J_P q_dot,  J_P = [ w_pan x (P - T) | w_tilt x (P - T) | d ],
//   w_pan = R_cT e_y,  w_tilt = R_cT Ry(pan) e_x,  d = (P - T) / |P - T|,
// R_cT the rotation camera <- trocar frame (= R_cb R_bT: R_bT known to the robot, R_cb estimated
// online, see CameraBaseRotation). A point moving with P_dot is seen as the camera moving with
// (-P_dot, 0): with ViSP's interaction matrices L (camera twist) and
//   cVe = I, eJe = [J_P; 0]   (the tip's velocity as the "end-effector" twist),
// vpServo::EYETOHAND_L_cVe_eJe gives q_dot = +lambda (L eJe)^+ e, and s_dot = -L eJe q_dot = -lambda e.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <deque>
#include <memory>
#include <optional>
#include <string>

#include "endo_guidance/control/rcm_arm.h"

namespace endo_guidance::control {

/// What the controller knows at one instant (camera frame, metres).
struct ServoMeasurement {
  Eigen::Vector3d trocar;   ///< T, estimated insertion point
  Eigen::Vector3d tip;      ///< P, back-projected tip
  double pan = 0.0;         ///< current pan joint (rad, from the robot's joint states)
  Eigen::Matrix3d R_camera_trocar = Eigen::Matrix3d::Identity();  ///< R_cT (estimate)
};

struct ServoParams {
  double gain_at_zero = 10.0;      ///< adaptive gain (vpAdaptiveGain): lambda(0), high enough to follow breathing
  double gain_at_infinity = 0.8;   ///< lambda(inf)
  double gain_slope = 60.0;        ///< slope of lambda at 0
  RcmJoints max_rate{0.15, 0.15, 0.02, 0.5};  ///< saturation (rad/s, m/s): vpRobot::saturateVelocities
  double min_depth = 0.01;         ///< m: a tip closer to the camera plane is refused (Z > this)
};

/// Features s = (x, y, log(Z/Z*)) of a tip P (and the desired Z*).
Eigen::Vector3d tipFeatures(Eigen::Vector3d const& P, double Z_star);
/// ds/dq_dot (3x3) through ViSP's interaction matrices and the trocar constraint (see the header).
Eigen::Matrix3d tipFeatureJacobian(ServoMeasurement const& m, double Z_star);

/// The control law. Not thread-safe.
class TrocarServo {
 public:
  explicit TrocarServo(ServoParams const& params = {});
  ~TrocarServo();
  void setTarget(Eigen::Vector3d const& tip_star);   ///< desired tip, camera frame
  std::optional<Eigen::Vector3d> const& target() const { return target_; }
  /// Joint rates (pan, tilt, insertion) driving the tip toward the target, saturated (the vector
  /// scaled as a whole). nullopt (the caller stops the arm) without a target or on degenerate
  /// geometry (tip at the trocar, behind the camera, singular Jacobian), with the reason.
  std::optional<Eigen::Vector3d> control(ServoMeasurement const& m, std::string* why = nullptr);
  /// Feature error of the last control() call.
  Eigen::Vector3d const& error() const { return error_; }
  ServoParams const& params() const { return params_; }
  void setParams(ServoParams const& p) { params_ = p; }

 private:
  ServoParams params_;
  std::optional<Eigen::Vector3d> target_;
  Eigen::Vector3d error_ = Eigen::Vector3d::Zero();
};

/// The unknown camera <- robot base rotation of eye-to-hand, from paired instrument directions:
/// d_c (seen by the camera) and d_b (from the robot's joints and kinematics), Wahba's problem
///   R_cb = argmin sum |d_c - R d_b|^2 = U diag(1, 1, det(U V^T)) V^T,  B = sum d_c d_b^T = U S V^T
/// over a bounded window. Usable when the directions span enough angle (second singular value of
/// B / n above min_spread): before that, the prior is used (the image-based law tolerates a
/// rotation error of tens of degrees, see the tests).
class CameraBaseRotation {
 public:
  CameraBaseRotation(Eigen::Matrix3d const& prior = Eigen::Matrix3d::Identity(), std::size_t window = 400,
                     double min_spread = 0.05)
      : prior_(prior), window_(window), min_spread_(min_spread) {}
  void add(Eigen::Vector3d const& d_camera, Eigen::Vector3d const& d_base);
  /// The estimate when conditioned, else the prior.
  Eigen::Matrix3d const& rotation() const { return estimated_ ? R_ : prior_; }
  bool estimated() const { return estimated_; }
  double spread() const { return spread_; }
  std::size_t size() const { return pairs_.size(); }
  void reset() { pairs_.clear(), estimated_ = false; }

 private:
  Eigen::Matrix3d prior_, R_ = Eigen::Matrix3d::Identity();
  std::size_t window_;
  double min_spread_, spread_ = 0.0;
  bool estimated_ = false;
  std::deque<std::pair<Eigen::Vector3d, Eigen::Vector3d>> pairs_;
};

}  // namespace endo_guidance::control
