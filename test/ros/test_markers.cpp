// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The rviz markers (ros/markers.h) against exact geometry, and the axis-through conversions
// (ros/conversions.h); no master needed.
#include <gtest/gtest.h>

#include <cmath>

#include "endo_guidance/ros/conversions.h"
#include "endo_guidance/ros/markers.h"

using namespace endo_guidance;

namespace {

Eigen::Vector3d toEigen(geometry_msgs::Point const& p) { return Eigen::Vector3d(p.x, p.y, p.z); }

std_msgs::Header header() {
  std_msgs::Header h;
  h.frame_id = "endoscope_optical_frame";
  h.stamp = ros::Time(12.5);
  return h;
}

geometry::ConstrainedAxis throughAxis(Eigen::Vector3d const& pivot, Eigen::Vector3d const& tip) {
  geometry::ConstrainedAxis c;
  c.pose.axis = *geometry::PluckerLine::through(pivot, tip);
  c.pivot = pivot;
  return c;
}

TEST(Markers, TheAxisThroughTheTrocarRunsFromThePivotToTheTip) {
  Eigen::Vector3d const P(0.10, 0.02, 0.01), T(0.01, -0.005, 0.12);
  std::vector<visualization_msgs::Marker> out;
  ros_io::appendThroughMarker(out, header(), 3, throughAxis(P, T), T);
  ASSERT_EQ(out.size(), 1u);
  auto const& m = out[0];
  EXPECT_EQ(m.ns, "axes_through");
  EXPECT_EQ(m.id, 3);
  EXPECT_EQ(m.type, visualization_msgs::Marker::LINE_LIST);
  EXPECT_EQ(m.header.frame_id, "endoscope_optical_frame");
  EXPECT_EQ(m.header.stamp, ros::Time(12.5));
  ASSERT_EQ(m.points.size(), 2u);
  EXPECT_LT((toEigen(m.points[0]) - P).norm(), 1e-12);
  EXPECT_LT((toEigen(m.points[1]) - T).norm(), 1e-12);
  EXPECT_GT(m.scale.x, 0.0);
  EXPECT_GT(m.color.a, 0.0);
}

TEST(Markers, AnOffAxisTipIsDrawnAtItsFootAndNoTipAtTheOpticalCentresFoot) {
  Eigen::Vector3d const P(-0.08, 0.03, 0.02), T(0.0, 0.0, 0.10);
  geometry::ConstrainedAxis const c = throughAxis(P, T);
  Eigen::Vector3d const d = c.pose.axis.direction();
  Eigen::Vector3d const off = d.unitOrthogonal();  // a measured tip 2 mm beside the fused axis
  std::vector<visualization_msgs::Marker> out;
  ros_io::appendThroughMarker(out, header(), 0, c, Eigen::Vector3d(T + 0.002 * off));
  ros_io::appendThroughMarker(out, header(), 1, c, std::nullopt);
  ASSERT_EQ(out.size(), 2u);
  EXPECT_LT((toEigen(out[0].points[1]) - T).norm(), 1e-12);
  Eigen::Vector3d const foot = toEigen(out[1].points[1]);
  EXPECT_LT(std::abs(foot.dot(d)), 1e-12);              // the optical centre's foot: perpendicular to d
  EXPECT_LT(c.pose.axis.distanceTo(foot), 1e-12);        // and on the axis
}

TEST(Markers, NothingIsDrawnForANonFiniteAxis) {
  geometry::ConstrainedAxis c = throughAxis(Eigen::Vector3d(0.1, 0, 0), Eigen::Vector3d(0, 0, 0.1));
  c.pivot = Eigen::Vector3d::Constant(NAN);
  std::vector<visualization_msgs::Marker> out;
  ros_io::appendThroughMarker(out, header(), 0, c, Eigen::Vector3d(0, 0, 0.1));
  EXPECT_TRUE(out.empty());
  c = throughAxis(Eigen::Vector3d(0.1, 0, 0), Eigen::Vector3d(0, 0, 0.1));
  ros_io::appendThroughMarker(out, header(), 0, c, Eigen::Vector3d(NAN, 0, 0.1));
  EXPECT_TRUE(out.empty());
}

TEST(Conversions, TheAxisThroughRoundTripsAndIsAbsentUnlessValid) {
  geometry::ConstrainedAxis const c = throughAxis(Eigen::Vector3d(0.1, 0.02, 0.01), Eigen::Vector3d(0.01, -0.005, 0.12));
  endo_guidance::InstrumentAxis m;
  EXPECT_FALSE(ros_io::throughFromMsg(m));  // through_valid false
  ASSERT_TRUE(ros_io::setThrough(c.pose, m));
  auto const back = ros_io::throughFromMsg(m);
  ASSERT_TRUE(back);
  EXPECT_LT((back->axis.direction() - c.pose.axis.direction()).norm(), 1e-12);
  EXPECT_LT((back->axis.moment() - c.pose.axis.moment()).norm(), 1e-12);
  m.axis_through.direction.x += 0.1;  // not a unit direction: refused, not renormalised
  EXPECT_FALSE(ros_io::throughFromMsg(m));
}

}  // namespace

// Found by fuzz_config: a K whose last row is not (0, 0, 1), or a focal length of 1e-300, passed
// and its inverse was not finite.
TEST(Conversions, CameraInfoMustBeAPinholeCamera) {
  sensor_msgs::CameraInfo info;
  info.width = 640, info.height = 480;
  info.K = {600, 0, 320, 0, 600, 240, 0, 0, 1};
  EXPECT_EQ(endo_guidance::ros_io::validateCameraInfo(info), "");
  info.P = {600, 0, 320, 0, 0, 600, 240, 0, 0, 0, 1, 0};
  EXPECT_EQ(endo_guidance::ros_io::validateCameraInfo(info), "");
  auto bad = [](sensor_msgs::CameraInfo i) { return !endo_guidance::ros_io::validateCameraInfo(i).empty(); };
  sensor_msgs::CameraInfo k = info;
  k.K[8] = 0.0;
  EXPECT_TRUE(bad(k));
  k = info;
  k.K[6] = 1e-3;
  EXPECT_TRUE(bad(k));
  k = info;
  k.K[0] = 1e-300;
  EXPECT_TRUE(bad(k));
  k = info;
  k.P[10] = 0.0;
  EXPECT_TRUE(bad(k));
}

// A camera mode change (a scaled stream) keeps the trocars; another camera does not.
TEST(Conversions, AnotherModeOfTheSameCameraIsRecognised) {
  using endo_guidance::ros_io::sameCameraScale;
  sensor_msgs::CameraInfo a;
  a.header.frame_id = "endoscope_optical_frame";
  a.width = 640, a.height = 480;
  a.distortion_model = "plumb_bob";
  a.D = {0.1, -0.02, 0, 0, 0};
  a.K = {600, 0, 319.5, 0, 600, 239.5, 0, 0, 1};
  a.P = {600, 0, 319.5, 0, 0, 600, 239.5, 0, 0, 0, 1, 0};
  sensor_msgs::CameraInfo b = a;  // 800x600: x' + 1/2 = 1.25 (x + 1/2)
  b.width = 800, b.height = 600;
  b.K = {750, 0, 399.5, 0, 750, 299.5, 0, 0, 1};
  b.P = {750, 0, 399.5, 0, 0, 750, 299.5, 0, 0, 0, 1, 0};
  EXPECT_TRUE(sameCameraScale(a, b));
  EXPECT_TRUE(sameCameraScale(b, a));
  EXPECT_TRUE(sameCameraScale(a, a));
  sensor_msgs::CameraInfo c = b;
  c.K[0] = c.P[0] = 825, c.K[4] = c.P[5] = 825;  // focal lengths +10 %: another camera
  EXPECT_FALSE(sameCameraScale(a, c));
  c = b;
  c.K[2] = c.P[2] = 420;  // principal point 20 px off
  EXPECT_FALSE(sameCameraScale(a, c));
  c = b;
  c.P[0] = 900;  // K scaled, P not
  EXPECT_FALSE(sameCameraScale(a, c));
  c = b;
  c.D[0] = 0.2;  // other lens
  EXPECT_FALSE(sameCameraScale(a, c));
  c = b;
  c.header.frame_id = "other_optical_frame";
  EXPECT_FALSE(sameCameraScale(a, c));
  c = b;
  c.width = 0;
  EXPECT_FALSE(sameCameraScale(a, c));
}
