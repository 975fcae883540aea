// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include "endo_guidance/geometry/classification.h"
#include "endo_guidance/geometry/cylinder_pose.h"
#include "endo_guidance/geometry/insertion_point_image.h"
#include "endo_guidance/sim/synthetic_scene.h"
#include "test_util.h"

using namespace endo_guidance::geometry;
using namespace endo_guidance::sim;
namespace test = endo_guidance::test;

// Three instruments: every noisy region is attached to its own trocar, in 3D and in the image.
TEST(Classification, ThreeInstruments) {
  SyntheticSceneOptions so;
  so.line_noise_px = 0.2;
  SyntheticScene scene(defaultInstruments(), so);
  std::vector<Eigen::Vector3d> trocars, images;
  for (std::size_t i = 0; i < scene.size(); ++i) {
    trocars.push_back(scene.meanTrocar(static_cast<int>(i)));
    images.push_back(projectPointHomogeneous(so.K, trocars.back()));
  }
  int n = 0, ok3 = 0, ok2 = 0;
  for (int k = 0; k < 300; ++k)
    for (auto const& v : scene.frame(k)) {
      auto const r = estimateCylinderPose(so.K, v.radius, v.measured);
      ASSERT_TRUE(r.ok());
      ++n;
      auto const a3 = classifyAxis(r.pose.axis, trocars, 0.015);
      ok3 += a3.index == v.instrument;
      auto const l = imageOfAxis(so.K, r.pose.axis);
      ASSERT_TRUE(l);
      auto const a2 = classifyImageLine(*l, images, 15.0);
      ok2 += a2.index == v.instrument;
      EXPECT_GT(a3.second, a3.distance);
    }
  ASSERT_GT(n, 500);
  EXPECT_GT(ok3, 0.99 * n);
  EXPECT_GT(ok2, 0.97 * n);
}

TEST(Classification, RejectsFarAxesAndLines) {
  std::vector<Eigen::Vector3d> const trocars{{0.1, 0.0, 0.0}, {-0.1, 0.0, 0.0}};
  auto const axis = PluckerLine::fromPointDirection({0.0, 0.05, 0.1}, {0, 0, 1});
  auto const a = classifyAxis(*axis, trocars, 0.01);
  EXPECT_EQ(a.index, -1);
  EXPECT_NEAR(a.distance, std::hypot(0.1, 0.05), 1e-12);
  EXPECT_EQ(classifyAxis(*axis, {}, 0.01).index, -1);
  // Image: finite point at 3 px from the line -> accepted at tau 5, rejected at tau 2.
  ImageLine const l(0.0, 1.0, -100.0);  // v = 100
  std::vector<Eigen::Vector3d> const pts{{50.0, 103.0, 1.0}, {2.0, 0.0, 0.0}};
  EXPECT_EQ(classifyImageLine(l, {pts[0]}, 5.0).index, 0);
  EXPECT_NEAR(classifyImageLine(l, {pts[0]}, 5.0).distance, 3.0, 1e-12);
  EXPECT_EQ(classifyImageLine(l, {pts[0]}, 2.0).index, -1);
  // Image point at infinity along u: the horizontal line is compatible; a vertical one is not.
  EXPECT_EQ(classifyImageLine(l, {pts[1]}, 1.0).index, 0);
  EXPECT_EQ(classifyImageLine(ImageLine(1.0, 0.0, -5.0), {pts[1]}, 1.0).index, -1);
  EXPECT_EQ(classifyImageLine(ImageLine(0.0, 0.0, 1.0), {pts[0]}, 5.0).index, -1);  // invalid line
}
