// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/control/visual_servo.h"

#include <visp3/vs/vpAdaptiveGain.h>
#include <visp3/robot/vpRobot.h>
#include <visp3/visual_features/vpFeatureDepth.h>
#include <visp3/visual_features/vpFeaturePoint.h>
#include <visp3/vs/vpServo.h>

#include <Eigen/Eigenvalues>
#include <Eigen/SVD>
#include <cmath>

namespace endo_guidance::control {

namespace {
// eJe = [J_P; 0]: the tip velocity under the trocar constraint (header).
bool tipJacobian(ServoMeasurement const& m, Eigen::Matrix3d* J) {
  Eigen::Vector3d const r = m.tip - m.trocar;
  double const rho = r.norm();
  if (!(rho > 1e-4) || !r.allFinite()) return false;
  Eigen::Vector3d const w_pan = m.R_camera_trocar * Eigen::Vector3d::UnitY();
  Eigen::Vector3d const w_tilt = m.R_camera_trocar * (Eigen::AngleAxisd(m.pan, Eigen::Vector3d::UnitY()) * Eigen::Vector3d::UnitX());
  J->col(0) = w_pan.cross(r);
  J->col(1) = w_tilt.cross(r);
  J->col(2) = r / rho;
  return true;
}
// ViSP's interaction of (x, y, log Z/Z*) w.r.t. the camera twist; linear part only (the
// angular part multiplies the zero rows of eJe).
Eigen::Matrix3d interactionLinear(Eigen::Vector3d const& P, double Z_star) {
  vpFeaturePoint p;
  p.buildFrom(P.x() / P.z(), P.y() / P.z(), P.z());
  vpFeatureDepth z;
  z.buildFrom(P.x() / P.z(), P.y() / P.z(), P.z(), std::log(P.z() / Z_star));
  vpMatrix const Lp = p.interaction(), Lz = z.interaction();
  Eigen::Matrix3d L;
  for (int j = 0; j < 3; ++j) {
    L(0, j) = Lp[0][j];
    L(1, j) = Lp[1][j];
    L(2, j) = Lz[0][j];
  }
  return L;
}
}  // namespace

Eigen::Vector3d tipFeatures(Eigen::Vector3d const& P, double Z_star) {
  return Eigen::Vector3d(P.x() / P.z(), P.y() / P.z(), std::log(P.z() / Z_star));
}

Eigen::Matrix3d tipFeatureJacobian(ServoMeasurement const& m, double Z_star) {
  Eigen::Matrix3d J;
  if (!tipJacobian(m, &J) || !(m.tip.z() > 0.0)) return Eigen::Matrix3d::Constant(NAN);
  return -interactionLinear(m.tip, Z_star) * J;  // moving point = camera moving with -P_dot
}

TrocarServo::TrocarServo(ServoParams const& params) : params_(params) {}
TrocarServo::~TrocarServo() = default;

void TrocarServo::setTarget(Eigen::Vector3d const& tip_star) { target_ = tip_star; }

std::optional<Eigen::Vector3d> TrocarServo::control(ServoMeasurement const& m, std::string* why) {
  auto fail = [why](char const* reason) -> std::optional<Eigen::Vector3d> {
    if (why) *why = reason;
    return std::nullopt;
  };
  if (!target_) return fail("no target");
  if (!m.tip.allFinite() || !m.trocar.allFinite() || !m.R_camera_trocar.allFinite() || !std::isfinite(m.pan))
    return fail("non-finite measurement");
  if (!(m.tip.z() > params_.min_depth) || !(target_->z() > params_.min_depth)) return fail("tip or target behind the camera");
  Eigen::Matrix3d J;
  if (!tipJacobian(m, &J)) return fail("tip at the trocar");
  double const Zs = target_->z();
  // ViSP task: features, desired features, eye-to-hand law on the joints.
  vpFeaturePoint p, pd;
  p.buildFrom(m.tip.x() / m.tip.z(), m.tip.y() / m.tip.z(), m.tip.z());
  pd.buildFrom(target_->x() / Zs, target_->y() / Zs, Zs);
  vpFeatureDepth z, zd;
  z.buildFrom(p.get_x(), p.get_y(), m.tip.z(), std::log(m.tip.z() / Zs));
  zd.buildFrom(pd.get_x(), pd.get_y(), Zs, 0.0);
  vpServo task;
  task.setServo(vpServo::EYETOHAND_L_cVe_eJe);
  task.setInteractionMatrixType(vpServo::CURRENT, vpServo::PSEUDO_INVERSE);
  task.setLambda(vpAdaptiveGain(params_.gain_at_zero, params_.gain_at_infinity, params_.gain_slope));
  vpVelocityTwistMatrix cVe;  // identity
  task.set_cVe(cVe);
  vpMatrix eJe(6, 3, 0.0);
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) eJe[i][j] = J(i, j);
  task.set_eJe(eJe);
  task.addFeature(p, pd);
  task.addFeature(z, zd);
  vpColVector qdot;
  try {
    qdot = task.computeControlLaw();
  } catch (vpException const&) {
    return fail("singular task Jacobian");
  }
  vpColVector const e = task.getError();
  error_ = Eigen::Vector3d(e[0], e[1], e[2]);
  vpColVector vmax(3);
  for (int i = 0; i < 3; ++i) vmax[i] = params_.max_rate(i);
  vpColVector const sat = vpRobot::saturateVelocities(qdot, vmax, false);
  Eigen::Vector3d const out(sat[0], sat[1], sat[2]);
  if (!out.allFinite()) return fail("non-finite control");
  return out;
}

void CameraBaseRotation::add(Eigen::Vector3d const& d_camera, Eigen::Vector3d const& d_base) {
  if (!d_camera.allFinite() || !d_base.allFinite() || d_camera.norm() < 1e-9 || d_base.norm() < 1e-9) return;
  pairs_.emplace_back(d_camera.normalized(), d_base.normalized());
  while (pairs_.size() > window_) pairs_.pop_front();
  if (pairs_.size() < 50) return;
  Eigen::Matrix3d B = Eigen::Matrix3d::Zero();
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (auto const& [c, b] : pairs_) {
    B += c * b.transpose();
    mean += b;
  }
  // Conditioning: angular spread of the robot-side directions (a single direction leaves the
  // rotation about it free).
  mean /= static_cast<double>(pairs_.size());
  Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
  for (auto const& pr : pairs_) S += (pr.second - mean) * (pr.second - mean).transpose();
  S /= static_cast<double>(pairs_.size());
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(S);
  spread_ = std::sqrt(std::max(0.0, es.eigenvalues()(1)));  // second largest of three
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(B, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d D = Eigen::Matrix3d::Identity();
  D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1.0 : 1.0;
  R_ = svd.matrixU() * D * svd.matrixV().transpose();
  estimated_ = spread_ >= min_spread_;
}

}  // namespace endo_guidance::control
