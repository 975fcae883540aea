// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/core/image_reduction.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cstdint>
#include <vector>

namespace endo_guidance::core {

namespace {

// f x f means (f > 2): rows accumulated in 16 bits, then each block's sum s rounded to nearest
// (half up), floor((2 s + f^2) / (2 f^2)), in one pass (OpenCV's area resampling is slow for
// factors above 2: 5 ms for 1920x1080 / 6 here). F > 0: the factor known at compile time, so the
// block sums are unrolled and the division is the compiler's exact multiply-shift (4x faster at
// 1920x1080 / 6). F = 0: n = 2 s + f^2 < 2^25 over q = 2 f^2 < 2^17 as (n M) >> 42 with
// M = ceil(2^42 / q): exact, since n (M q - 2^42) < n q < 2^42 (and n M < 2^63).
template <int F>
void boxMeans(cv::Mat const& src, int factor, cv::Mat& dst) {
  int const f = F > 0 ? F : factor;
  int const W = src.cols / f, H = src.rows / f, n = 3 * W * f;
  dst.create(H, W, CV_8UC3);
  std::vector<std::uint16_t> acc(static_cast<std::size_t>(n));
  std::uint32_t const d = static_cast<std::uint32_t>(f * f);
  std::uint64_t const M = ((std::uint64_t{1} << 42) + 2 * d - 1) / (2 * d);
  auto mean = [&](std::uint32_t s) {
    if constexpr (F > 0) return static_cast<std::uint8_t>((2 * s + F * F) / (2 * F * F));
    else return static_cast<std::uint8_t>((static_cast<std::uint64_t>(2 * s + d) * M) >> 42);
  };
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
        out[3 * x + ch] = mean(sum);
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
  else if (f == 3) boxMeans<3>(src, f, dst);
  else if (f == 4) boxMeans<4>(src, f, dst);
  else if (f == 5) boxMeans<5>(src, f, dst);
  else if (f == 6) boxMeans<6>(src, f, dst);  // 1920x1080 at the default processing width
  else if (f == 8) boxMeans<8>(src, f, dst);
  else boxMeans<0>(src, f, dst);
}

}  // namespace endo_guidance::core
