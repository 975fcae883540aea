// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include "endo_guidance/perception/seed_search.h"

using namespace endo_guidance::perception;

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

// A dark border covered mostly by shafts and a grey blob: the local "tissue level" (upper
// quartile of the window) is then their own, and 0.7 of it falls inside a shaft's noise.
// run_floor keeps a noisy shaft one run (not stubs split at its noisy pixels); a shaft beside
// the blob, in one run with it, is seeded in its own (lower) part, not in the run's middle.
TEST(SeedSearch, ShaftsCoveringTheBorderWindow) {
  cv::Mat bgr(120, 160, CV_8UC3, cv::Scalar(60, 80, 160));
  FieldOfView const fov = detectFieldOfView(bgr);
  cv::Mat feature(120, 160, CV_8U, cv::Scalar(120));
  // Along the bottom border: a grey blob (9-11) on x = 0-59, a shaft (4-5) on 60-79 beside it,
  // tissue (120) on 80-99, a noisy shaft (6-10) on 100-159.
  auto value = [](int x) { return x < 60 ? 9 + x % 3 : x < 80 ? 4 + x % 2 : x < 100 ? 120 : 6 + (x * 7) % 5; };
  for (int x = 0; x < 160; ++x) feature(cv::Rect(x, 100, 1, 20)).setTo(value(x));
  auto bottomSeeds = [&](SeedSearchParams const& p) {
    std::vector<Seed> out;
    for (auto const& s : findSeeds(feature, fov, p))
      if (s.position.y >= 100) out.push_back(s);
    return out;
  };
  SeedSearchParams p;
  auto const seeds = bottomSeeds(p);
  // The noisy shaft: one run (it reaches up the right border's low corner too).
  bool noisy_whole = false, beside_blob = false;
  for (auto const& s : seeds) {
    noisy_whole |= s.width >= 60 && s.position.x >= 100;
    // The blob and the shaft beside it: one run from the left border's low corner to x = 80,
    // seeded on the shaft, with the shaft's level.
    if (s.position.x >= 60 && s.position.x < 80) beside_blob = s.width >= 80 && s.mean_value < 6.f;
  }
  EXPECT_TRUE(noisy_whole) << seeds.size() << " seeds";
  EXPECT_TRUE(beside_blob) << seeds.size() << " seeds";
  // Without the floor (the relative threshold alone, about 0.7 x 10 = 7) the noisy shaft breaks
  // up into stubs.
  p.run_floor = 0;
  int longest = 0;
  for (auto const& s : bottomSeeds(p))
    if (s.position.x >= 100) longest = std::max(longest, s.width);
  EXPECT_LT(longest, 40);
}
