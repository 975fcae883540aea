// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "endo_guidance/core/field_of_view.h"

using namespace endo_guidance::core;

TEST(FieldOfView, FullRectangle) {
  cv::Mat img(120, 160, CV_8UC3, cv::Scalar(60, 80, 160));
  img(cv::Rect(70, 0, 12, 60)).setTo(cv::Scalar(15, 15, 15));  // a black shaft touching the border
  FieldOfView const f = detectFieldOfView(img);
  ASSERT_TRUE(f.valid());
  EXPECT_FALSE(f.circular);
  EXPECT_EQ(f.bounds, cv::Rect(0, 0, 160, 120));  // the shaft does not notch it
  for (auto const& p : f.border) {
    EXPECT_GE(std::min({p.x, p.y, 159 - p.x, 119 - p.y}), 2);
    EXPECT_LE(std::min({p.x, p.y, 159 - p.x, 119 - p.y}), 4);
  }
}

TEST(FieldOfView, CircularWithBlackSurround) {
  cv::Mat img(240, 320, CV_8UC3, cv::Scalar(0, 0, 0));
  cv::circle(img, {160, 120}, 110, cv::Scalar(70, 90, 170), -1);
  FieldOfView const f = detectFieldOfView(img);
  ASSERT_TRUE(f.valid());
  EXPECT_TRUE(f.circular);
  EXPECT_NEAR(f.centre.x, 160, 1.0);
  EXPECT_NEAR(f.centre.y, 120, 1.0);
  for (auto const& p : f.border) EXPECT_NEAR(std::hypot(p.x - 160.0, p.y - 120.0), 110 - 3, 2.5);
  EXPECT_GT(f.depth.at<float>(120, 160), 100.f);
  EXPECT_EQ(f.depth.at<float>(5, 5), 0.f);
}

TEST(FieldOfView, SideBars) {
  cv::Mat img(100, 200, CV_8UC3, cv::Scalar(0, 0, 0));
  img(cv::Rect(12, 0, 176, 100)).setTo(cv::Scalar(60, 80, 160));
  FieldOfView const f = detectFieldOfView(img);
  EXPECT_FALSE(f.circular);
  EXPECT_NEAR(f.bounds.x, 12, 1);
  EXPECT_NEAR(f.bounds.width, 176, 2);
}
