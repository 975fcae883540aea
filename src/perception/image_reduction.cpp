// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/image_reduction.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cstdint>
#include <vector>
#if defined(__GNUC__) && defined(__x86_64__)
#include <immintrin.h>
#endif

namespace endo_guidance::perception {

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

#if defined(__GNUC__) && defined(__x86_64__)
#define ENDO_GUIDANCE_AVX2_HALVING 1
// The halving of output pixels x..W-1 of one row (the SIMD loop's tail), (a + b + c + d + 2) >> 2
// per channel, from input rows r0, r1.
void halveRow(std::uint8_t const* r0, std::uint8_t const* r1, std::uint8_t* out, int x, int W) {
  for (; x < W; ++x)
    for (int ch = 0; ch < 3; ++ch) {
      int const i = 6 * x + ch;
      out[3 * x + ch] = static_cast<std::uint8_t>((r0[i] + r0[i + 3] + r1[i] + r1[i + 3] + 2) >> 2);
    }
}

// One row's horizontal pair sums of 4 chunks (12 input bytes, 6 output bytes each) from r, in
// lanes a = (chunk 0, chunk 2), b = (chunk 1, chunk 3): packed, the lanes then hold chunks 0, 1
// and 2, 3 in order.
__attribute__((target("avx2"))) inline void pairSums(std::uint8_t const* r, __m256i pairs, __m256i ones, __m256i& a, __m256i& b) {
  auto const at = [r](int i) { return reinterpret_cast<__m128i const*>(r + i); };
  a = _mm256_maddubs_epi16(_mm256_shuffle_epi8(_mm256_loadu2_m128i(at(24), at(0)), pairs), ones);
  b = _mm256_maddubs_epi16(_mm256_shuffle_epi8(_mm256_loadu2_m128i(at(36), at(12)), pairs), ones);
}
// Each 128-bit lane takes 12 bytes (4 pixels, 2 output pixels) of a row: pshufb puts each
// channel's horizontal pair side by side, maddubs adds the pairs in 16 bits (<= 510), the two
// rows are added, +2 >> 2, packed. 8 output pixels per step from 4 lanes; every load and store
// is 16 bytes, 4 past the bytes used, so the loop stops 10 output pixels before the row's end
// and the scalar row finishes it. Exact: the same integer sums as cv::resize's INTER_AREA path.
__attribute__((target("avx2"))) void halveAvx2(cv::Mat const& src, cv::Mat& dst) {
  int const W = dst.cols;
  __m256i const pairs = _mm256_broadcastsi128_si256(_mm_setr_epi8(0, 3, 1, 4, 2, 5, 6, 9, 7, 10, 8, 11, -1, -1, -1, -1));
  __m256i const ones = _mm256_set1_epi8(1), two = _mm256_set1_epi16(2);
  __m256i const compact = _mm256_broadcastsi128_si256(_mm_setr_epi8(0, 1, 2, 3, 4, 5, 8, 9, 10, 11, 12, 13, -1, -1, -1, -1));
  for (int y = 0; y < dst.rows; ++y) {
    std::uint8_t const* r0 = src.ptr<std::uint8_t>(2 * y);
    std::uint8_t const* r1 = src.ptr<std::uint8_t>(2 * y + 1);
    std::uint8_t* out = dst.ptr<std::uint8_t>(y);
    int x = 0;
    for (; x + 10 <= W; x += 8) {
      __m256i a0, b0, a1, b1;
      pairSums(r0 + 6 * x, pairs, ones, a0, b0);
      pairSums(r1 + 6 * x, pairs, ones, a1, b1);
      __m256i const a = _mm256_srli_epi16(_mm256_add_epi16(_mm256_add_epi16(a0, a1), two), 2);
      __m256i const b = _mm256_srli_epi16(_mm256_add_epi16(_mm256_add_epi16(b0, b1), two), 2);
      __m256i const v = _mm256_shuffle_epi8(_mm256_packus_epi16(a, b), compact);
      _mm_storeu_si128(reinterpret_cast<__m128i*>(out + 3 * x), _mm256_castsi256_si128(v));
      _mm_storeu_si128(reinterpret_cast<__m128i*>(out + 3 * x + 12), _mm256_extracti128_si256(v, 1));
    }
    halveRow(r0, r1, out, x, W);
  }
}
#endif

}  // namespace

void reduceImage(cv::Mat const& source, int f, cv::Mat& dst) {
  CV_Assert(source.type() == CV_8UC3 && f >= 1 && f <= 255);  // (16-bit row sums)
  CV_Assert(f <= source.rows && f <= source.cols);            // (an empty result otherwise)
  cv::Mat const src = source;  // (a reference to the data, kept should dst be the same Mat: in place)
  if (f == 1) dst = src;
  // Halving, (a + b + c + d + 2) >> 2: with AVX2 (chosen at run time), pairs side by side by
  // pshufb, 4-5x faster than OpenCV's area resampling (scalar for 3 channels: 115-190 us at
  // 640x480, 12 % of the pipeline); otherwise that resampling on an even-sized view. (A
  // universal-intrinsics version without SSSE3 measured slower than OpenCV's: de-interleaving BGR
  // costs more than it saves.)
#ifdef ENDO_GUIDANCE_AVX2_HALVING
  else if (f == 2 && cv::checkHardwareSupport(CV_CPU_AVX2)) {
    dst.create(src.rows / 2, src.cols / 2, CV_8UC3);
    halveAvx2(src, dst);
  }
#endif
  else if (f == 2) cv::resize(src(cv::Rect(0, 0, src.cols / 2 * 2, src.rows / 2 * 2)), dst, cv::Size(src.cols / 2, src.rows / 2), 0, 0, cv::INTER_AREA);
  else if (f == 3) boxMeans<3>(src, f, dst);
  else if (f == 4) boxMeans<4>(src, f, dst);
  else if (f == 5) boxMeans<5>(src, f, dst);
  else if (f == 6) boxMeans<6>(src, f, dst);  // 1920x1080 at the default processing width
  else if (f == 8) boxMeans<8>(src, f, dst);
  else boxMeans<0>(src, f, dst);
}

}  // namespace endo_guidance::perception
