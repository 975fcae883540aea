// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/core/sigma_filter.h"

#include <algorithm>
#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace endo_guidance::core {

namespace {

// One window offset over a row: where |q - c| <= d, add q to the 16-bit sum and 1 to the count.
void accumulate(std::uint8_t const* __restrict c, std::uint8_t const* __restrict q, std::uint16_t* __restrict s,
                std::uint8_t* __restrict k, int W, std::uint8_t d) {
  int x = 0;
#if defined(__SSE2__)
  __m128i const dv = _mm_set1_epi8(static_cast<char>(d));
  __m128i const one = _mm_set1_epi8(1);
  __m128i const zero = _mm_setzero_si128();
  for (; x + 16 <= W; x += 16) {
    __m128i const a = _mm_loadu_si128(reinterpret_cast<__m128i const*>(c + x));
    __m128i const b = _mm_loadu_si128(reinterpret_cast<__m128i const*>(q + x));
    __m128i const ad = _mm_or_si128(_mm_subs_epu8(a, b), _mm_subs_epu8(b, a));  // |a - b|
    __m128i const m = _mm_cmpeq_epi8(_mm_min_epu8(ad, dv), ad);                 // |a - b| <= d
    __m128i const bm = _mm_and_si128(b, m);
    __m128i* sp = reinterpret_cast<__m128i*>(s + x);
    _mm_storeu_si128(sp, _mm_add_epi16(_mm_loadu_si128(sp), _mm_unpacklo_epi8(bm, zero)));
    _mm_storeu_si128(sp + 1, _mm_add_epi16(_mm_loadu_si128(sp + 1), _mm_unpackhi_epi8(bm, zero)));
    __m128i* kp = reinterpret_cast<__m128i*>(k + x);
    _mm_storeu_si128(kp, _mm_add_epi8(_mm_loadu_si128(kp), _mm_and_si128(m, one)));
  }
#endif
  for (; x < W; ++x) {
    std::uint8_t const a = c[x], b = q[x];
    std::uint8_t const ad = a > b ? a - b : b - a;
    if (ad <= d) {
      s[x] = static_cast<std::uint16_t>(s[x] + b);
      ++k[x];
    }
  }
}

}  // namespace

void sigmaFilter(cv::Mat const& src, cv::Mat& dst, int radius, int delta) {
  CV_Assert(src.type() == CV_8U && radius >= 1 && radius <= 3 && delta >= 0);
  CV_Assert(src.data != dst.data);
  int const W = src.cols, H = src.rows, R = radius;
  cv::Mat pad;
  cv::copyMakeBorder(src, pad, R, R, R, R, cv::BORDER_REPLICATE);
  dst.create(src.size(), CV_8U);
  int const n = (2 * R + 1) * (2 * R + 1);  // <= 49: counts fit in 8 bits, sums in 16
  // Reciprocals in 16.16 fixed point: mean = (sum * inv[cnt] + 2^15) >> 16 (cnt >= 1: the centre).
  std::vector<std::uint32_t> inv(static_cast<std::size_t>(n) + 1, 0);
  for (int c = 1; c <= n; ++c) inv[c] = static_cast<std::uint32_t>((65536u + c / 2) / c);
  std::vector<std::uint16_t> sum(static_cast<std::size_t>(W));
  std::vector<std::uint8_t> cnt(static_cast<std::size_t>(W));
  std::uint8_t const d = static_cast<std::uint8_t>(std::min(delta, 255));
  for (int y = 0; y < H; ++y) {
    std::uint8_t const* c = pad.ptr<std::uint8_t>(y + R) + R;
    std::fill(sum.begin(), sum.end(), 0);
    std::fill(cnt.begin(), cnt.end(), 0);
    for (int dy = -R; dy <= R; ++dy) {
      std::uint8_t const* row = pad.ptr<std::uint8_t>(y + R + dy) + R;
      for (int dx = -R; dx <= R; ++dx) accumulate(c, row + dx, sum.data(), cnt.data(), W, d);
    }
    std::uint8_t* o = dst.ptr<std::uint8_t>(y);
    for (int x = 0; x < W; ++x) o[x] = static_cast<std::uint8_t>((sum[x] * inv[cnt[x]] + 32768u) >> 16);
  }
}

}  // namespace endo_guidance::core
