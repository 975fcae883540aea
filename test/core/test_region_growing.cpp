// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include "endo_guidance/core/region_growing.h"

using namespace endo_guidance::core;

TEST(RegionGrowing, GrowsBelowThresholdInsideTheView) {
  cv::Mat bgr(100, 100, CV_8UC3, cv::Scalar(60, 80, 160));
  FieldOfView const fov = detectFieldOfView(bgr);
  cv::Mat feature(100, 100, CV_8U, cv::Scalar(100));
  feature(cv::Rect(40, 0, 10, 60)).setTo(10);
  feature(cv::Rect(50, 30, 20, 5)).setTo(30);  // joins only at threshold >= 30
  RegionGrower g;
  g.reset(feature, fov);
  auto const r1 = g.grow({45, 3}, 20);
  ASSERT_TRUE(r1);
  EXPECT_EQ(r1->box.x, 40);
  EXPECT_EQ(r1->box.width, 10);
  EXPECT_GT(r1->box.height, 50);
  EXPECT_GE(r1->box.y, 3);  // the 3-px inset of the view is outside
  auto const r2 = g.grow({45, 3}, 30);
  ASSERT_TRUE(r2);
  EXPECT_GT(r2->area, r1->area + 80);
  EXPECT_FALSE(g.grow({10, 10}, 50));  // seed above the threshold
  // Claimed pixels are skipped; a claim limited to a polygon takes only its part.
  g.claim(*r1, 1, {{40, 0}, {50, 0}, {50, 20}, {40, 20}});
  EXPECT_TRUE(g.claimed({45, 10}));
  EXPECT_FALSE(g.claimed({45, 40}));
  EXPECT_FALSE(g.grow({45, 10}, 20));
  auto const r3 = g.grow({45, 40}, 20);
  ASSERT_TRUE(r3);
  EXPECT_LT(r3->area, r1->area);
  EXPECT_EQ(g.labels().at<std::uint8_t>(10, 45), 1);
}
