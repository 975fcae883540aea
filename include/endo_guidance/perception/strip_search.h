// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <array>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "endo_guidance/perception/contour_fit.h"
#include "endo_guidance/perception/field_of_view.h"
#include "endo_guidance/perception/region_growing.h"
#include "endo_guidance/perception/seed_search.h"

namespace endo_guidance::perception {

struct StripSearchParams {
  bool enabled = true;            ///< search seeds whose grown regions gave no shaft (a leaked region)
  double max_angle_deg = 75.0;    ///< sides searched within this angle of the inward normal at the seed
  double coarse_step_deg = 3.0;   ///< angular step of the first pass (then refined to step / 3, then step / 12)
  int start_slack_px = 2;         ///< border points: sides start on the seed's run or this far beyond its ends
  int extend_px = 40;             ///< border points: ... or this far beyond the end the shaft lies toward
  int track_px = 6;               ///< processing px: with last frame's strip, sides start this close to its sides
  int max_starts = 24;            ///< start points per side along the run (a long run is sampled)
  double full_response = 40.0;    ///< Sobel units (feature): an edge this steep counts fully
  double min_response = 0.35;     ///< fraction of full_response: a side continues while the edge is this strong on average
  double min_side_px = 20.0;      ///< processing px: shortest side kept
  double min_inside_low = 0.8;    ///< fraction of the strip between the sides that is shaft-like (at or below the level)
  double min_length_ratio = 0.5; ///< the shorter side over the longer (both contours end at the tip)
  double min_width_px = 5.0;     ///< processing px: narrowest strip at the entry
  double max_inside_outside_ratio = 0.5;  ///< the strip's median feature over the tissue's beside each side
  double min_end_width = 0.45;     ///< the strip's far width over its entry width (perspective narrows it; crossing sides do not)
  int candidates_per_side = 8;    ///< best side hypotheses paired
  double max_full_res_ratio = 0.5;  ///< stripContrastFullRes(): median edge channel inside over outside
  double max_full_res_ratio_matte = 0.9;  ///< ... the same for a strip with few highlights inside
  double max_specular_fraction = 0.05;    ///< ... "few": this fraction of the inside samples
  /// ... the tissue's level beside a line: this quantile of its samples. Not the median: a shaft
  /// beside a grey blob (gauze, another shaft, a metal sleeve) along half a side is still less
  /// chromatic than the tissue along the rest of that side; a pale fold's surroundings are pale
  /// throughout.
  double full_res_outside_quantile = 0.75;
  double max_refine_shift = 3.0;  ///< processing px: the sub-pixel lines stay this close to the strip's sides at both ends
  /// full-res px: a strip whose sub-pixel lines left it (stripAgrees()) is refined again with the
  /// wide pass's half-width (ContourLinesParams::coarse_halfwidth_px, 9 px) 1 px narrower at a
  /// time, down to this, until they stay on it (refineStrip(); 0: no retry): the wide pass may
  /// lock onto a steeper tissue edge beyond a weak shaft edge.
  double retry_min_halfwidth_px = 3.0;
};

/// One side hypothesis of the strip search: a ray from a border point into the view.
struct StripRay {
  Eigen::Vector2d start, dir, out;  ///< start (processing px), unit direction, unit outward normal (toward the tissue)
  double angle = 0.0;               ///< about the inward normal at the seed (rad)
  double score = -1.0;              ///< best prefix of sum(min(g.out / full_response, 1) - min_response) (walkRay())
  double length = 0.0;              ///< where that prefix ends (px)
  int pos = 0;                      ///< its start: border points from the seed run's first one
};
/// Walks the ray in the gradient (gx, gy: CV_16S) one pixel at a time and keeps the best prefix:
/// the side continues while the edge, on average, is at least min_response strong, and ends where
/// it stops (jaws, tip, or the start of a leak), where it leaves the image or (after its first
/// 4 px) the field of view, or 8 below its best. Sets score and length.
void walkRay(StripRay& ray, cv::Mat const& gx, cv::Mat const& gy, FieldOfView const& fov, StripSearchParams const& params);
/// The gradient and the field of view packed for the ray walks (one 32-bit load per step
/// instead of three): per pixel (2 gy + inside) << 16 | (gx & 0xffff), inside = 1 within the
/// field of view's mask. Built once per frame (packRayField()).
struct RayField {
  cv::Mat packed;  ///< CV_32S, continuous; empty: no field
};
/// gx, gy: CV_16S of the field of view's size, every |value| below 16384 (a 3x3 Sobel of 8-bit
/// data is within 1020); otherwise cv::Exception.
RayField packRayField(cv::Mat const& gx, cv::Mat const& gy, FieldOfView const& fov);
/// walkRay() for every ray, several at a time in SIMD lanes (eight with AVX2, else four): the
/// same results, bit for bit.
void walkRays(std::vector<StripRay>& rays, RayField const& field, StripSearchParams const& params);
/// The same, packing the field first (packRayField()).
void walkRays(std::vector<StripRay>& rays, cv::Mat const& gx, cv::Mat const& gy, FieldOfView const& fov,
              StripSearchParams const& params);

/// The sides of a shaft searched directly in the edge image from a border seed -- the fallback
/// when region growing from the seed leaks into tissue of the same colour (grey membranes, the
/// vignetted rim, smoke), which breaks the boundary's two classes. Each side starts at an end of
/// the seed's border run and is the ray (angle about the inward normal) along which the feature
/// gradient, signed from shaft to tissue, stays strong the longest: the best prefix of
/// sum(min(g.n / g_full, 1) - min_response). Sides are paired by parallelism (contours of a
/// cylinder meet at most max_angle apart), a shaft-like interior and no crossing. The result is
/// a SideFit for refineContour() (full-resolution sub-pixel lines) and the strip as its region.
/// `field`: packRayField() of the CV_16S Sobel of `feature` and of `fov` (the second form packs
/// it from `gx`, `gy`); `level`: feature value at or below which the interior is shaft-like.
/// `previous`: this shaft's strip in the last frame (video), searched about only.
struct StripCandidate {
  SideFit sides;
  Region region;
  double score = 0.0;
  std::array<Eigen::Vector2d, 2> start, dir;  ///< the two sides' rays (processing px)
};
std::optional<StripCandidate> searchStrip(cv::Mat const& feature, RayField const& field, FieldOfView const& fov, Seed const& seed,
                                          int level, int scale, StripSearchParams const& params, ContourLinesParams const& lines,
                                          StripCandidate const* previous = nullptr);
/// The same from the gradient (packRayField() first).
std::optional<StripCandidate> searchStrip(cv::Mat const& feature, cv::Mat const& gx, cv::Mat const& gy,
                                          FieldOfView const& fov, Seed const& seed, int level, int scale,
                                          StripSearchParams const& params, ContourLinesParams const& lines,
                                          StripCandidate const* previous = nullptr);

/// Whether the sub-pixel contour found from a strip stayed on the strip: each line within
/// max_refine_shift (processing px) of the side it was refined from, at both ends of that side.
/// The wide sub-pixel pass can otherwise lock onto a neighbouring tissue edge.
bool stripAgrees(StripCandidate const& strip, geometry::ApparentContour const& contour, int scale, StripSearchParams const& params);

/// The strip's sub-pixel contour (refineContour()) that stays on it (stripAgrees()): when the
/// wide pass locks onto a neighbouring edge (a tissue fold a few px beyond a weak shaft edge),
/// the strip is refined again with the wide pass narrowed (retry_min_halfwidth_px). Rejected as
/// kNotStraight when no pass stays on the strip.
ContourFit refineStrip(StripCandidate const& strip, FieldOfView const& fov, cv::Mat const& bgr, int scale,
                       StripSearchParams const& params, ContourLinesParams const& lines);

/// Whether the shaft between the contour's lines is, on the full-resolution image, clearly less
/// chromatic than the tissue beside each line: median chroma inside <= max_full_res_ratio x the
/// full_res_outside_quantile of the samples a third of a width outside (sides beyond the image
/// are not tested), or
/// <= max_full_res_ratio_matte x when fewer than max_specular_fraction of the inside samples are
/// highlights (near white). At the processing scale a band of specular speckles on wet tissue
/// (white dots between red pixels) averages to a grey strip; at full resolution most of it is
/// tissue and many of its samples are white. Metal mirroring the tissue is weakly contrasted but
/// matte.
/// Samples of edgeChannel() (acrossContour()).
bool stripContrastFullRes(cv::Mat const& bgr, geometry::ApparentContour const& contour, StripSearchParams const& params);
/// The same from samples already taken (acrossContour()).
bool stripContrastFullRes(AcrossSamples samples, StripSearchParams const& params);

}  // namespace endo_guidance::perception
