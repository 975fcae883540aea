// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "endo_guidance/perception/field_of_view.h"

using namespace endo_guidance::perception;

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
  // Depth: the distance to the area's edge, the image's edge included (a full-rectangle view has
  // no black surround; the shafts still enter across the image edge).
  EXPECT_NEAR(f.depth.at<float>(60, 80), 60.f, 1.5f);
  EXPECT_NEAR(f.depth.at<float>(0, 80), 1.f, 0.5f);
  EXPECT_NEAR(f.depth.at<float>(60, 0), 1.f, 0.5f);
  EXPECT_NEAR(f.depth.at<float>(30, 10), 11.f, 1.0f);
  // depthAt(): the nearest pixel's depth, clamped to the image; 0 without a depth map.
  EXPECT_EQ(depthAt(f, {10.4, 29.6}), f.depth.at<float>(30, 10));
  EXPECT_EQ(depthAt(f, {-7.0, 60.2}), f.depth.at<float>(60, 0));
  EXPECT_EQ(depthAt(f, {500.0, 500.0}), f.depth.at<float>(119, 159));
  EXPECT_EQ(depthAt(FieldOfView{}, {10.0, 10.0}), 0.0);
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
  // Between the bars the depth is the distance to the nearer bar or to the top/bottom edge.
  EXPECT_NEAR(f.depth.at<float>(50, 100), 50.f, 1.5f);
  EXPECT_NEAR(f.depth.at<float>(50, 20), 8.f, 1.5f);
  EXPECT_NEAR(f.depth.at<float>(2, 100), 3.f, 0.5f);
}
