// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"
#include "endo_guidance/perception/colour_feature.h"
#include "endo_guidance/perception/contour_params.h"
#include "endo_guidance/perception/line_fit.h"

namespace endo_guidance::perception {

/// The bilinear B, G, R of `bgr` (CV_8UC3) at (x, y), which must lie in [0, cols - 1) x [0, rows - 1).
inline void bilinearAt(cv::Mat const& bgr, double x, double y, float (&c)[3]) {
  int const x0 = static_cast<int>(x), y0 = static_cast<int>(y);
  float const fx = static_cast<float>(x - x0), fy = static_cast<float>(y - y0);
  std::uint8_t const* p0 = bgr.ptr<std::uint8_t>(y0) + 3 * x0;
  std::uint8_t const* p1 = bgr.ptr<std::uint8_t>(y0 + 1) + 3 * x0;
  for (int k = 0; k < 3; ++k)
    c[k] = (1 - fy) * ((1 - fx) * p0[k] + fx * p0[k + 3]) + fy * ((1 - fx) * p1[k] + fx * p1[k + 3]);
}

/// The channel in which the contour lines are located with sub-pixel precision (steepest descent
/// from tissue into the shaft): the chroma max - min, which separates grey and black shafts from
/// saturated tissue.
inline float edgeChannel(float b, float g, float r) { return ColourFeature::chroma(b, g, r); }

/// The edge channel at a + i d, i = 0..count-1, bilinear, every sample inside the image: the
/// profiles' sampler, eight samples per step with AVX2 (chosen at run time, with OpenCV's
/// optimisations on), else one per SSE2 step; identical to edgeChannel() of the bilinear colour,
/// which `reference` computes one sample at a time.
void sampleEdgeChannel(cv::Mat const& bgr, Eigen::Vector2d const& a, Eigen::Vector2d const& d, int count, float* out,
                       bool reference = false);

/// A side's edge channel other than edgeChannel(): the projection of the BGR colour on a unit
/// direction, the one from the shaft's colour to the tissue's across that side (sideColourDirection()).
/// Where shaft and tissue are equally chromatic (grey fat, membrane, a black shaft in shadow) the
/// chroma has no edge, but the colours still differ along this direction. nullptr: edgeChannel().
using ColourDirection = Eigen::Vector3f;
/// The unit BGR direction from the shaft's colour to the tissue's beside side `line` (full-res px,
/// positive side = shaft) over [t0, t1] along it: the difference of the per-channel medians at
/// `inside_px` in and `outside_px` out, every 2 px; nullopt when fewer than 3 samples lie in the
/// image or the two colours are the same.
std::optional<ColourDirection> sideColourDirection(cv::Mat const& bgr, geometry::ImageLine const& line, double t0, double t1,
                                                   double inside_px, double outside_px);

/// The edges found on the profiles across `line` at t0 + j step along it (nullopt: no edge on
/// that profile), with the parameters of widePass().
struct ProfileEdges {
  geometry::ImageLine line = geometry::ImageLine::Zero();
  double t0 = 0.0, step = 0.0;
  std::vector<std::optional<Eigen::Vector2d>> edges;
};
/// The sub-pixel API: the edge points of a shaft side on profiles across `line` (full-res px,
/// positive side = shaft) every refine_step_px for t in [t0, t1] along its direction (-b, a),
/// each at the steepest descent of edgeChannel() (or of the colour along `direction`) from tissue
/// into the shaft (the centroid of the slope's lobe), then a robust least-squares line (Tukey
/// biweight) with its covariance.
std::optional<RefinedLine> refineLineSubpixel(cv::Mat const& bgr, geometry::ImageLine const& line, double t0, double t1,
                                              ContourLinesParams const& params, ColourDirection const* direction = nullptr);
/// The parameters of the first, wide sub-pixel pass (coarse_halfwidth_px, profiles sampled at
/// twice profile_step_px), which recentres a line before the narrow pass.
ContourLinesParams widePass(ContourLinesParams const& params);

/// refineLineSubpixel() taking the profiles of `reuse` where line and t0 are the same (its step a
/// multiple of refine_step_px; edgeChannel()'s, so not with a `direction`), and keeping every
/// profile's edge in `record`.
std::optional<RefinedLine> refineLineProfiles(cv::Mat const& bgr, geometry::ImageLine const& line, double t0, double t1,
                                              ContourLinesParams const& params, ProfileEdges const* reuse, ProfileEdges* record,
                                              ColourDirection const* direction = nullptr);
/// A refined line (over [t0, t1] along its direction (-b, a)) followed beyond that extent, within
/// [t_lo, t_hi]: one narrow profile every refine_step_px, kept while its edge lies on the line
/// (within max(3 residuals, extend_gate_px)), until extend_max_misses profiles in a row miss;
/// past a gap of more than 3 profiles, the edge counts again only once 4 profiles in a row hold
/// it. The line refitted over all its points, refitted every 16 new ones on the way. nullopt:
/// nothing added, or the extension made the residual worse (another edge).
std::optional<RefinedLine> extendLineSubpixel(cv::Mat const& bgr, RefinedLine const& refined, double t0, double t1,
                                              double t_lo, double t_hi, ContourLinesParams const& params,
                                              ColourDirection const* direction = nullptr);

}  // namespace endo_guidance::perception
