// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/core/colour_feature.h"

#include <algorithm>
#include <cmath>

namespace endo_guidance::core {

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

void ColourFeature::compute(cv::Mat const& bgr, cv::Mat& feature) const {
  CV_Assert(bgr.type() == CV_8UC3);
  feature.create(bgr.size(), CV_8U);
  std::uint8_t const* lut = lut_.data();
  for (int y = 0; y < bgr.rows; ++y) {
    std::uint8_t const* s = bgr.ptr<std::uint8_t>(y);
    std::uint8_t* d = feature.ptr<std::uint8_t>(y);
    for (int x = 0; x < bgr.cols; ++x, s += 3)
      d[x] = lut[(static_cast<unsigned>(s[0] >> 2) << 12) | (static_cast<unsigned>(s[1] >> 2) << 6) | (s[2] >> 2)];
  }
}

}  // namespace endo_guidance::core
