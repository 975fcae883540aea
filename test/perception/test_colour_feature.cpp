// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "endo_guidance/perception/colour_feature.h"

using namespace endo_guidance::perception;

TEST(ColourFeature, GreyAndBlackAreLowTissueIsHigh) {
  ColourFeature const f;
  EXPECT_EQ(f.exact(128, 128, 128), 0.0f);       // grey metal
  EXPECT_EQ(f.exact(20, 20, 20), 0.0f);          // black
  EXPECT_LT(f.exact(30, 25, 35), 20.0f);         // dark, slightly reddish shaft
  EXPECT_GT(f.exact(70, 60, 175), 120.0f);       // red tissue
  EXPECT_GT(f.exact(70, 165, 215), 180.0f);      // yellow fat
  EXPECT_GT(f.exact(140, 120, 200), 60.0f);      // pink, pale
  // Hue origin: green maps to the lowest weight by default.
  EXPECT_LT(f.exact(50, 200, 50), 10.0f);
  ColourFeatureParams p;
  p.hue_origin_deg = 0.0;  // red origin: red tissue would become low (why the default is green)
  EXPECT_LT(ColourFeature(p).exact(60, 60, 200), 5.0f);
}

TEST(ColourFeature, LookupTableMatchesExactWithinQuantisation) {
  ColourFeature const f;
  cv::Mat img(64, 64, CV_8UC3);
  cv::randu(img, 0, 256);
  cv::Mat out;
  f.compute(img, out);
  ASSERT_EQ(out.type(), CV_8U);
  // 6-bit bins: the chroma is off by at most ~4 levels (x2 for the hue weight), the weight by
  // a few percent; near the hue origin's wrap the weight can jump, hence the count below.
  int within = 0;
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x) {
      cv::Vec3b const c = img.at<cv::Vec3b>(y, x);
      float const e = std::min(255.f, f.exact(c[0], c[1], c[2]));
      within += std::abs(e - out.at<std::uint8_t>(y, x)) <= 8.f + 0.05f * e;
    }
  EXPECT_GT(within, 64 * 64 * 97 / 100);
  int big = 0;
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x) {
      cv::Vec3b const c = img.at<cv::Vec3b>(y, x);
      big += std::abs(std::min(255.f, f.exact(c[0], c[1], c[2])) - out.at<std::uint8_t>(y, x)) > 12.f;
    }
  EXPECT_LT(big, 64 * 64 / 50);
}

TEST(ColourFeature, EveryBinMatchesItsTableValue) {
  // compute() runs 16 pixels at a time in integer arithmetic at the default parameters, the
  // lookup table otherwise (and on a row's tail): both must give the table's value, the exact
  // feature at the centre of the 6-bit bin, rounded and clipped, for every bin (and any low bits).
  ColourFeature const f;
  cv::Mat img(512, 512, CV_8UC3), out;  // 2^18 pixels: one per bin
  for (int i = 0; i < 512 * 512; ++i) {
    int const b = i >> 12, g = (i >> 6) & 63, r = i & 63, low = (i * 7) & 3;
    img.at<cv::Vec3b>(i / 512, i % 512) = cv::Vec3b(static_cast<std::uint8_t>(4 * b + low), static_cast<std::uint8_t>(4 * g + (3 - low)),
                                                     static_cast<std::uint8_t>(4 * r + (low ^ 1)));
  }
  f.compute(img, out);
  int wrong = 0;
  for (int i = 0; i < 512 * 512; ++i) {
    cv::Vec3b const c = img.at<cv::Vec3b>(i / 512, i % 512);
    float const e = f.exact((c[0] >> 2) * 4 + 1.5f, (c[1] >> 2) * 4 + 1.5f, (c[2] >> 2) * 4 + 1.5f);
    wrong += out.at<std::uint8_t>(i / 512, i % 512) != std::lround(std::clamp(e, 0.0f, 255.0f));
  }
  EXPECT_EQ(wrong, 0);
  // Another hue origin takes the table: the same definition.
  ColourFeatureParams p;
  p.hue_origin_deg = 100.0;
  ColourFeature const f2(p);
  cv::Mat out2;
  f2.compute(img, out2);
  wrong = 0;
  for (int i = 0; i < 512 * 512; i += 7) {
    cv::Vec3b const c = img.at<cv::Vec3b>(i / 512, i % 512);
    float const e = f2.exact((c[0] >> 2) * 4 + 1.5f, (c[1] >> 2) * 4 + 1.5f, (c[2] >> 2) * 4 + 1.5f);
    wrong += out2.at<std::uint8_t>(i / 512, i % 512) != std::lround(std::clamp(e, 0.0f, 255.0f));
  }
  EXPECT_EQ(wrong, 0);
}
