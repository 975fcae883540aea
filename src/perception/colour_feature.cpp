// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/colour_feature.h"

#include <algorithm>
#include <cmath>
#include <opencv2/core/hal/intrin.hpp>

namespace endo_guidance::perception {

ColourFeature::ColourFeature(ColourFeatureParams const& params) : params_(params), lut_(1u << 18) {
  for (int b = 0; b < 64; ++b)
    for (int g = 0; g < 64; ++g)
      for (int r = 0; r < 64; ++r) {
        // Centre of the quantisation bin.
        float const v = exact(b * 4 + 1.5f, g * 4 + 1.5f, r * 4 + 1.5f);
        lut_[(b << 12) | (g << 6) | r] = static_cast<std::uint8_t>(std::lround(std::clamp(v, 0.0f, 255.0f)));
      }
}

float ColourFeature::exact(float b, float g, float r) const {
  float const mx = std::max(b, std::max(g, r)), mn = std::min(b, std::min(g, r));
  float const c = mx - mn;
  if (c <= 0.0f) return 0.0f;
  // Hue in degrees (HSV hexcone).
  float h;
  if (mx == r) h = 60.0f * std::fmod((g - b) / c + 6.0f, 6.0f);
  else if (mx == g) h = 60.0f * ((b - r) / c + 2.0f);
  else h = 60.0f * ((r - g) / c + 4.0f);
  float hs = std::fmod(h - static_cast<float>(params_.hue_origin_deg) + 720.0f, 360.0f);
  return static_cast<float>(params_.gain) * c * (hs / 180.0f);  // F = C * w(h)
}

namespace {

// The table's value for 8 pixels at the default hue origin (120 deg) and gain (1), from the
// 6-bit channels k = v >> 2 (u16 lanes): with C = max - min and the hexcone hue h,
//   C w(h) = C ((h - 120) mod 360) / 180 = S / 3,
//   S = 4C + g - b (max r), b - r (+ 6C if b < r) (max g), r - g + 2C (max b)
// in the channels' own units (no division by C). The table takes each bin's centre,
// 4k + 1.5: the offsets cancel, C and S scale by 4, and F = round(4 S_k / 3) =
// floor((4 S_k + 1) / 3) (4 S_k / 3 is never a half), the division being the exact
// (y * 21846) >> 16 for y < 1540.
inline cv::v_uint16x8 featureFromBins(cv::v_uint16x8 const& b, cv::v_uint16x8 const& g, cv::v_uint16x8 const& r) {
  using namespace cv;
  v_uint16x8 const mx = v_max(r, v_max(g, b)), mn = v_min(r, v_min(g, b)), c = mx - mn;
  v_uint16x8 const is_r = r == mx, is_g = (g == mx) & ~is_r;
  v_uint16x8 const s_r = (c << 2) + g - b;                                 // >= 3C: no wrap
  v_uint16x8 const s_g = v_select(b < r, b + (c << 2) + (c << 1) - r, b - r);  // >= 0 either way
  v_uint16x8 const s_b = r + (c << 1) - g;                                 // >= C
  v_uint16x8 const s = v_select(is_r, s_r, v_select(is_g, s_g, s_b));
  return v_mul_hi((s << 2) + v_setall_u16(1), v_setall_u16(21846));
}

}  // namespace

void ColourFeature::compute(cv::Mat const& bgr, cv::Mat& feature) const {
  CV_Assert(bgr.type() == CV_8UC3);
  feature.create(bgr.size(), CV_8U);
  std::uint8_t const* lut = lut_.data();
  // The default parameters: 16 pixels at a time with the table's exact values, no table loads.
  bool const simd = params_.hue_origin_deg == 120.0 && params_.gain == 1.0;
  for (int y = 0; y < bgr.rows; ++y) {
    std::uint8_t const* s = bgr.ptr<std::uint8_t>(y);
    std::uint8_t* d = feature.ptr<std::uint8_t>(y);
    int x = 0;
    if (simd)
      for (; x + 16 <= bgr.cols; x += 16, s += 48) {
        cv::v_uint8x16 b, g, r;
        cv::v_load_deinterleave(s, b, g, r);
        cv::v_uint16x8 b0, b1, g0, g1, r0, r1;
        cv::v_expand(b, b0, b1);
        cv::v_expand(g, g0, g1);
        cv::v_expand(r, r0, r1);
        cv::v_uint16x8 const f0 = featureFromBins(b0 >> 2, g0 >> 2, r0 >> 2), f1 = featureFromBins(b1 >> 2, g1 >> 2, r1 >> 2);
        cv::v_store(d + x, cv::v_pack(f0, f1));  // saturates at 255
      }
    for (; x < bgr.cols; ++x, s += 3)
      d[x] = lut[(static_cast<unsigned>(s[0] >> 2) << 12) | (static_cast<unsigned>(s[1] >> 2) << 6) | (s[2] >> 2)];
  }
}

}  // namespace endo_guidance::perception
