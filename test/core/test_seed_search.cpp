// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include "endo_guidance/core/seed_search.h"

using namespace endo_guidance::core;

TEST(SeedSearch, LowRunsOnTheBorderBecomeSeeds) {
  cv::Mat bgr(120, 160, CV_8UC3, cv::Scalar(60, 80, 160));
  FieldOfView const fov = detectFieldOfView(bgr);
  cv::Mat feature(120, 160, CV_8U, cv::Scalar(120));
  feature(cv::Rect(70, 0, 12, 40)).setTo(10);   // a shaft entering from the top
  feature(cv::Rect(0, 90, 30, 9)).setTo(20);    // one from the left
  feature(cv::Rect(150, 50, 10, 1)).setTo(5);   // a 1-px scratch: too thin
  auto const seeds = findSeeds(feature, fov);
  ASSERT_EQ(seeds.size(), 2u);
  bool top = false, left = false;
  for (auto const& s : seeds) {
    top |= s.position.y <= 4 && s.position.x >= 70 && s.position.x < 82;
    left |= s.position.x <= 4 && s.position.y >= 90 && s.position.y < 99;
    EXPECT_GE(s.width, 3);
  }
  EXPECT_TRUE(top && left);
  // With a trocar image up and to the right, the top seed comes first and is attached to it.
  auto const focused = findSeeds(feature, fov, {}, {Eigen::Vector3d(100, -400, 1)});
  ASSERT_EQ(focused.size(), 2u);
  EXPECT_LE(focused[0].position.y, 4);
  EXPECT_EQ(focused[0].insertion_point, 0);
  EXPECT_EQ(focused[1].insertion_point, -1);
  // A uniformly low border (no contrast) gives no seed.
  cv::Mat flat(120, 160, CV_8U, cv::Scalar(5));
  EXPECT_TRUE(findSeeds(flat, fov).empty());
}
