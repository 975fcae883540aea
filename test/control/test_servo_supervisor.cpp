// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The servo's safety as properties: seeded random sequences of targets, detections, dropouts,
// glitches, stale joints and tf, late, future and replayed stamps, clock jumps and frame gaps,
// in closed loop with a simulated arm, the watchdog ticking at 100 Hz as in the nodelet. After
// every decision:
//   P1 the command is finite and within max_velocity;
//   P2 a non-zero command comes only from data within the ages allowed (measurement stamp,
//      joint states, robot tf), with an instrument, a trocar, continuous with the previous frame;
//   P3 between commands the rate changes by at most max_acceleration times the time held (a
//      stop is always allowed), except for braking ahead of a workspace bound;
//   P4 at no instant is a non-zero command held longer than its data allow, to within one
//      watchdog tick: two control periods after the measurement arrived (maxGap), max_age after
//      its stamp, joint_timeout after the last joint states.
// The same checker run on the bare control law (no supervisor) must find violations: the
// properties can fail.
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <map>
#include <random>

#include "endo_guidance/control/servo_supervisor.h"

using namespace endo_guidance::control;

namespace {

constexpr double kTick = 0.01;  // the nodelet's watchdog timer

// What the checker drives: the supervisor, or a bare law without its gating.
struct Policy {
  std::function<ServoDecision(bool)> enable;
  std::function<void(int)> instrument;
  std::function<void(TargetRequest const&, double)> target;
  std::function<ServoDecision(ServoFrame const&, RobotSample const&, double, double)> step;
  std::function<ServoDecision(double, double, double)> watchdog;
};

Policy supervised(ServoSupervisor& s) {
  Eigen::Matrix3d K;
  K << 500, 0, 320, 0, 500, 240, 0, 0, 1;
  return {[&s](bool on) { return s.setEnabled(on); }, [&s](int id) { s.setInstrument(id); },
          [&s](TargetRequest const& t, double roll) { s.setTarget(t, roll); },
          [&s, K](ServoFrame const& f, RobotSample const& r, double t, double ros) { return s.step(f, r, t, ros, K); },
          [&s](double t, double ros, double joints) { return s.watchdog(t, ros, joints); }};
}

// The control law and the workspace limit only, trusting every input (what the supervisor adds
// is what the properties test).
struct Bare {
  TrocarServo servo;
  RcmLimits limits;
  RcmJoints last = RcmJoints::Zero();
  double roll = 0.0;
};
Policy bare(Bare& b) {
  return {[&b](bool) { return ServoDecision{}; }, [](int) {},
          [&b](TargetRequest const& t, double roll) {
            if (t.mode == TargetRequest::kTip3d) b.servo.setTarget(t.tip);
            b.roll = roll;
          },
          [&b](ServoFrame const& f, RobotSample const& r, double, double) {
            ServoDecision d;
            if (!f.tip || !f.trocar || !r.joints || !r.R_base_trocar) return d;
            auto const v = b.servo.control({*f.trocar, *f.tip, (*r.joints)(kPan), *r.R_base_trocar});
            if (!v) return d;
            RcmJoints c;
            c << *v, b.roll;
            d.command = limitRates(*r.joints, b.last, c, 0.04, b.limits);
            d.send = true;
            b.last = d.command;
            return d;
          },
          [](double, double, double) { return ServoDecision{}; }};
}

struct Outcome {
  long steps = 0, commands = 0, moving = 0;
  std::map<std::string, long> violations;
  std::map<std::string, long> stops;  // first words of the reasons
};

// One seeded sequence of `frames` frames in closed loop.
void runSequence(Policy const& policy, SupervisorParams const& P, std::uint64_t seed, int frames, Outcome& out) {
  double const max_gap = ServoSupervisor(P).maxGap();
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  auto chance = [&](double p) { return U(rng) < p; };
  auto uni = [&](double a, double b) { return a + (b - a) * U(rng); };
  RcmLimits const& L = P.limits;
  // Camera frame = robot base frame; the trocar outside the view, its axis toward the view.
  Eigen::Vector3d const T0(0.11, 0.02, 0.02);
  Eigen::Vector3d const z = (Eigen::Vector3d(0.0, 0.0, 0.13) - T0).normalized();
  RcmKinematics kin;
  kin.trocar.linear() = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), z).toRotationMatrix();
  kin.trocar.translation() = T0;
  SimulatedArm arm(RcmJoints(uni(-0.3, 0.3), uni(-0.3, 0.3), uni(0.1, 0.2), 0.0), L);
  double const nan = std::numeric_limits<double>::quiet_NaN();
  auto randomTarget = [&] {
    TargetRequest t;
    if (chance(0.7)) {
      RcmJoints const qt(uni(-1.0, 1.0), uni(-1.0, 1.0), uni(0.0, 0.3), 0.0);  // partly outside the workspace
      t.tip = kin.tip(qt).translation();
      if (chance(0.05)) t.tip.z() = -t.tip.z();
      if (chance(0.03)) t.tip.x() = nan;
    } else {
      t.mode = chance(0.97) ? TargetRequest::kTipPixel : 7;
      t.pixel = Eigen::Vector2d(uni(-200, 840), uni(-200, 680));
      if (chance(0.3)) t.line = Eigen::Vector3d(uni(-1, 1), uni(-1, 1), uni(-500, 500));
      t.depth = chance(0.3) ? 0.0 : uni(-0.05, 0.4);
    }
    double const roll = chance(0.05) ? (chance(0.5) ? nan : 1e9) : uni(-3.0, 3.0);
    policy.target(t, roll);
  };
  policy.enable(true);
  policy.instrument(0);
  randomTarget();

  double t = 0.0, ros_offset = uni(0.0, 1e6);
  double joints_until = -1.0, tf_frozen_until = -1.0, tf_frozen_stamp = 0.0, joints_arrival = 0.0;
  bool enabled = true;
  int instrument = 0;
  std::optional<Eigen::Vector3d> prev_tip;
  std::optional<double> prev_stamp;
  // The command the arm holds and where it came from.
  RcmJoints held = RcmJoints::Zero();
  double held_arrival = 0.0, held_stamp = 0.0, last_cmd_time = -1.0;
  RcmJoints q, rate;
  auto violate = [&](char const* what) { ++out.violations[what]; };
  auto advance = [&](double dt) {  // the arm moves with the held command; the watchdog ticks
    for (double done = 0.0; done < dt - 1e-12; done += kTick) {
      double const h = std::min(kTick, dt - done);
      arm.write(held);
      arm.step(h);
      t += h;
      if (t < joints_until) {
      } else {
        joints_arrival = t;  // the driver's joint states, 100 Hz
      }
      ServoDecision const d = policy.watchdog(t, t + ros_offset, joints_arrival);
      if (d.send) held = d.command, last_cmd_time = t;
      if (!held.isZero()) {
        ++out.moving;
        if (t - held_arrival > max_gap + kTick + 1e-9) violate("P4 command outlives its data (arrival)");
        if (t + ros_offset - held_stamp > P.max_age + kTick + 1e-9) violate("P4 command outlives its data (stamp)");
        if (t - joints_arrival > P.joint_timeout + kTick + 1e-9) violate("P4 command outlives its data (joints)");
      }
    }
  };
  for (int k = 0; k < frames; ++k) {
    // Frame timing: 25-60 Hz, sometimes a gap.
    advance(chance(0.02) ? uni(0.05, 0.5) : 1.0 / (chance(0.5) ? 60.0 : uni(25.0, 60.0)));
    if (chance(0.003)) ros_offset -= uni(1.0, 30.0);  // a looped bag
    if (chance(0.003)) ros_offset += uni(0.2, 5.0);   // or a clock stepped forward
    if (chance(0.01)) joints_until = t + uni(0.1, 0.6);
    if (chance(0.01)) tf_frozen_until = t + uni(0.1, 0.6), tf_frozen_stamp = t + ros_offset;
    if (chance(0.004)) {
      enabled = !enabled;
      if (enabled) prev_tip.reset(), prev_stamp.reset();  // engaging starts a new history
      ServoDecision const d = policy.enable(enabled);
      if (d.send) held = d.command, last_cmd_time = t;
    }
    if (chance(0.004)) policy.instrument(instrument = chance(0.5) ? -1 : 0);
    if (chance(0.01)) randomTarget();
    arm.read(q, rate);
    double const ros = t + ros_offset;
    // The camera side.
    ServoFrame f;
    double const latency = chance(0.03) ? uni(0.1, 1.0) : chance(0.01) ? -uni(0.11, 1.0) : uni(0.003, 0.03);
    f.stamp = ros - latency;
    if (!chance(0.05)) {
      Eigen::Isometry3d const I = kin.instrument(q);
      f.tip = kin.tip(q).translation() + Eigen::Vector3d(uni(-1, 1), uni(-1, 1), uni(-1, 1)) * 2e-4;
      f.direction = I.linear().col(2);
      if (chance(0.02)) *f.tip += Eigen::Vector3d(uni(-1, 1), uni(-1, 1), uni(-1, 1)).normalized() * uni(0.011, 0.05);
      if (chance(0.005)) f.tip->y() = nan;
    }
    if (!chance(0.03)) f.trocar = T0 + Eigen::Vector3d(uni(-1, 1), uni(-1, 1), uni(-1, 1)) * 1e-4;
    if (f.trocar && chance(0.005)) f.trocar->z() = nan;
    // The robot side.
    RobotSample r;
    r.joints = q;
    r.joints_arrival = joints_arrival;
    if (chance(0.005)) (*r.joints)(kDepth) = nan;
    if (!chance(0.02)) {
      r.R_base_trocar = kin.trocar.linear();
      r.R_base_instrument = kin.instrument(q).linear();
      r.instrument_stamp = t < tf_frozen_until ? tf_frozen_stamp : ros - uni(0.0, 0.02);
    }
    ServoDecision const d = policy.step(f, r, t, ros);
    ++out.steps;
    if (!d.reason.empty()) ++out.stops[d.reason.substr(0, d.reason.find_first_of(" :(0123456789"))];
    // What the properties allow.
    bool const tip_ok = f.tip && f.tip->allFinite();
    bool const continuous = !tip_ok || !prev_tip || (*f.tip - *prev_tip).norm() <= P.max_jump;
    bool const fresh = std::abs(ros - f.stamp) <= P.max_age && (!prev_stamp || f.stamp >= *prev_stamp) &&
                       t - r.joints_arrival <= P.joint_timeout && r.joints->allFinite() &&
                       (!r.R_base_instrument || ros - r.instrument_stamp <= P.joint_timeout);
    bool const complete = enabled && instrument >= 0 && tip_ok && f.trocar && f.trocar->allFinite() && r.R_base_trocar;
    if (enabled && instrument >= 0) {  // the history of the frames seen while engaged
      prev_tip = tip_ok ? f.tip : std::nullopt;
      if (prev_stamp && f.stamp < *prev_stamp) prev_tip.reset();
      prev_stamp = f.stamp;
    }
    if (!d.send) continue;
    ++out.commands;
    RcmJoints const& c = d.command;
    if (!c.allFinite()) {
      violate("P1 command not finite");
      continue;
    }
    for (int i = 0; i < 4; ++i)
      if (std::abs(c(i)) > L.max_velocity(i) * (1 + 1e-9)) violate("P1 beyond max_velocity");
    if (!c.isZero()) {
      if (!fresh) violate("P2 command from stale data");
      if (!complete) violate("P2 command without instrument, trocar, tf or while disabled");
      if (!continuous) violate("P2 command across a tip jump");
      // P3: the change over the time the previous command was held, unless braking at a bound.
      double const held_for = held.isZero() ? P.period : std::clamp(t - last_cmd_time, 1e-3, P.period);
      auto near = [&](double dist, double v, double a) { return dist <= v * v / (2 * a) + std::abs(v) * P.period + 1e-6; };
      double const cone_dist = L.max_cone - Eigen::Vector2d(q(kPan), q(kTilt)).norm();
      double const w = Eigen::Vector2d(held(kPan), held(kTilt)).norm();
      bool const braking[4] = {near(cone_dist, w, L.max_acceleration(kPan)), near(cone_dist, w, L.max_acceleration(kTilt)),
                               near(std::min(q(kDepth) - L.min_depth, L.max_depth - q(kDepth)), held(kDepth), L.max_acceleration(kDepth)),
                               near(std::min(q(kRoll) - L.min_roll, L.max_roll - q(kRoll)), held(kRoll), L.max_acceleration(kRoll))};
      for (int i = 0; i < 4; ++i)
        if (!braking[i] && std::abs(c(i) - held(i)) > L.max_acceleration(i) * held_for + 1e-9) violate("P3 beyond max_acceleration");
      held_arrival = t, held_stamp = f.stamp;
    }
    held = c, last_cmd_time = t;
  }
}

SupervisorParams limitsForTest() {
  SupervisorParams p;
  p.limits.max_cone = 0.6;
  p.limits.min_depth = 0.06;
  p.limits.max_depth = 0.22;
  return p;
}

}  // namespace

TEST(ServoSupervisor, SafetyPropertiesHoldOverRandomSequences) {
  SupervisorParams const P = limitsForTest();
  Outcome out;
  for (std::uint64_t seed = 0; seed < 200; ++seed) {
    ServoSupervisor s(P);
    runSequence(supervised(s), P, seed, 600, out);
  }
  std::printf("[ supervisor ] %ld frames, %ld commands sent, arm moving %ld ticks of %.0f ms\n", out.steps, out.commands,
              out.moving, kTick * 1e3);
  for (auto const& [why, n] : out.stops) std::printf("[ supervisor ]   stops \"%s...\": %ld\n", why.c_str(), n);
  for (auto const& [what, n] : out.violations) ADD_FAILURE() << what << ": " << n << " times";
  // Not vacuous: the servo really drives the arm, and every kind of fault was met.
  EXPECT_GT(out.moving, out.steps / 2);
  for (char const* why : {"instrument", "tip", "measurement", "clock", "tf", "robot", "joint", "target", "no"})
    EXPECT_GT(out.stops[why], 0) << why;
}

TEST(ServoSupervisor, TheBareLawViolatesTheProperties) {
  SupervisorParams const P = limitsForTest();
  Outcome out;
  for (std::uint64_t seed = 0; seed < 20; ++seed) {
    Bare b;
    b.limits = P.limits;
    b.servo.setTarget(Eigen::Vector3d(0.0, 0.0, 0.13));
    runSequence(bare(b), P, seed, 600, out);
  }
  for (auto const& [what, n] : out.violations) std::printf("[ supervisor ] bare law: %s: %ld\n", what.c_str(), n);
  EXPECT_GT(out.violations["P2 command from stale data"], 0);
  EXPECT_GT(out.violations["P2 command across a tip jump"], 0);
  EXPECT_GT(out.violations["P3 beyond max_acceleration"], 0);  // its fixed period at 60 Hz frames
  EXPECT_GT(out.violations["P4 command outlives its data (arrival)"], 0);
  EXPECT_GT(out.violations["P4 command outlives its data (stamp)"], 0);
  EXPECT_GT(out.violations["P4 command outlives its data (joints)"], 0);
}

// A camera that stalls after another stop must still be reported: the diagnostics show the
// last stop's reason, and a stale "instrument lost" would hide that no frames come at all.
TEST(ServoSupervisor, ReportsACameraGapOnceEvenWhenAlreadyStopped) {
  ServoSupervisor s(limitsForTest());
  s.setEnabled(true);
  s.setInstrument(0);
  ServoDecision d = s.watchdog(1.0, 1.0, 1.0);
  EXPECT_EQ(d.reason, "no camera measurement yet");
  EXPECT_TRUE(d.publish_state);
  EXPECT_FALSE(d.send);  // the arm was never driven: no command
  EXPECT_TRUE(s.watchdog(1.01, 1.01, 1.01).reason.empty()) << "reported once per gap";
  d = s.step(ServoFrame{}, RobotSample{}, 2.0, 2.0);  // a frame without the instrument
  EXPECT_EQ(d.reason.rfind("instrument lost", 0), 0u) << d.reason;
  EXPECT_TRUE(s.watchdog(2.0 + 0.5 * s.maxGap(), 2.05, 2.05).reason.empty()) << "within the gap allowed";
  d = s.watchdog(2.2, 2.2, 2.2);
  EXPECT_EQ(d.reason.rfind("no camera measurement for 0.200 s", 0), 0u) << d.reason;
  EXPECT_TRUE(d.publish_state);
  EXPECT_FALSE(d.send);
  EXPECT_TRUE(s.watchdog(2.3, 2.3, 2.3).reason.empty());
  s.step(ServoFrame{}, RobotSample{}, 3.0, 3.0);  // frames again, then a new gap: reported again
  EXPECT_FALSE(s.watchdog(3.2, 3.2, 3.2).reason.empty());
  s.setEnabled(false);
  EXPECT_TRUE(s.watchdog(5.0, 5.0, 5.0).reason.empty()) << "a disabled servo reports nothing";
}

TEST(ServoSupervisor, ResolvesPixelTargetsOnTheRayAtTheDepth) {
  Eigen::Matrix3d K;
  K << 500, 0, 320, 0, 500, 240, 0, 0, 1;
  Eigen::Vector3d const T(0.1, 0.0, 0.02), tip(0.0, 0.0, 0.12);
  TargetRequest t;
  t.mode = TargetRequest::kTipPixel;
  t.pixel = Eigen::Vector2d(330, 250);
  t.depth = 0.12;
  std::string why;
  auto const P = resolveTarget(t, K, T, tip, &why);
  ASSERT_TRUE(P) << why;
  EXPECT_NEAR((*P - T).norm(), 0.12, 1e-12);
  Eigen::Vector3d const px = K * *P;
  EXPECT_NEAR(px.x() / px.z(), 330, 1e-9);
  EXPECT_NEAR(px.y() / px.z(), 250, 1e-9);
  t.line = Eigen::Vector3d(0, 1, -240);  // y = 240: the pixel moves onto it
  auto const Q = resolveTarget(t, K, T, tip, &why);
  ASSERT_TRUE(Q);
  EXPECT_NEAR((K * *Q).y() / (K * *Q).z(), 240, 1e-9);
  t.depth = 0.01;  // no point of the ray that close to the trocar
  EXPECT_FALSE(resolveTarget(t, K, T, tip, &why));
  EXPECT_NE(why.find("unreachable"), std::string::npos);
  EXPECT_FALSE(resolveTarget(t, std::nullopt, T, tip, &why));
}
