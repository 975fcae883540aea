// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/core/sigma_filter.h"

#include <algorithm>
#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

namespace endo_guidance {

void sigmaFilter(cv::Mat const& src, cv::Mat& dst, int radius, int delta) {
  CV_Assert(src.type() == CV_8U && radius >= 1 && radius <= 3 && delta >= 0);
  CV_Assert(src.data != dst.data);
  int const W = src.cols, H = src.rows, R = radius;
  cv::Mat pad;
  cv::copyMakeBorder(src, pad, R, R, R, R, cv::BORDER_REPLICATE);
  dst.create(src.size(), CV_8U);
  int const n = (2 * R + 1) * (2 * R + 1);
  // Reciprocals in 16.16 fixed point: mean = (sum * inv[cnt] + 2^15) >> 16.
  std::vector<std::uint32_t> inv(static_cast<std::size_t>(n) + 1, 0);
  for (int c = 1; c <= n; ++c) inv[c] = static_cast<std::uint32_t>((65536u + c / 2) / c);
  std::vector<std::uint16_t> sum(static_cast<std::size_t>(W));
  std::vector<std::uint8_t> cnt(static_cast<std::size_t>(W));
  std::uint8_t const d = static_cast<std::uint8_t>(std::min(delta, 255));
  for (int y = 0; y < H; ++y) {
    std::uint8_t const* c = pad.ptr<std::uint8_t>(y + R) + R;
    std::fill(sum.begin(), sum.end(), 0);
    std::fill(cnt.begin(), cnt.end(), 0);
    std::uint16_t* __restrict s = sum.data();
    std::uint8_t* __restrict k = cnt.data();
    for (int dy = -R; dy <= R; ++dy) {
      std::uint8_t const* row = pad.ptr<std::uint8_t>(y + R + dy) + R;
      for (int dx = -R; dx <= R; ++dx) {
        std::uint8_t const* q = row + dx;
        for (int x = 0; x < W; ++x) {
          std::uint8_t const a = c[x], b = q[x];
          std::uint8_t const diff = a > b ? a - b : b - a;
          std::uint8_t const m = diff <= d ? 0xFF : 0x00;  // branch-free
          s[x] = static_cast<std::uint16_t>(s[x] + (b & m));
          k[x] = static_cast<std::uint8_t>(k[x] + (m & 1));
        }
      }
    }
    std::uint8_t* o = dst.ptr<std::uint8_t>(y);
    for (int x = 0; x < W; ++x) o[x] = static_cast<std::uint8_t>((s[x] * inv[k[x]] + 32768u) >> 16);
  }
}

}  // namespace endo_guidance
