// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include "endo_guidance/geometry/classification.h"
#include "endo_guidance/geometry/cylinder_pose.h"
#include "endo_guidance/sim/synthetic_scene.h"
#include "test_util.h"

using namespace endo_guidance::geometry;
using namespace endo_guidance::sim;
namespace test = endo_guidance::test;

// Three instruments: every noisy axis is attached to its own trocar.
TEST(Classification, ThreeInstruments) {
  SyntheticSceneOptions so;
  so.line_noise_px = 0.2;
  SyntheticScene scene(defaultInstruments(), so);
  std::vector<Eigen::Vector3d> trocars;
  for (std::size_t i = 0; i < scene.size(); ++i) trocars.push_back(scene.meanTrocar(static_cast<int>(i)));
  int n = 0, ok3 = 0;
  for (int k = 0; k < 300; ++k)
    for (auto const& v : scene.frame(k)) {
      auto const r = estimateCylinderPose(so.K, v.radius, v.measured);
      ASSERT_TRUE(r.ok());
      ++n;
      auto const a3 = classifyAxis(r.pose.axis, trocars, 0.015);
      ok3 += a3.index == v.instrument;
      EXPECT_GT(a3.second, a3.distance);
    }
  ASSERT_GT(n, 500);
  EXPECT_GT(ok3, 0.99 * n);
}

TEST(Classification, RejectsFarAxes) {
  std::vector<Eigen::Vector3d> const trocars{{0.1, 0.0, 0.0}, {-0.1, 0.0, 0.0}};
  auto const axis = PluckerLine::fromPointDirection({0.0, 0.05, 0.1}, {0, 0, 1});
  auto const a = classifyAxis(*axis, trocars, 0.01);
  EXPECT_EQ(a.index, -1);
  EXPECT_NEAR(a.distance, std::hypot(0.1, 0.05), 1e-12);
  EXPECT_EQ(classifyAxis(*axis, {}, 0.01).index, -1);
}
