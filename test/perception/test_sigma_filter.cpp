// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <opencv2/core.hpp>

#include "endo_guidance/perception/sigma_filter.h"

using namespace endo_guidance::perception;

namespace {
// Reference: the textbook definition, integer mean rounded to nearest.
cv::Mat reference(cv::Mat const& src, int R, int delta) {
  cv::Mat dst(src.size(), CV_8U);
  for (int y = 0; y < src.rows; ++y)
    for (int x = 0; x < src.cols; ++x) {
      int const c = src.at<std::uint8_t>(y, x);
      int sum = 0, n = 0;
      for (int dy = -R; dy <= R; ++dy)
        for (int dx = -R; dx <= R; ++dx) {
          int const yy = std::clamp(y + dy, 0, src.rows - 1), xx = std::clamp(x + dx, 0, src.cols - 1);
          int const v = src.at<std::uint8_t>(yy, xx);
          if (std::abs(v - c) <= delta) {
            sum += v;
            ++n;
          }
        }
      dst.at<std::uint8_t>(y, x) = static_cast<std::uint8_t>((sum * 2 + n) / (2 * n));
    }
  return dst;
}
}  // namespace

TEST(SigmaFilter, MatchesTheDefinition) {
  // Widths through each path: 32-pixel (AVX2) and 16-pixel (SSE2) blocks, and a scalar tail
  // (53 = 32 + 16 + 5 where the CPU has AVX2); random values, and a smooth ramp
  // (many windows whose mean is exactly half-way: the rounding must be half up, as defined).
  for (int w : {53, 64, 5}) {
    cv::Mat img(37, w, CV_8U), ramp(37, w, CV_8U);
    cv::randu(img, 0, 256);
    for (int y = 0; y < ramp.rows; ++y)
      for (int x = 0; x < ramp.cols; ++x) ramp.at<std::uint8_t>(y, x) = static_cast<std::uint8_t>((3 * x + 5 * y) % 256);
    for (cv::Mat const* m : {&img, &ramp})
      for (int R : {1, 2, 3})
        for (int delta : {0, 5, 20, 255}) {
          cv::Mat out;
          sigmaFilter(*m, out, R, delta);
          cv::Mat const ref = reference(*m, R, delta);
          EXPECT_EQ(cv::norm(out, ref, cv::NORM_INF), 0.0) << "width " << w << " R " << R << " delta " << delta;
        }
  }
}

TEST(SigmaFilter, KeepsEdgesAndSmoothsNoise) {
  cv::Mat img(40, 40, CV_8U, cv::Scalar(40));
  img(cv::Rect(20, 0, 20, 40)).setTo(140);
  cv::Mat noise(img.size(), CV_8S);
  cv::randn(noise, 0, 4);
  cv::Mat noisy;
  img.convertTo(noisy, CV_16S);
  cv::Mat n16;
  noise.convertTo(n16, CV_16S);
  noisy += n16;
  noisy.convertTo(noisy, CV_8U);
  cv::Mat out;
  sigmaFilter(noisy, out, 2, 15);
  // The step survives: columns 19 and 20 stay on their sides.
  for (int y = 2; y < 38; ++y) {
    EXPECT_LT(out.at<std::uint8_t>(y, 19), 60);
    EXPECT_GT(out.at<std::uint8_t>(y, 20), 120);
  }
  // Noise is reduced inside the flat halves.
  cv::Scalar m0, s0, m1, s1;
  cv::meanStdDev(noisy(cv::Rect(3, 3, 14, 34)), m0, s0);
  cv::meanStdDev(out(cv::Rect(3, 3, 14, 34)), m1, s1);
  EXPECT_LT(s1[0], 0.6 * s0[0]);
  EXPECT_THROW(sigmaFilter(noisy, noisy, 1, 5), cv::Exception);  // in place is refused
}
