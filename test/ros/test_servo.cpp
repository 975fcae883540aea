// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// rostest (test/ros/servo_sim.test): the closed loop in the simulated operating room, scored
// against the simulator's truth on tf: simulator + driver + vision pipeline + VisualServo, 2 mm
// breathing, a camera-to-base rotation prior 25 deg off. Several targets from the start pose
// reached in turn; then the instruments vanish mid-motion and the command must be zero within
// one control period.
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/JointState.h>
#include <std_srvs/SetBool.h>
#include <tf2_eigen/tf2_eigen.h>
#include <tf2_ros/transform_listener.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <mutex>

#include "endo_guidance/InsertionPointArray.h"
#include "endo_guidance/InstrumentAxisArray.h"
#include "endo_guidance/InstrumentVelocity.h"
#include "endo_guidance/ServoState.h"
#include "endo_guidance/ServoTarget.h"
#include "ros_test_main.h"

using namespace endo_guidance;

namespace {
std::string const kCamera = "endoscope_optical_frame";

TEST(ServoSim, TargetsReachedSafelyAndStopsWhenTheInstrumentIsLost) {
  ros::NodeHandle nh;
  tf2_ros::Buffer buffer;
  tf2_ros::TransformListener listener(buffer);
  // Joint limits are watched over the whole run.
  std::mutex m;
  double max_cone = 0.0, min_depth = 1.0, max_depth = 0.0;
  auto js_sub = nh.subscribe<sensor_msgs::JointState>("joint_states", 100, [&](sensor_msgs::JointState::ConstPtr const& js) {
    std::lock_guard<std::mutex> l(m);
    max_cone = std::max(max_cone, std::hypot(js->position.at(0), js->position.at(1)));
    min_depth = std::min(min_depth, js->position.at(2));
    max_depth = std::max(max_depth, js->position.at(2));
  });
  std::vector<double> latencies;
  auto st_sub = nh.subscribe<ServoState>("visual_servo/state", 100, [&](ServoState::ConstPtr const& s) {
    std::lock_guard<std::mutex> l(m);
    if (s->active) latencies.push_back(s->latency);
  });
  ros::Publisher target_pub = nh.advertise<ServoTarget>("visual_servo/target", 2, true);
  Eigen::Vector3d true_trocar = Eigen::Vector3d::Constant(NAN);  // arm_0's, with breathing
  auto truth_sub = nh.subscribe<InsertionPointArray>("endoscope/truth/insertion_points", 5, [&](InsertionPointArray::ConstPtr const& t) {
    std::lock_guard<std::mutex> l(m);
    if (!t->points.empty()) true_trocar = Eigen::Vector3d(t->points[0].position.x, t->points[0].position.y, t->points[0].position.z);
  });

  // 1. The pipeline finds the trocars while the scripted surgeon moves the arms.
  double explore = 12.0;
  ros::param::get("/motion_script/duration", explore);
  InsertionPointArray::ConstPtr est, truth;
  int well = 0;
  est = endo_guidance::test::waitForTrocars(nh, 3, &well);
  ASSERT_EQ(well, 3) << "the pipeline did not find the three trocars";
  for (ros::WallTime t0 = ros::WallTime::now(); (ros::WallTime::now() - t0).toSec() < explore + 2.0;) {
    // wait until the scripted motion is over (its duration counts from its start)
    if (ros::WallTime::now().toSec() - t0.toSec() > 1.0) {
      auto const js = ros::topic::waitForMessage<sensor_msgs::JointState>("joint_states", nh, ros::Duration(1.0));
      if (js && std::abs(js->velocity.at(0)) + std::abs(js->velocity.at(1)) + std::abs(js->velocity.at(2)) < 1e-9) break;
    }
    ros::WallDuration(0.1).sleep();
  }
  truth = ros::topic::waitForMessage<InsertionPointArray>("endoscope/truth/insertion_points", nh, ros::Duration(5.0));
  est = ros::topic::waitForMessage<InsertionPointArray>("endoscope/insertion_points", nh, ros::Duration(5.0));
  ASSERT_TRUE(truth && est);
  // arm_0's trocar among the estimates: the nearest to the true one.
  Eigen::Vector3d const T0(truth->points.at(0).position.x, truth->points.at(0).position.y, truth->points.at(0).position.z);
  int id = -1;
  double bd = 0.01;
  for (auto const& p : est->points) {
    double const d = (Eigen::Vector3d(p.position.x, p.position.y, p.position.z) - T0).norm();
    if (p.located && d < bd) bd = d, id = p.id;  // the servo pivots about a located (tf) point
  }
  ASSERT_GE(id, 0) << "no estimated trocar within 10 mm of arm_0's";

  // 2. Targets: reachable tips given as joint configurations of the true arm (pan, tilt, depth);
  // the tip is the visible one, the jaws' end, jaw_length beyond the arm's tip frame.
  double jaw = 0.0;
  ASSERT_TRUE(ros::param::get("/endoscope_simulator/jaw_length", jaw));
  Eigen::Isometry3d const cT = tf2::transformToEigen(buffer.lookupTransform(kCamera, "sim/trocar_0", ros::Time(0), ros::Duration(2.0)));
  // The last one is given as a tip pixel and an insertion depth (mode TIP_PIXEL).
  std::vector<Eigen::Vector3d> const goals{{0.12, -0.10, 0.13}, {-0.15, 0.08, 0.16}, {0.05, 0.15, 0.12}, {-0.05, -0.1, 0.14}};
  auto const info = ros::topic::waitForMessage<sensor_msgs::CameraInfo>("endoscope/camera_info", nh, ros::Duration(3.0));
  ASSERT_TRUE(info);
  std::printf("[ servo ] target  settled(s)  tip err(mm)  axis err(deg)  overshoot(mm)   (errors: the worst over 4 s held after settling)\n");
  for (std::size_t g = 0; g < goals.size(); ++g) {
    Eigen::Vector3d const& q = goals[g];
    Eigen::Vector3d const dir = (Eigen::AngleAxisd(q(0), Eigen::Vector3d::UnitY()) * Eigen::AngleAxisd(q(1), Eigen::Vector3d::UnitX())) *
                                Eigen::Vector3d::UnitZ();
    Eigen::Vector3d const P_star = cT * ((q(2) + jaw) * dir);
    ServoTarget t;
    t.header.stamp = ros::Time::now();
    t.header.frame_id = kCamera;
    t.mode = ServoTarget::TIP_3D;
    t.insertion_point_id = id;
    t.tip.x = P_star.x();
    t.tip.y = P_star.y();
    t.tip.z = P_star.z();
    if (g + 1 == goals.size()) {
      t.mode = ServoTarget::TIP_PIXEL;
      t.tip_px.x = info->K[0] * P_star.x() / P_star.z() + info->K[2];
      t.tip_px.y = info->K[4] * P_star.y() / P_star.z() + info->K[5];
      t.depth = q(2) + jaw;  // trocar to the visible tip
    }
    target_pub.publish(t);
    bool const pixel_mode = t.mode == ServoTarget::TIP_PIXEL;
    // 3D targets: tip within 1 mm, axis within 0.5 deg; the pixel target: its pixel within 2 px
    // and the insertion depth within 2 mm (the depth goes through the trocar estimate and the
    // tip estimate along the shaft, each a few tenths of a mm).
    double const bound1 = pixel_mode ? 2.0 : 1.0, bound2 = pixel_mode ? 2.0 : 0.5;
    // Score on the truth (tf of the simulated arm), every 40 ms for up to 25 s, then 4 s more:
    // once within bounds over 4 s (a breathing cycle), the target is held 4 s and scored there.
    // (The first window within bounds begins just after the error last crossed them, so its worst
    // is the approach's, just under the bound, not the held error.)
    std::vector<double> tip_err, ax_err;
    double overshoot = 0.0;
    Eigen::Vector3d u0 = Eigen::Vector3d::Zero();
    std::size_t converged = 0;  // samples when first within bounds over 4 s
    for (int k = 0; k < 725; ++k) {
      ros::WallDuration(0.04).sleep();
      Eigen::Isometry3d tip, ins, tro;
      try {
        tip = tf2::transformToEigen(buffer.lookupTransform(kCamera, "sim/instrument_0_tip", ros::Time(0)));
      } catch (tf2::TransformException const&) {
        continue;
      }
      // The simulator adds the breathing displacement to what it renders: the true trocar now.
      Eigen::Vector3d b;
      {
        std::lock_guard<std::mutex> l(m);
        b = true_trocar - cT.translation();
      }
      if (!b.allFinite()) continue;
      Eigen::Vector3d const T = cT.translation() + b;
      Eigen::Vector3d const P = tip.translation() + b + jaw * (tip.translation() - cT.translation()).normalized();
      if (u0.isZero()) u0 = (P - P_star).normalized();
      if (pixel_mode) {  // what was asked: the tip's pixel (px) and its insertion depth (mm)
        Eigen::Vector2d const px(info->K[0] * P.x() / P.z() + info->K[2], info->K[4] * P.y() / P.z() + info->K[5]);
        tip_err.push_back((px - Eigen::Vector2d(t.tip_px.x, t.tip_px.y)).norm());
        // Depth from the mean trocar: the target point is fixed in the camera frame while the
        // true trocar breathes.
        ax_err.push_back(std::abs((P - cT.translation()).norm() - t.depth) * 1e3);
      } else {
        tip_err.push_back((P - P_star).norm() * 1e3);
        ax_err.push_back(std::acos(std::clamp((P - T).normalized().dot((P_star - T).normalized()), -1.0, 1.0)) * 180 / M_PI);
      }
      overshoot = std::max(overshoot, -(P - P_star).dot(u0) * 1e3);
      // Converged: both within bounds over the last 4 s; then held for 4 s more.
      if (converged == 0 && tip_err.size() >= 100 && *std::max_element(tip_err.end() - 100, tip_err.end()) < bound1 &&
          *std::max_element(ax_err.end() - 100, ax_err.end()) < bound2)
        converged = tip_err.size();
      if (converged > 0 && tip_err.size() >= converged + 100) break;
    }
    ASSERT_GE(tip_err.size(), 100u);
    EXPECT_GT(converged, 0u) << "target " << g << " not within bounds over 4 s in 25 s";
    double const fin_tip = *std::max_element(tip_err.end() - 100, tip_err.end());  // the held 4 s (else the last 4 s)
    double const fin_ax = *std::max_element(ax_err.end() - 100, ax_err.end());
    double settled = 0.0;
    for (std::size_t i = tip_err.size(); i-- > 0;)
      if (tip_err[i] >= bound1 || ax_err[i] >= bound2) {
        settled = (i + 1) * 0.04;
        break;
      }
    if (pixel_mode)
      std::printf("[ servo ] %zu (pixel + depth) settled %.2f s, tip pixel error %.2f px, depth error %.3f mm, overshoot %.2f mm\n", g,
                  settled, fin_tip, fin_ax, overshoot);
    else
      std::printf("[ servo ] %zu       %6.2f      %6.3f       %6.3f         %6.2f\n", g, settled, fin_tip, fin_ax, overshoot);
    EXPECT_LT(fin_tip, bound1) << "target " << g;
    EXPECT_LT(fin_ax, bound2) << "target " << g;
    EXPECT_LT(overshoot, 3.0) << "target " << g;  // stated bound
  }
  {
    std::lock_guard<std::mutex> l(m);
    std::printf("[ servo ] joints over the run: cone <= %.4f rad (limit 0.6), depth in [%.4f, %.4f] m (limits 0.06, 0.22)\n", max_cone,
                min_depth, max_depth);
    EXPECT_LE(max_cone, 0.6 + 1e-9);
    EXPECT_GE(min_depth, 0.06 - 1e-9);
    EXPECT_LE(max_depth, 0.22 + 1e-9);
    if (!latencies.empty()) {
      std::vector<double> l2 = latencies;
      std::sort(l2.begin(), l2.end());
      std::printf("[ servo ] control latency (image stamp -> command): p50 %.1f ms, p95 %.1f ms over %zu steps\n", l2[l2.size() / 2] * 1e3,
                  l2[l2.size() * 95 / 100] * 1e3, l2.size());
    }
  }

  // 3. Features lost mid-motion: a far target, then the instruments vanish (smoke).
  ServoTarget t;
  t.header.frame_id = kCamera;
  t.mode = ServoTarget::TIP_3D;
  t.insertion_point_id = id;
  Eigen::Vector3d const far = cT * ((0.16 + jaw) * Eigen::Vector3d(0.3, 0.3, 1.0).normalized());
  t.tip.x = far.x();
  t.tip.y = far.y();
  t.tip.z = far.z();
  target_pub.publish(t);
  std::atomic<double> first_hidden_image{0.0}, first_zero{0.0};
  std::atomic<bool> hidden{false};
  std::atomic<double> hidden_from{1e300};  // sim time after which frames are rendered hidden
  std::atomic<int> nonzero_after{0};
  std::atomic<bool> occluding{false}, last_zero{false};
  std::atomic<int> nonzero_run{0};  // non-zero commands in a row
  // A frame stamped after the occlusion call returned was rendered without the instruments (the
  // simulator reads the flag once per frame, before its stamp). One stamped while the call was
  // under way may be too: a zero command is counted from the call on, so it may come before the
  // first frame known to be hidden (a negative delay).
  auto img_sub = nh.subscribe<sensor_msgs::Image>("endoscope/image_raw", 5, [&](sensor_msgs::Image::ConstPtr const& im) {
    if (hidden && im->header.stamp.toSec() > hidden_from && first_hidden_image == 0.0) first_hidden_image = ros::WallTime::now().toSec();
  });
  // No shaft may be reported on a frame without instruments (tissue only).
  std::atomic<int> phantom_axes{0};
  auto axes_sub = nh.subscribe<InstrumentAxisArray>("endoscope/instruments", 5, [&](InstrumentAxisArray::ConstPtr const& a) {
    if (hidden && a->header.stamp.toSec() > hidden_from) phantom_axes += static_cast<int>(a->axes.size());
  });
  double last_nonzero_rate = 0.0;
  auto cmd_sub = nh.subscribe<InstrumentVelocity>("arm_0/command", 50, [&](InstrumentVelocity::ConstPtr const& c) {
    bool const zero = c->pan_rate == 0.0 && c->tilt_rate == 0.0 && c->insertion_rate == 0.0;
    if (!zero) last_nonzero_rate = std::abs(c->pan_rate) + std::abs(c->tilt_rate);
    last_zero = zero;
    nonzero_run = zero ? 0 : nonzero_run + 1;
    if (occluding && zero && first_zero == 0.0) first_zero = ros::WallTime::now().toSec();
    if (first_zero > 0.0 && !zero) ++nonzero_after;
  });
  // Hidden once the servo has driven the arm for 5 frames, well before the arm reaches the
  // other instruments on its way (0.6-0.7 s after the target: there its tip is occluded by
  // arm_1 and jumps, and the servo stops for that, before the instruments vanish).
  for (int i = 0; i < 200 && nonzero_run < 5; ++i) ros::WallDuration(0.01).sleep();
  EXPECT_GE(nonzero_run.load(), 5) << "the servo did not drive the arm to the far target";
  EXPECT_GT(last_nonzero_rate, 0.0) << "the servo was not moving before the loss";
  EXPECT_FALSE(last_zero) << "the servo had stopped before the instruments vanished";
  std_srvs::SetBool occ;
  occ.request.data = true;
  occluding = true;
  ASSERT_TRUE(test::callService("endoscope_simulator/occlude", occ));  // (idempotent)
  hidden_from = ros::Time::now().toSec();
  hidden = true;
  ros::WallDuration(1.0).sleep();
  ASSERT_GT(first_hidden_image, 0.0);
  ASSERT_GT(first_zero, 0.0) << "no zero command after the instruments vanished";
  double const delay = first_zero - first_hidden_image;
  std::printf("[ servo ] instruments lost: zero command %.1f ms after the first image without them (period 40 ms); %d non-zero after\n",
              delay * 1e3, nonzero_after.load());
  EXPECT_LT(delay, 0.04);
  EXPECT_EQ(nonzero_after.load(), 0);
  EXPECT_EQ(phantom_axes.load(), 0) << "shafts reported on frames without instruments";
  occ.request.data = false;
  test::callService("endoscope_simulator/occlude", occ);
}
}  // namespace

int main(int argc, char** argv) { return endo_guidance::test::runRosTests(argc, argv, "test_servo", 3); }
