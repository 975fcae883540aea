// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <algorithm>

#include "endo_guidance/perception/region_growing.h"

using namespace endo_guidance::perception;

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

TEST(RegionGrowing, GrowthLevelsAreLoweredOnADarkBorderThenTheAbsoluteOnesAbove) {
  RegionGrowingParams p;  // thresholds 18 24 30 37 45, fractions 0.4 0.52 0.64 0.76 0.88, dark border < 45
  // A bright border: the absolute thresholds only.
  GrowthLevels const bright = growthLevels(p, 10.f, 60.f);
  EXPECT_EQ(bright.thresholds, p.thresholds);
  EXPECT_EQ(bright.strip_level, 45);
  // A dark border (tissue at 30, seed at 10): 10 + f (30 - 10) = 18, 20.4, 22.8, 25.2, 27.6 ->
  // min with the thresholds: 18 20 23 25 28; then the absolute levels above 28: 30 37 45.
  GrowthLevels const dark = growthLevels(p, 10.f, 30.f);
  EXPECT_EQ(dark.thresholds, (std::vector<int>{18, 20, 23, 25, 28, 30, 37, 45}));
  EXPECT_EQ(dark.strip_level, 28);
  EXPECT_TRUE(std::is_sorted(dark.thresholds.begin(), dark.thresholds.end()));
  // A border no brighter than the seed: unchanged.
  EXPECT_EQ(growthLevels(p, 20.f, 22.f).thresholds, p.thresholds);
}

TEST(RegionGrowing, ARememberedLevelIsFoundAgainWhenTheListChangesLength) {
  RegionGrowingParams p;
  int const n = static_cast<int>(p.thresholds.size());
  std::vector<int> const dark = growthLevels(p, 10.f, 30.f).thresholds;  // 18 20 23 25 28 30 37 45
  std::vector<int> const bright = growthLevels(p, 10.f, 60.f).thresholds;  // 18 24 30 37 45
  // A place in the configured list is kept (it follows the tissue's level).
  EXPECT_EQ(rememberedLevel(bright, n, 2, dark[2]), 2);
  EXPECT_EQ(rememberedLevel(dark, n, 4, bright[4]), 4);
  // An absolute level added on a dark border (index 6: 37) is found by its threshold in a list
  // without it, and is never out of range (the shorter list has 5 levels).
  EXPECT_EQ(rememberedLevel(bright, n, 6, 37), 3);
  EXPECT_EQ(rememberedLevel(bright, n, 7, 45), 4);
  EXPECT_EQ(rememberedLevel(dark, n, 6, 37), 6);
  // A list of another dark border where 37 is not added (all lowered levels above 30): the nearest.
  std::vector<int> const other = growthLevels(p, 20.f, 44.f).thresholds;  // 18 24 30 37 41, then 45
  EXPECT_EQ(other[rememberedLevel(other, n, 6, 37)], 37);
  EXPECT_EQ(rememberedLevel({}, n, 3, 30), -1);
}
