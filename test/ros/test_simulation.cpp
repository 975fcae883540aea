// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// rostest (test/ros/simulation.test): EndoscopeSimulator + RcmDriver without scripted motion.
// Frame rate, ground truth against tf, the watchdog, limits under saturating commands, and a
// command in the wrong frame.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/JointState.h>
#include <tf2_ros/transform_listener.h>

#include <Eigen/Geometry>
#include <atomic>
#include <cmath>
#include <mutex>

#include "endo_guidance/InsertionPointArray.h"
#include "endo_guidance/InstrumentAxisArray.h"
#include "endo_guidance/InstrumentVelocity.h"
#include "ros_test_main.h"

using namespace endo_guidance;

namespace {

struct Joints {
  std::mutex m;
  sensor_msgs::JointState last;
  double max_depth = -1e9, max_cone = 0.0, max_depth_rate = 0.0;
  void cb(sensor_msgs::JointState::ConstPtr const& js) {
    std::lock_guard<std::mutex> l(m);
    last = *js;
    for (std::size_t a = 0; a + 3 < js->position.size(); a += 4) {
      max_depth = std::max(max_depth, js->position[a + 2]);
      max_cone = std::max(max_cone, std::hypot(js->position[a], js->position[a + 1]));
      max_depth_rate = std::max(max_depth_rate, std::abs(js->velocity[a + 2]));
    }
  }
  sensor_msgs::JointState get() {
    std::lock_guard<std::mutex> l(m);
    return last;
  }
};

class Simulation : public ::testing::Test {
 protected:
  void SetUp() override {
    joints_sub_ = nh_.subscribe("joint_states", 100, &Joints::cb, &joints_);
    cmd_ = nh_.advertise<InstrumentVelocity>("arm_0/command", 10);
    for (int i = 0; i < 100 && (joints_.get().name.empty() || cmd_.getNumSubscribers() == 0); ++i) ros::WallDuration(0.05).sleep();
    ASSERT_FALSE(joints_.get().name.empty()) << "no joint_states from the driver";
  }
  /// Sends the same command at 50 Hz for `seconds` (wall time).
  void command(double pan, double tilt, double insertion, double roll, double seconds, std::string const& frame = "sim/trocar_0") {
    InstrumentVelocity c;
    c.header.frame_id = frame;
    c.pan_rate = pan;
    c.tilt_rate = tilt;
    c.insertion_rate = insertion;
    c.roll_rate = roll;
    for (ros::WallTime t0 = ros::WallTime::now(); (ros::WallTime::now() - t0).toSec() < seconds; ros::WallDuration(0.02).sleep()) {
      c.header.stamp = ros::Time::now();
      cmd_.publish(c);
    }
  }
  /// Waits (up to 3 s) until the joints stop moving: the commands of a previous test keep the arm
  /// going until its watchdog stops it.
  void waitForRest() {
    for (int i = 0; i < 12; ++i) {
      auto const a = joints_.get().position;
      ros::WallDuration(0.25).sleep();
      if (joints_.get().position == a) return;
    }
    ADD_FAILURE() << "the arm did not come to rest";
  }
  ros::NodeHandle nh_;
  Joints joints_;
  ros::Subscriber joints_sub_;
  ros::Publisher cmd_;
};

TEST_F(Simulation, FramesArriveAtTheSetRate) {
  std::atomic<int> n{0};
  ros::Time first, last;
  auto sub = nh_.subscribe<sensor_msgs::Image>("endoscope/image_raw", 10, [&](sensor_msgs::Image::ConstPtr const& m) {
    if (n == 0) first = m->header.stamp;
    last = m->header.stamp;
    ++n;
    EXPECT_EQ(m->header.frame_id, "endoscope_optical_frame");
    EXPECT_EQ(m->encoding, "bgr8");
  });
  ros::WallDuration(4.0).sleep();
  sub.shutdown();
  double const rate = (n - 1) / (last - first).toSec();
  std::printf("[ simulator ] %d frames, %.2f Hz (set: 25 Hz)\n", n.load(), rate);
  EXPECT_NEAR(rate, 25.0, 2.5);
}

TEST_F(Simulation, GroundTruthMatchesTf) {
  tf2_ros::Buffer buffer;
  tf2_ros::TransformListener listener(buffer);
  auto const points = ros::topic::waitForMessage<InsertionPointArray>("endoscope/truth/insertion_points", nh_, ros::Duration(5.0));
  auto const axes = ros::topic::waitForMessage<InstrumentAxisArray>("endoscope/truth/axes", nh_, ros::Duration(5.0));
  ASSERT_TRUE(points && axes);
  ASSERT_EQ(points->points.size(), 3u);
  EXPECT_GE(axes->axes.size(), 2u);  // the tips in view
  for (auto const& p : points->points) {
    auto const t = buffer.lookupTransform("endoscope_optical_frame", "sim/trocar_" + std::to_string(p.id), ros::Time(0), ros::Duration(3.0));
    EXPECT_NEAR(t.transform.translation.x, p.position.x, 1e-6);
    EXPECT_NEAR(t.transform.translation.y, p.position.y, 1e-6);
    EXPECT_NEAR(t.transform.translation.z, p.position.z, 1e-6);
  }
  double jaw = 0.0;
  ASSERT_TRUE(ros::param::get("/endoscope_simulator/jaw_length", jaw));
  for (auto const& a : axes->axes) {
    ASSERT_TRUE(a.tip_valid);
    auto const t = buffer.lookupTransform("endoscope_optical_frame", "sim/instrument_" + std::to_string(a.insertion_point_id) + "_tip",
                                          ros::Time(0), ros::Duration(3.0));
    Eigen::Vector3d const d(a.axis.direction.x, a.axis.direction.y, a.axis.direction.z), m(a.axis.moment.x, a.axis.moment.y, a.axis.moment.z);
    // The truth's tip is the visible one: the jaws' end, jaw_length beyond the driver's tip frame.
    EXPECT_NEAR(t.transform.translation.x + jaw * d.x(), a.tip.x, 1e-6);
    EXPECT_NEAR(t.transform.translation.y + jaw * d.y(), a.tip.y, 1e-6);
    EXPECT_NEAR(t.transform.translation.z + jaw * d.z(), a.tip.z, 1e-6);
    // The true axis passes through its trocar (moment = p x d with p the trocar).
    auto const& tp = points->points[static_cast<std::size_t>(a.insertion_point_id)].position;
    EXPECT_LT((Eigen::Vector3d(tp.x, tp.y, tp.z).cross(d) - m).norm(), 1e-9);
  }
}

TEST_F(Simulation, WatchdogStopsTheArm) {
  command(0.2, 0.0, 0.0, 0.0, 1.0);
  double const moving = joints_.get().velocity.at(0);
  EXPECT_GT(moving, 0.1) << "the arm did not follow the command";
  ros::WallDuration(0.4).sleep();  // > watchdog_timeout (0.2 s)
  auto const a = joints_.get();
  ros::WallDuration(0.5).sleep();
  auto const b = joints_.get();
  std::printf("[ watchdog ] pan rate while commanded %.3f rad/s; 0.4 s after the last command %.3g rad/s; drift over 0.5 s %.3g rad\n",
              moving, a.velocity.at(0), b.position.at(0) - a.position.at(0));
  EXPECT_EQ(a.velocity.at(0), 0.0);
  EXPECT_EQ(b.position.at(0), a.position.at(0));
}

TEST_F(Simulation, LimitsHoldUnderSaturatingCommands) {
  command(0.0, 0.0, 1.0, 0.0, 3.0);  // 20x the insertion rate limit, for long enough to hit max_depth
  command(5.0, 5.0, 0.0, 0.0, 3.0);  // far beyond the pan/tilt cone
  std::lock_guard<std::mutex> l(joints_.m);
  std::printf("[ limits ] max depth %.5f m (limit 0.22), max cone %.5f rad (limit 0.6), max insertion rate %.4f m/s (limit 0.05)\n",
              joints_.max_depth, joints_.max_cone, joints_.max_depth_rate);
  EXPECT_GT(joints_.max_depth, 0.219);  // it did reach the limit...
  EXPECT_LE(joints_.max_depth, 0.22 + 1e-12);  // ...and never crossed it
  EXPECT_GT(joints_.max_cone, 0.59);
  EXPECT_LE(joints_.max_cone, 0.6 + 1e-9);
  EXPECT_LE(joints_.max_depth_rate, 0.05 + 1e-12);
}

TEST_F(Simulation, CommandInTheWrongFrameIsIgnored) {
  waitForRest();  // (LimitsHoldUnderSaturatingCommands may run just before)
  double const before = joints_.get().position.at(4);  // arm_1? no: arm_0 only listens on arm_0/command
  auto const q0 = joints_.get().position.at(1);
  command(0.0, 0.3, 0.0, 0.0, 0.6, "camera_frame");
  ros::WallDuration(0.3).sleep();
  EXPECT_EQ(joints_.get().position.at(1), q0) << "a command in the wrong frame moved the arm";
  EXPECT_EQ(joints_.get().position.at(4), before);
}

// The whole chain in the simulated operating room (simulation_pipeline.test: scripted motion and
// the vision pipeline): the estimated trocars, on tf, converge to the simulator's truth.
TEST(SimulatedSurgery, EstimatedTrocarsMatchTheTruth) {
  ros::NodeHandle nh;
  tf2_ros::Buffer buffer;
  tf2_ros::TransformListener listener(buffer);
  InsertionPointArray::ConstPtr est;
  int well = 0;
  est = endo_guidance::test::waitForTrocars(nh, 3, &well);
  ASSERT_TRUE(est);
  ASSERT_EQ(well, 3) << "the pipeline did not find the three trocars within 60 s";
  ros::WallDuration(3.0).sleep();  // a few more seconds of views
  auto const truth = ros::topic::waitForMessage<InsertionPointArray>("endoscope/truth/insertion_points", nh, ros::Duration(5.0));
  ASSERT_TRUE(truth);
  est = ros::topic::waitForMessage<InsertionPointArray>("endoscope/insertion_points", nh, ros::Duration(5.0));
  for (auto const& p : est->points) {
    if (!p.located) continue;  // only located points are on tf
    auto const t = buffer.lookupTransform("endoscope_optical_frame", "trocar_" + std::to_string(p.id), ros::Time(0), ros::Duration(2.0));
    Eigen::Vector3d const X(t.transform.translation.x, t.transform.translation.y, t.transform.translation.z);
    double best = 1e9;
    for (auto const& q : truth->points) best = std::min(best, (X - Eigen::Vector3d(q.position.x, q.position.y, q.position.z)).norm());
    std::printf("[ simulated surgery ] trocar_%d (tf): %.2f mm from the true trocar, %u views\n", p.id, best * 1e3, p.views);
    EXPECT_LT(best, 0.003);
  }
}

}  // namespace

int main(int argc, char** argv) { return endo_guidance::test::runRosTests(argc, argv, "test_simulation", 2); }
