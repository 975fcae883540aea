// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/control/servo_supervisor.h"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "endo_guidance/geometry/apparent_contour.h"

namespace endo_guidance::control {

namespace {
std::string fmt(char const* f, double v) {
  char b[96];
  std::snprintf(b, sizeof b, f, v);
  return b;
}
}  // namespace

std::optional<Eigen::Vector3d> resolveTarget(TargetRequest const& t, std::optional<Eigen::Matrix3d> const& K,
                                             Eigen::Vector3d const& T, Eigen::Vector3d const& tip, std::string* why) {
  auto fail = [&](char const* w) {
    if (why) *why = w;
    return std::nullopt;
  };
  if (t.mode == TargetRequest::kTip3d) {
    if (!t.tip.allFinite() || !(t.tip.z() > 0.0)) return fail("target tip behind the camera or not finite");
    return t.tip;
  }
  if (t.mode != TargetRequest::kTipPixel) return fail("unknown target mode");
  if (!K || !K->allFinite() || !(std::abs(K->determinant()) > 0.0)) return fail("pixel target without a valid camera_info");
  if (!t.pixel.allFinite() || !t.line.allFinite() || !std::isfinite(t.depth)) return fail("target not finite");
  Eigen::Vector2d px = t.pixel;
  if (t.line.head<2>().norm() > 0.0) px = geometry::footOnLine(t.line / t.line.head<2>().norm(), px);  // onto the desired axis line
  Eigen::Vector3d const ray = (K->inverse() * px.homogeneous()).normalized();
  double const depth = t.depth > 0.0 ? t.depth : (tip - T).norm();
  // |s ray - T| = depth: s^2 - 2 s (ray.T) + |T|^2 - depth^2 = 0; the root nearest the current tip.
  double const b = ray.dot(T), c = T.squaredNorm() - depth * depth, disc = b * b - c;
  if (!(disc >= 0.0)) return fail("no tip on that pixel's ray is at that depth from the trocar (unreachable)");
  std::optional<Eigen::Vector3d> best;
  for (double s : {b - std::sqrt(disc), b + std::sqrt(disc)})
    if (s > 0.0 && (!best || (s * ray - tip).norm() < (*best - tip).norm())) best = s * ray;
  if (!best) return fail("the target is behind the camera");
  return best;
}

ServoSupervisor::ServoSupervisor(SupervisorParams const& p, ServoParams const& servo, CameraBaseRotation const& rotation)
    : params_(p), servo_(servo), rotation_(rotation) {}

ServoDecision ServoSupervisor::setEnabled(bool on) {
  if (on && !enabled_) last_tip_.reset(), last_stamp_.reset(), gap_reported_ = false;
  enabled_ = on;
  ServoDecision d;
  if (!on) {
    d.send = true;  // always, even when idle: disabling is the operator's stop
    d.reason = "servo disabled";
    moving_ = false;
    last_.setZero();
  }
  return d;
}

void ServoSupervisor::setTarget(TargetRequest const& t, double roll_rate) {
  pending_ = t;
  roll_rate_ = std::isfinite(roll_rate) ? roll_rate : 0.0;
}

ServoDecision ServoSupervisor::stop(std::string reason) {
  // A zero command when the arm was being driven; an idle servo stays silent (the arm may be
  // driven by someone else, and the driver's watchdog holds it still).
  ServoDecision d;
  d.send = moving_ || !last_.isZero();
  d.reason = std::move(reason);
  d.publish_state = true;
  moving_ = false;
  last_.setZero();
  return d;
}

ServoDecision ServoSupervisor::watchdog(double steady_now, double ros_now, double joints_arrival) {
  if (!enabled_) return {};
  // A camera gap is reported once per gap even when an earlier stop holds the arm: the stale
  // reason (a jump, a lost instrument) would hide that no frames are coming.
  if (steady_now - last_arrival_ > maxGap() && !gap_reported_) {
    gap_reported_ = true;
    return stop(last_arrival_ < -1e299 ? std::string("no camera measurement yet")
                                       : fmt("no camera measurement for %.3f s", steady_now - last_arrival_));
  }
  if (!moving_) return {};
  if (ros_now - command_stamp_ > params_.max_age) return stop(fmt("command's measurement %.3f s old", ros_now - command_stamp_));
  if (!(steady_now - joints_arrival <= params_.joint_timeout))
    return stop(fmt("joint states stale (%.3f s without)", steady_now - joints_arrival));
  return {};
}

ServoDecision ServoSupervisor::step(ServoFrame const& f, RobotSample const& r, double steady_now, double ros_now,
                                    std::optional<Eigen::Matrix3d> const& K) {
  last_arrival_ = steady_now;
  gap_reported_ = false;
  if (!enabled_) return {};
  if (instrument_ < 0) return stop("no instrument chosen (target.insertion_point_id)");
  // Time: the measurement's own stamp, by the ROS clock (a late or replayed frame is refused).
  if (!std::isfinite(f.stamp)) return stop("measurement stamp not finite");
  if (last_stamp_ && f.stamp < *last_stamp_) {
    last_stamp_ = f.stamp, last_tip_.reset();
    return stop("clock jumped back (stamp earlier than the previous one): history dropped");
  }
  last_stamp_ = f.stamp;
  // The instrument through our trocar in this frame, continuous with the previous frame's.
  if (!f.tip) return last_tip_.reset(), stop("instrument lost (no shaft through trocar " + std::to_string(instrument_) + ")");
  Eigen::Vector3d const tip = *f.tip;
  if (!tip.allFinite() || !f.direction.allFinite()) return last_tip_.reset(), stop("instrument not finite");
  std::optional<Eigen::Vector3d> const previous = last_tip_;
  last_tip_ = tip;
  if (previous && (tip - *previous).norm() > params_.max_jump)
    return stop(fmt("tip jumped %.1f mm between frames", (tip - *previous).norm() * 1e3));
  double const age = ros_now - f.stamp;
  if (age > params_.max_age) return stop(fmt("measurement %.3f s old", age));
  if (age < -params_.max_age) return stop(fmt("measurement stamped %.3f s in the future (clocks not in sync)", -age));
  if (!f.trocar || !f.trocar->allFinite()) return stop("tf missing: " + f.trocar_error);
  if (!r.R_base_trocar || !r.R_base_instrument || !r.R_base_trocar->allFinite() || !r.R_base_instrument->allFinite())
    return stop("tf missing: " + r.tf_error);
  if (r.instrument_stamp > 0.0 && ros_now - r.instrument_stamp > params_.joint_timeout)
    return stop(fmt("robot tf %.3f s old", ros_now - r.instrument_stamp));
  if (!r.joints || !r.joints->allFinite() || steady_now - r.joints_arrival > params_.joint_timeout)
    return stop("joint states missing or stale");
  RcmJoints const& q = *r.joints;
  // Eye-to-hand rotation: paired instrument directions (camera vs robot).
  if (estimate_rotation_) rotation_.add(f.direction, r.R_base_instrument->col(2));
  if (pending_) {
    std::string why;
    auto const P = resolveTarget(*pending_, K, *f.trocar, tip, &why);
    pending_.reset();
    if (!P) return stop("target refused: " + why);
    servo_.setTarget(*P);
  }
  ServoMeasurement const m{*f.trocar, tip, q(kPan), rotation_.rotation() * *r.R_base_trocar};
  std::string why;
  auto const rates = servo_.control(m, &why);
  if (!rates) return stop(why);
  // Never out of the workspace, nor beyond the rate and acceleration limits.
  RcmJoints cmd;
  cmd << *rates, roll_rate_;
  // The acceleration limit over the time the previous command was actually held (frames may come
  // faster than the period).
  double const dt = moving_ ? std::clamp(steady_now - command_arrival_, 1e-3, params_.period) : params_.period;
  ServoDecision d;
  d.command = limitRates(q, last_, cmd, dt, params_.limits);
  if (!d.command.allFinite()) return stop("command not finite");
  d.send = d.publish_state = true;
  d.tip_error = (tip - *servo_.target()).norm();
  d.axis_error = std::acos(std::clamp(f.direction.normalized().dot((*servo_.target() - *f.trocar).normalized()), -1.0, 1.0));
  moving_ = true;
  last_ = d.command;
  command_arrival_ = steady_now, command_stamp_ = f.stamp;
  return d;
}

}  // namespace endo_guidance::control
