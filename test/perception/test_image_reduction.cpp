// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "endo_guidance/perception/image_reduction.h"

using namespace endo_guidance::perception;

namespace {
cv::Mat randomImage(int w, int h, int seed) {
  cv::Mat m(h, w, CV_8UC3);
  cv::RNG rng(seed);
  rng.fill(m, cv::RNG::UNIFORM, 0, 256);
  return m;
}
// The rounded mean of each f x f block, computed directly.
cv::Mat blockMeans(cv::Mat const& src, int f) {
  cv::Mat out(src.rows / f, src.cols / f, CV_8UC3);
  for (int y = 0; y < out.rows; ++y)
    for (int x = 0; x < out.cols; ++x)
      for (int k = 0; k < 3; ++k) {
        int s = 0;
        for (int j = 0; j < f; ++j)
          for (int i = 0; i < f; ++i) s += src.at<cv::Vec3b>(f * y + j, f * x + i)[k];
        out.at<cv::Vec3b>(y, x)[k] = static_cast<std::uint8_t>((2 * s + f * f) / (2 * f * f));  // round half up
      }
  return out;
}
int maxDiff(cv::Mat const& a, cv::Mat const& b) {
  cv::Mat d;
  cv::absdiff(a, b, d);
  double m = 0.0;
  cv::minMaxLoc(d.reshape(1), nullptr, &m);
  return static_cast<int>(m);
}
}  // namespace

TEST(ImageReduction, HalvingEqualsOpenCVAreaResamplingBitForBit) {
  // Both code paths: the AVX2 one where the CPU has it, and OpenCV's resampling (optimisations
  // off). Widths with and without a SIMD tail (8 output pixels per step, the last 10 by the
  // scalar row), too narrow for a step, and a submatrix (row stride, bytes past the row's end).
  for (bool const optimised : {true, false}) {
    cv::setUseOptimized(optimised);
    for (auto const& wh : {cv::Size(640, 480), cv::Size(720, 576), cv::Size(38, 10), cv::Size(2, 2), cv::Size(66, 6),
                           cv::Size(20, 4), cv::Size(22, 4), cv::Size(36, 2), cv::Size(1922, 6)}) {
      cv::Mat const src = randomImage(wh.width, wh.height, wh.width);
      cv::Mat ref, got;
      cv::resize(src, ref, wh / 2, 0, 0, cv::INTER_AREA);
      reduceImage(src, 2, got);
      ASSERT_EQ(got.size(), ref.size());
      EXPECT_EQ(maxDiff(got, ref), 0) << wh << (optimised ? " optimised" : " plain");
      EXPECT_EQ(maxDiff(got, blockMeans(src, 2)), 0) << wh;
    }
    cv::Mat const big = randomImage(700, 300, 7);
    cv::Mat const roi = big(cv::Rect(3, 5, 642, 290));
    cv::Mat ref, got;
    cv::resize(roi, ref, roi.size() / 2, 0, 0, cv::INTER_AREA);
    reduceImage(roi, 2, got);
    EXPECT_EQ(maxDiff(got, ref), 0);
  }
  cv::setUseOptimized(true);
}

TEST(ImageReduction, InPlaceGivesTheSameAsIntoAnotherImage) {
  for (int f : {2, 3, 7}) {
    cv::Mat m = randomImage(100, 40, f);
    cv::Mat const expected = blockMeans(m, f);
    reduceImage(m, f, m);
    ASSERT_EQ(m.size(), expected.size()) << f;
    EXPECT_EQ(maxDiff(m, expected), 0) << f;
  }
}

TEST(ImageReduction, EveryFactorGivesTheRoundedBlockMeansAndDropsTheRemainder) {
  cv::Mat const src = randomImage(101, 47, 3);  // odd sizes: the last columns and rows are dropped
  for (int f : {2, 3, 4, 5, 6, 7, 8, 9}) {
    cv::Mat got;
    reduceImage(src, f, got);
    ASSERT_EQ(got.size(), cv::Size(101 / f, 47 / f)) << f;
    EXPECT_EQ(maxDiff(got, blockMeans(src, f)), 0) << f;
  }
  // The largest factor: every block mean exact too.
  cv::Mat const large = randomImage(512, 300, 5);
  cv::Mat got255;
  reduceImage(large, 255, got255);
  ASSERT_EQ(got255.size(), cv::Size(2, 1));
  EXPECT_EQ(maxDiff(got255, blockMeans(large, 255)), 0);
  cv::Mat same;
  reduceImage(src, 1, same);
  EXPECT_EQ(same.data, src.data);  // shared, not copied
  // Saturated input stays exact (no 16-bit overflow in the row sums).
  cv::Mat const white(48, 48, CV_8UC3, cv::Scalar::all(255));
  for (int f : {2, 12, 16}) {
    cv::Mat got;
    reduceImage(white, f, got);
    EXPECT_EQ(cv::countNonZero(got.reshape(1) != 255), 0) << f;
  }
  cv::Mat bad;
  EXPECT_THROW(reduceImage(cv::Mat(10, 10, CV_8UC1), 2, bad), cv::Exception);
  EXPECT_THROW(reduceImage(src, 0, bad), cv::Exception);
}

// A processing pixel maps to the centre of its block at full resolution (toFullRes) and back
// (toProcessing): the block of reduced pixel (x, y) covers full-resolution columns f x .. f x +
// f - 1, whose centre is f x + (f - 1) / 2. Checked against reduceImage() itself: the ramp
// I = x reduces to the ramp's value at the mapped column (within the rounding of a half).
TEST(ImageReduction, PixelsMapToTheirBlocksCentres) {
  for (int f : {1, 2, 3, 4, 6}) {
    for (Eigen::Vector2d const& p : {Eigen::Vector2d(0, 0), Eigen::Vector2d(7, 3), Eigen::Vector2d(2.5, 11.25)}) {
      Eigen::Vector2d const q = toFullRes(p, f);
      EXPECT_DOUBLE_EQ(q.x(), f * p.x() + 0.5 * (f - 1));
      EXPECT_DOUBLE_EQ(q.y(), f * p.y() + 0.5 * (f - 1));
      EXPECT_LT((toProcessing(q, f) - p).norm(), 1e-12);
      for (double w : {1.0, -2.5}) {  // homogeneous, at any scale
        Eigen::Vector3d const h = toProcessing(Eigen::Vector3d(q.x() * w, q.y() * w, w), f);
        EXPECT_LT((h.head<2>() / h.z() - p).norm(), 1e-12);
      }
    }
    // A point at infinity (a direction) keeps its direction.
    Eigen::Vector3d const dir = toProcessing(Eigen::Vector3d(3.0, -4.0, 0.0), f);
    EXPECT_DOUBLE_EQ(dir.z(), 0.0);
    EXPECT_NEAR(dir.x() * -4.0 - dir.y() * 3.0, 0.0, 1e-12);
    cv::Mat ramp(6 * f, 24 * f, CV_8UC3), small;
    for (int y = 0; y < ramp.rows; ++y)
      for (int x = 0; x < ramp.cols; ++x) ramp.at<cv::Vec3b>(y, x) = cv::Vec3b::all(static_cast<std::uint8_t>(x));  // (< 256)
    reduceImage(ramp, f, small);
    for (int x = 0; x < small.cols; ++x)
      EXPECT_NEAR(small.at<cv::Vec3b>(2, x)[0], toFullRes(Eigen::Vector2d(x, 2), f).x(), 0.5 + 1e-9) << "f " << f << " x " << x;
  }
}
