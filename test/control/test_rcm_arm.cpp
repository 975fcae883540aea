// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <random>

#include "endo_guidance/control/rcm_arm.h"

using namespace endo_guidance::control;

TEST(RcmArm, KinematicsRoundTrip) {
  std::mt19937_64 rng(5);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  RcmKinematics kin;
  kin.trocar = Eigen::Translation3d(0.1, -0.2, 0.3) * Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized());
  double worst = 0.0;
  for (int i = 0; i < 2000; ++i) {
    RcmJoints q(1.4 * U(rng), 1.4 * U(rng), 0.15 + 0.1 * U(rng), 3.0 * U(rng));
    Eigen::Isometry3d const I = kin.instrument(q), T = kin.tip(q);
    // The shaft passes through the trocar: the instrument frame's origin is the trocar.
    ASSERT_LT((I.translation() - kin.trocar.translation()).norm(), 1e-12);
    ASSERT_NEAR((T.translation() - I.translation()).norm(), q(kDepth), 1e-12);
    RcmJoints const back = kin.inverse(I.linear(), T.translation());
    worst = std::max(worst, (back - q).cwiseAbs().maxCoeff());
  }
  EXPECT_LT(worst, 1e-9);
  // Direction formula of the header.
  RcmJoints const q(0.3, -0.2, 0.1, 0.5);
  Eigen::Vector3d const d = kin.trocar.linear().transpose() * kin.instrument(q).linear().col(2);
  EXPECT_LT((d - Eigen::Vector3d(std::cos(-0.2) * std::sin(0.3), -std::sin(-0.2), std::cos(-0.2) * std::cos(0.3))).norm(), 1e-12);
}

TEST(RcmArm, RandomCommandsNeverExceedTheLimits) {
  RcmLimits L;
  std::mt19937_64 rng(11);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  SimulatedArm arm(RcmJoints(0.0, 0.0, 0.1, 0.0), L);
  double const dt = 0.01;
  RcmJoints q, rate = RcmJoints::Zero(), prev = RcmJoints::Zero();
  double worst_vel = 0.0, worst_acc = 0.0, worst_out = 0.0;
  int saturated = 0;
  for (int k = 0; k < 20000; ++k) {
    // Wild commands: up to 20x the velocity limits, sometimes held, sometimes NaN.
    RcmJoints cmd(20 * U(rng), 20 * U(rng), 2 * U(rng), 50 * U(rng));
    if (k % 997 == 0) cmd(1) = std::nan("");
    arm.read(q, rate);
    // Away from every bound (no braking or hard stop involved), the rate change must respect the
    // acceleration limits.
    bool const interior = std::hypot(q(kPan), q(kTilt)) < L.max_cone - 0.05 && q(kDepth) > L.min_depth + 0.02 &&
                          q(kDepth) < L.max_depth - 0.02 && std::abs(q(kRoll)) < M_PI - 0.5;
    RcmJoints const v = limitRates(q, rate, cmd, dt, L);
    ASSERT_TRUE(v.allFinite());
    arm.write(v);
    arm.step(dt);
    arm.read(q, rate);
    for (int i = 0; i < 4; ++i) worst_vel = std::max(worst_vel, std::abs(v(i)) / L.max_velocity(i));
    if (cmd.allFinite() && interior)
      for (int i = 0; i < 4; ++i) worst_acc = std::max(worst_acc, std::abs(v(i) - prev(i)) / dt / L.max_acceleration(i));
    prev = v;
    worst_out = std::max(worst_out, std::hypot(q(kPan), q(kTilt)) - L.max_cone);
    ASSERT_TRUE(L.inside(q, 1e-9)) << "step " << k << ": " << q.transpose();
    saturated += std::abs(std::hypot(q(kPan), q(kTilt)) - L.max_cone) < 1e-3;
  }
  std::printf("[ limits ] 20000 random commands: max |v|/v_max %.3f, max |dv/dt|/a_max %.3f (hard stops at bounds "
              "excluded), cone overshoot %.2e rad, %d steps on the cone\n",
              worst_vel, worst_acc, worst_out, saturated);
  EXPECT_LE(worst_vel, 1.0 + 1e-12);
  EXPECT_LE(worst_acc, 1.0 + 1e-9);
  EXPECT_GT(saturated, 0);  // the commands did push against the workspace limit
}

TEST(RcmArm, AccelerationLimitedWhenFarFromBounds) {
  RcmLimits L;
  RcmJoints const q(0.0, 0.0, 0.14, 0.0);
  RcmJoints const v = limitRates(q, RcmJoints::Zero(), RcmJoints(10, 0, 0, 0), 0.01, L);
  EXPECT_NEAR(v(kPan), L.max_acceleration(kPan) * 0.01, 1e-12);  // from rest: one step of acceleration
  EXPECT_EQ(v(kTilt), 0.0);
  // Toward a bound: it brakes so that it can stop before it.
  RcmJoints const near(0.0, 0.0, L.max_depth - 1e-4, 0.0);
  RcmJoints const w = limitRates(near, RcmJoints(0, 0, 0.05, 0), RcmJoints(0, 0, 0.05, 0), 0.01, L);
  EXPECT_LE(near(kDepth) + w(kDepth) * 0.01, L.max_depth + 1e-15);
  EXPECT_LE(w(kDepth), std::sqrt(2 * L.max_acceleration(kDepth) * 1e-4) + 1e-12);
}

TEST(RcmArm, WatchdogStopsWithoutCommands) {
  CommandWatchdog w(0.2);
  EXPECT_TRUE(w.expired(0.0));  // never fed: stopped
  w.feed(1.0);
  EXPECT_FALSE(w.expired(1.1));
  EXPECT_FALSE(w.expired(1.2));
  EXPECT_TRUE(w.expired(1.2001));
  w.feed(2.0);
  EXPECT_FALSE(w.expired(2.05));
}
