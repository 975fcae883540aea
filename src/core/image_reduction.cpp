// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/core/image_reduction.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cstdint>
#include <vector>

namespace endo_guidance::core {

namespace {

// f x f means (f > 2): rows accumulated in 16 bits, then each block's sum rounded to nearest
// (half up), in one pass (OpenCV's area resampling is slow for factors above 2: 5 ms for
// 1920x1080 / 6 here). (2 s + d) / (2 d), d = f^2, in double: a non-integer quotient is at least
// 1 / (2 d) >= 7.7e-6 below the next integer, so the 1e-6 added against the product's rounding
// never carries.
void boxMeans(cv::Mat const& src, int f, cv::Mat& dst) {
  int const W = src.cols / f, H = src.rows / f, n = 3 * W * f;
  dst.create(H, W, CV_8UC3);
  std::vector<std::uint16_t> acc(static_cast<std::size_t>(n));
  double const d = static_cast<double>(f) * f, rcp = 1.0 / (2.0 * d);
  for (int y = 0; y < H; ++y) {
    std::fill(acc.begin(), acc.end(), 0);
    for (int r = 0; r < f; ++r) {
      std::uint8_t const* __restrict in = src.ptr<std::uint8_t>(y * f + r);
      std::uint16_t* __restrict a = acc.data();
      for (int i = 0; i < n; ++i) a[i] = static_cast<std::uint16_t>(a[i] + in[i]);
    }
    std::uint8_t* out = dst.ptr<std::uint8_t>(y);
    for (int x = 0; x < W; ++x)
      for (int ch = 0; ch < 3; ++ch) {
        std::uint32_t sum = 0;
        for (int j = 0; j < f; ++j) sum += acc[static_cast<std::size_t>(3 * (x * f + j) + ch)];
        out[3 * x + ch] = static_cast<std::uint8_t>((2.0 * sum + d) * rcp + 1e-6);
      }
  }
}

}  // namespace

void reduceImage(cv::Mat const& src, int f, cv::Mat& dst) {
  CV_Assert(src.type() == CV_8UC3 && f >= 1 && f <= 255);  // (16-bit row sums)
  if (f == 1) dst = src;
  // OpenCV's area resampling at exactly 2 (an even-sized view): its fast path, (a + b + c + d + 2) >> 2.
  // (A universal-intrinsics version measured 150-190 us against its 115-160 us at 640x480:
  // de-interleaving BGR without SSSE3 costs more than it saves.)
  else if (f == 2) cv::resize(src(cv::Rect(0, 0, src.cols / 2 * 2, src.rows / 2 * 2)), dst, cv::Size(src.cols / 2, src.rows / 2), 0, 0, cv::INTER_AREA);
  else boxMeans(src, f, dst);
}

}  // namespace endo_guidance::core
