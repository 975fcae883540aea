// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

namespace endo_guidance::perception {

/// Parameters of the hue-saturation feature.
struct ColourFeatureParams {
  /// Hue origin (degrees, 0 = red, 120 = green): hues just above it map to low values. Tissue
  /// is red to yellow (hue 330..60 deg); with the origin at green (120 deg) tissue lands on
  /// 1.2..1.7 of the weight range [0, 2) and never low.
  double hue_origin_deg = 120.0;
  /// Output scale: F = gain * C * w(h), clipped to 255.
  double gain = 1.0;
};

/// The joint hue-saturation feature of [Doignon07] Sec. 3, low on grey metal and black shafts:
/// \f[ \mathcal{H} = S_c \cdot w(h),\qquad S_c = \max(R,G,B) - \min(R,G,B),\qquad
///     w(h) = \frac{(h - h_0) \bmod 360}{180} \in [0, 2) \f]
/// The saturation is measured as HSV chroma (S*V) rather than S = C/V: on dark pixels (black
/// insulated shafts, vignetting) S = C/V is noise and often high, the chroma is low (per-pixel
/// AUCs: docs/accuracy.md). Specular highlights (white: C ~ 0) are low too; they are rejected
/// later by shape, not colour.
class ColourFeature {
 public:
  explicit ColourFeature(ColourFeatureParams const& params = {});
  /// BGR (CV_8UC3) -> feature (CV_8U), through a 6-bit-per-channel lookup table (one load per pixel).
  void compute(cv::Mat const& bgr, cv::Mat& feature) const;
  /// The exact, continuous feature of one colour (0..255 per channel, any real values).
  float exact(float b, float g, float r) const;
  /// Chroma only (max - min): the continuous channel used to locate edges with sub-pixel precision.
  static float chroma(float b, float g, float r) {
    float const mx = std::max(b, std::max(g, r)), mn = std::min(b, std::min(g, r));
    return mx - mn;
  }
  ColourFeatureParams const& params() const { return params_; }

 private:
  ColourFeatureParams params_;
  std::vector<std::uint8_t> lut_;  // 2^18 entries: (b>>2)<<12 | (g>>2)<<6 | (r>>2)
};

}  // namespace endo_guidance::perception
