// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/sigma_filter.h"

#include <algorithm>
#include <cstdint>
#include <opencv2/core.hpp>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif
#if defined(__GNUC__) && defined(__x86_64__)
#include <immintrin.h>
#endif

namespace endo_guidance::perception {

namespace {

// The mean rounded half up, floor(sum / n + 1/2) = floor((2 sum + n) / (2 n)), as in the
// definition (n >= 1: the centre is always in).
inline std::uint8_t roundedMean(int sum, int n) { return static_cast<std::uint8_t>((2 * sum + n) / (2 * n)); }

// One output pixel from the padded rows (scalar: the tail of a row).
inline std::uint8_t filterPixel(std::uint8_t const* const* rows, int x, int R, int d) {
  int const c = rows[R][x];
  int sum = 0, n = 0;
  for (int dy = 0; dy <= 2 * R; ++dy)
    for (int dx = -R; dx <= R; ++dx) {
      int const q = rows[dy][x + dx];
      if (std::abs(q - c) <= d) {
        sum += q;
        ++n;
      }
    }
  return roundedMean(sum, n);
}

#if defined(__GNUC__) && defined(__x86_64__)
#define ENDO_GUIDANCE_AVX2_SIGMA 1
// The rounded means of 8 pixels (the low or high 16-bit half of each 128-bit half).
__attribute__((target("avx2"))) inline __m256i mean8(__m256i s16, __m256i n16, bool hi) {
  __m256i const zero = _mm256_setzero_si256();
  __m256i const s32 = hi ? _mm256_unpackhi_epi16(s16, zero) : _mm256_unpacklo_epi16(s16, zero);
  __m256i const n32 = hi ? _mm256_unpackhi_epi16(n16, zero) : _mm256_unpacklo_epi16(n16, zero);
  __m256 const num = _mm256_cvtepi32_ps(_mm256_add_epi32(_mm256_add_epi32(s32, s32), n32));
  __m256 const den = _mm256_cvtepi32_ps(_mm256_add_epi32(n32, n32));
  return _mm256_cvttps_epi32(_mm256_div_ps(num, den));
}

// The SSE2 loop below on 32 pixels at a time (AVX2, chosen at run time). AVX2's unpack and pack
// work within each 128-bit half, so the halves go through exactly the SSE2 steps side by side:
// the same integers, the same exact float division, the same output. Returns the first x not done.
__attribute__((target("avx2"))) int sigmaRowAvx2(std::uint8_t const* const* rows, std::uint8_t* o, int W, int R, int d) {
  __m256i const dv = _mm256_set1_epi8(static_cast<char>(d));
  __m256i const zero = _mm256_setzero_si256();
  int x = 0;
  for (; x + 32 <= W; x += 32) {
    __m256i const c = _mm256_loadu_si256(reinterpret_cast<__m256i const*>(rows[R] + x));
    __m256i slo = zero, shi = zero, cnt = zero;
    for (int dy = 0; dy <= 2 * R; ++dy)
      for (int dx = -R; dx <= R; ++dx) {
        __m256i const q = _mm256_loadu_si256(reinterpret_cast<__m256i const*>(rows[dy] + x + dx));
        __m256i const ad = _mm256_or_si256(_mm256_subs_epu8(c, q), _mm256_subs_epu8(q, c));
        __m256i const m = _mm256_cmpeq_epi8(_mm256_min_epu8(ad, dv), ad);
        __m256i const qm = _mm256_and_si256(q, m);
        slo = _mm256_add_epi16(slo, _mm256_unpacklo_epi8(qm, zero));
        shi = _mm256_add_epi16(shi, _mm256_unpackhi_epi8(qm, zero));
        cnt = _mm256_sub_epi8(cnt, m);
      }
    __m256i const nlo = _mm256_unpacklo_epi8(cnt, zero), nhi = _mm256_unpackhi_epi8(cnt, zero);
    __m256i const m0 = _mm256_packs_epi32(mean8(slo, nlo, false), mean8(slo, nlo, true));
    __m256i const m1 = _mm256_packs_epi32(mean8(shi, nhi, false), mean8(shi, nhi, true));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(o + x), _mm256_packus_epi16(m0, m1));
  }
  return x;
}
#endif

}  // namespace

void sigmaFilter(cv::Mat const& src, cv::Mat& dst, int radius, int delta) {
  CV_Assert(src.type() == CV_8U && radius >= 1 && radius <= 3 && delta >= 0);
  CV_Assert(src.data != dst.data);
  int const W = src.cols, H = src.rows, R = radius;
  cv::Mat pad;
  cv::copyMakeBorder(src, pad, R, R, R, R, cv::BORDER_REPLICATE);
  dst.create(src.size(), CV_8U);
  int const d = std::min(delta, 255);
  std::uint8_t const* rows[7];
#ifdef ENDO_GUIDANCE_AVX2_SIGMA
  bool const avx2 = cv::checkHardwareSupport(CV_CPU_AVX2);
#endif
  for (int y = 0; y < H; ++y) {
    for (int dy = 0; dy <= 2 * R; ++dy) rows[dy] = pad.ptr<std::uint8_t>(y + dy) + R;
    std::uint8_t* o = dst.ptr<std::uint8_t>(y);
    int x = 0;
#ifdef ENDO_GUIDANCE_AVX2_SIGMA
    if (avx2) x = sigmaRowAvx2(rows, o, W, R, d);
#endif
#if defined(__SSE2__)
    // 16 pixels at a time, the whole window in registers: per offset, |q - c| <= d selects q
    // into 16-bit sums and 1 into 8-bit counts (n <= 49); then the rounded mean in float,
    // which is exact here: 2 sum + n < 2^15, and a non-integer quotient is >= 1 / (2 n) from
    // the next integer, far above float's rounding error, so truncation gives the floor.
    __m128i const dv = _mm_set1_epi8(static_cast<char>(d));
    __m128i const zero = _mm_setzero_si128();
    for (; x + 16 <= W; x += 16) {
      __m128i const c = _mm_loadu_si128(reinterpret_cast<__m128i const*>(rows[R] + x));
      __m128i slo = zero, shi = zero, cnt = zero;
      for (int dy = 0; dy <= 2 * R; ++dy)
        for (int dx = -R; dx <= R; ++dx) {
          __m128i const q = _mm_loadu_si128(reinterpret_cast<__m128i const*>(rows[dy] + x + dx));
          __m128i const ad = _mm_or_si128(_mm_subs_epu8(c, q), _mm_subs_epu8(q, c));  // |c - q|
          __m128i const m = _mm_cmpeq_epi8(_mm_min_epu8(ad, dv), ad);                 // |c - q| <= d
          __m128i const qm = _mm_and_si128(q, m);
          slo = _mm_add_epi16(slo, _mm_unpacklo_epi8(qm, zero));
          shi = _mm_add_epi16(shi, _mm_unpackhi_epi8(qm, zero));
          cnt = _mm_sub_epi8(cnt, m);  // m = -1 where selected
        }
      __m128i const nlo = _mm_unpacklo_epi8(cnt, zero), nhi = _mm_unpackhi_epi8(cnt, zero);
      auto mean4 = [&](__m128i s16, __m128i n16, bool hi) {
        __m128i const s32 = hi ? _mm_unpackhi_epi16(s16, zero) : _mm_unpacklo_epi16(s16, zero);
        __m128i const n32 = hi ? _mm_unpackhi_epi16(n16, zero) : _mm_unpacklo_epi16(n16, zero);
        __m128 const num = _mm_cvtepi32_ps(_mm_add_epi32(_mm_add_epi32(s32, s32), n32));
        __m128 const den = _mm_cvtepi32_ps(_mm_add_epi32(n32, n32));
        return _mm_cvttps_epi32(_mm_div_ps(num, den));
      };
      __m128i const m0 = _mm_packs_epi32(mean4(slo, nlo, false), mean4(slo, nlo, true));
      __m128i const m1 = _mm_packs_epi32(mean4(shi, nhi, false), mean4(shi, nhi, true));
      _mm_storeu_si128(reinterpret_cast<__m128i*>(o + x), _mm_packus_epi16(m0, m1));
    }
#endif
    for (; x < W; ++x) o[x] = filterPixel(rows, x, R, d);
  }
}

}  // namespace endo_guidance::perception
