// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstdint>
#include <opencv2/core.hpp>
#include <functional>
#include <memory>
#include <optional>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"
#include "endo_guidance/perception/colour_feature.h"
#include "endo_guidance/perception/field_of_view.h"
#include "endo_guidance/perception/region_growing.h"

namespace endo_guidance::perception {

/// Scale of the red-green opponent term of edgeChannel(): pure red keeps the feature's weight
/// (w(0 deg) = 4/3, colour_feature.h).
constexpr float kRedGreenScale = 4.0f / 3.0f;
/// The channel in which the contour lines are located with sub-pixel precision (steepest descent
/// from tissue into the shaft): E = (1 - w) (max - min) + w k (R - G), k = kRedGreenScale.
/// The chroma max - min separates grey and black shafts from any saturated tissue, but it is
/// rectified -- noise raises it where it is low, on the shaft side of the edge, and moves the
/// edge outward -- and it is as high on metal that mirrors yellow fat as on the fat. The
/// red-green opponent term is linear in the colour (noise averages out) and is high on
/// haemoglobin-red and pink tissue only: metal reflecting fat, a yellow light or a hazy scene
/// stays near zero. Per pixel, shaft mask against the tissue around it on the 80 in-vivo
/// EndoVis'15 stills: AUC 0.93 / 0.78 (chroma; images where a shaft was found / missed),
/// 0.95 / 0.87 (R - G).
inline float edgeChannel(float b, float g, float r, float w) {
  return (1.f - w) * ColourFeature::chroma(b, g, r) + (w * kRedGreenScale) * (r - g);
}

struct ContourLinesParams {
  int border_margin = 2;          ///< processing px: boundary points this close to the FOV edge are the entry
  int min_side_points = 10;       ///< boundary points per side (processing px)
  double min_inlier_fraction = 0.5;  ///< LMedS inliers per side: fewer and the side is not a straight line
  double max_angle_deg = 20.0;    ///< between the two contour lines
  double min_length_px = 30.0;    ///< full-res: entry to tip
  double min_width_px = 8.0;      ///< full-res: shaft width at entry and tip (3 -> 8: robotic DS2 false 0.11 -> 0.05 per frame)
  int lmeds_samples = 30;         ///< random pairs per side (P(no clean pair) < 1e-3 at 20 % outliers)
  int max_gap_points = 6;         ///< a side ends after this many consecutive boundary points off its line
  double refine_step_px = 2.0;    ///< full-res: spacing of the edge profiles along a line (every
                                  ///< profile counts on real images: capping them at 128 per line cost
                                  ///< 2.5 % robotic recall and 0.1 px in-vivo)
  double refine_halfwidth_px = 3.5;  ///< full-res: half length of each profile across the line (final pass)
  double coarse_halfwidth_px = 9.0;  ///< full-res: the same for the first, wide pass
  double profile_step_px = 0.5;   ///< full-res: sampling along each profile (the wide pass uses 2x)
  double score_step_px = 6.0;     ///< full-res: profile spacing when scoring candidate regions
  double min_edge_contrast = 2.5; ///< edgeChannel() units per px: weaker profiles carry no edge
  double edge_lobe_floor = 0.05;  ///< final pass: an edge is the centroid of its slope's lobe down to this fraction
                                  ///< of the peak (within +-2.5 px), not of every descent in the window
                                  ///< (< 0: the window; the wide pass always takes the window)
  double edge_red_green_weight = 0.0;  ///< w of edgeChannel(): 0 locates the edges in the chroma alone (opt-in: docs/known-limits.md)
  double brightness_fallback_contrast = 0.0;  ///< grey levels per px: a profile without a chroma edge
                                              ///< takes a brightness drop this steep (0: never; opt-in:
                                              ///< 8 finds 1 more in-vivo shaft and 1 more false one,
                                              ///< robotic Dataset 2 -1 shaft: docs/known-limits.md)
  int min_edge_points = 8;        ///< sub-pixel edge points per line
  int extend_max_misses = 40;     ///< a refined line is followed beyond its region side until this many
                                  ///< profiles in a row give no edge on it (40: 80 px of occlusion, an
                                  ///< instrument's tip across the shaft, are crossed; beyond a gap of more
                                  ///< than 3 profiles 4 in a row must confirm the edge. Hard scene, from
                                  ///< 10 without confirmation: line p95 0.463 -> 0.403 px, direction 0.84 ->
                                  ///< 0.76 deg; 30 without confirmation: in-vivo lines 2.31 -> 2.39 px, one
                                  ///< shaft's lines jumped to another edge (3.0 -> 23 px); 0: not followed)
  double extend_gate_px = 0.75;   ///< ... "on it": within max(3 residuals, this)
  double line_sigma_floor_px = 0.25;  ///< px: systematic error at each end of a line, added to the covariance
                                      ///< the residuals give. They miss the errors common to the edge points
                                      ///< (compression, shading): on the rendered scenes the axes' distances to
                                      ///< their trocar were 2-4x their predicted sigma, and their weights in the
                                      ///< trocar estimate mis-ranked (0 -> 0.25: trocars 0.22 -> 0.04 mm clean,
                                      ///< 2.70 -> 1.36 mm for the best-seen one of the hard scene)
  double max_residual_px = 3.0;   ///< RMS of the sub-pixel edge points to their line
  double min_elongation = 2.0;    ///< length (entry to tip) over mean width
  double max_widening = 2.0;      ///< width at the tip over width at the entry: a shaft pointing toward the
                                  ///< camera widens toward its tip, but not this much (real data: at most
                                  ///< 1.75 among the shafts found; 2.0 took robotic Dataset 2's false
                                  ///< shafts from 0.32 to 0.07 per frame, dark wedges in a corner)
  double min_entry_sine = 0.1;    ///< sine of the angle between the shaft and the FOV border where its axis
                                  ///< leaves the view (0.2 refused shafts lying along the border: 2 of the
                                  ///< 98 in-vivo ones, 1.5 % of the rendered ones; 0.1 added one false shaft)
  double min_parallel_side_ratio = 0.5;  ///< a side that is not a straight line from the entry (a shaft
                                  ///< merged with a grey blob there: gauze) may be the straight stretch of
                                  ///< its chain parallel to the other side, at least this long relative to
                                  ///< it and beside it over this fraction of its own length (0: never;
                                  ///< hard scene 79.7 -> 86.1 % found, its left trocar 3.0 -> 1.4 mm)
  double min_fill = 0.45;         ///< fraction of the strip between the lines covered by the region
  double min_inside = 0.6;        ///< fraction of the region inside that strip (near it)
  double min_inside_merged = 0.3; ///< the same for a region that meets the FOV border more than once
  double max_glare_fraction = 0.5;  ///< of the samples between the lines (full resolution, acrossContour()):
                                    ///< more glare (near white, achromatic) and it is a reflection on wet
                                    ///< tissue, not a shaft (in-vivo: 0.69-0.94 on the 3 false shafts of a
                                    ///< glare patch, at most 0.22 on the shafts found; false 0.100 -> 0.062 per image)
  std::uint64_t seed = 7;
};

enum class ContourRejection {
  kNone = 0, kTooFewPoints, kNotStraight, kNotParallel, kTooShort, kTooThin, kCrossing, kWeakEdges, kResidual,
  kNotElongated, kNotFilled, kAlongBorder, kLowContrast, kWidthJump, kDuplicate, kWidens, kGlare, kTipOnBorder,
  kNotContinued
};
char const* toString(ContourRejection r);

/// Full-resolution colour samples across a contour, at 39 stations evenly spaced from its entry
/// to its tip: three between the lines (at 1/4, 1/2 and 3/4 of the width) and one beside each
/// line, a third of the width (at least 3 px) outside it. Samples off the image are left out.
/// The samples are of edgeChannel() with the red-green weight given (the contour's own
/// ContourLinesParams::edge_red_green_weight; 0: the chroma max - min).
struct AcrossSamples {
  std::vector<float> inside;                  ///< edgeChannel() between the lines
  std::array<std::vector<float>, 2> outside;  ///< ... beside lines[0] and lines[1]
  int glare = 0;  ///< inside samples that are glare: near white (max channel >= 230) and achromatic (chroma < 30)
};
AcrossSamples acrossContour(cv::Mat const& bgr, geometry::ApparentContour const& contour, float red_green_weight);

/// Whether the contour is mostly glare between its lines (AcrossSamples::glare over the inside
/// samples > max_glare_fraction): a specular reflection on wet tissue, which the S.H feature
/// sees as low as metal, not a shaft. A shaft's highlights are streaks along it.
bool mostlyGlare(cv::Mat const& bgr, geometry::ApparentContour const& contour, ContourLinesParams const& params);
/// The same from samples already taken (acrossContour()).
bool mostlyGlare(AcrossSamples const& samples, ContourLinesParams const& params);

/// A line fitted robustly to points: least median of squares over random pairs, then least squares
/// on the inliers ([Rousseeuw87]). `line` is normalised (a^2 + b^2 = 1), orientation arbitrary.
struct RobustLine {
  Eigen::Vector3d line = Eigen::Vector3d::Zero();
  std::vector<int> inliers;
  double sigma = 0.0;  ///< robust scale of the residuals
};
std::optional<RobustLine> fitLineLMedS(std::vector<Eigen::Vector2d> const& pts, int samples, std::uint64_t seed);

/// Sub-pixel edge points of a shaft side: profiles across `line` (full-res pixels, positive side
/// = shaft) every step px between parameters t0..t1 (along the line direction (-b, a)), located at
/// the steepest descent of the chroma from tissue to shaft (parabolic peak), then a robust
/// least-squares line (Tukey reweighting) with its covariance and RMS residual.
struct RefinedLine {
  geometry::ImageLine line = geometry::ImageLine::Zero();
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();
  double residual_px = 0.0;
  int points = 0;
  std::vector<Eigen::Vector2d> inliers;  ///< the edge points behind the line (full-res pixels)
};
std::optional<RefinedLine> refineLineSubpixel(cv::Mat const& bgr, geometry::ImageLine const& line, double t0, double t1,
                                              ContourLinesParams const& params);
/// The parameters of the first, wide sub-pixel pass (coarse_halfwidth_px, profiles sampled at
/// twice profile_step_px), which recentres a line before the narrow pass.
ContourLinesParams widePass(ContourLinesParams const& params);

/// [Doignon07] Sec. 3: the ordered region boundary is split in two classes at the boundary point
/// farthest from the seed (points on the FOV border excluded), a line is fitted to each class
/// (LMedS, then sub-pixel on the full-resolution image), and the region is rejected unless its
/// boundary is two straight, near-parallel lines around a shaft of some length and width.
/// `scale` maps processing pixels to full-resolution ones (p_full = scale p + (scale - 1) / 2).
struct ContourFit {
  std::optional<geometry::ApparentContour> contour;
  ContourRejection rejection = ContourRejection::kNone;
  int edge_points = 0;  ///< sub-pixel edge points behind both lines
  std::array<std::vector<Eigen::Vector2d>, 2> edges;  ///< those points, per contour line (contour order)
};
ContourFit fitApparentContour(Region const& region, FieldOfView const& fov, cv::Mat const& bgr_full, int scale,
                              ContourLinesParams const& params);

/// The edges found on the profiles across `line` at t0 + j step along it (nullopt: no edge on
/// that profile), with the parameters of widePass().
struct ProfileEdges {
  geometry::ImageLine line = geometry::ImageLine::Zero();
  double t0 = 0.0, step = 0.0;
  std::vector<std::optional<Eigen::Vector2d>> edges;
};
struct SideChains;  // what every side search of a region shares (contour_lines.cpp)
/// The first, cheap half of fitApparentContour(): two-class split and LMedS per side (no image
/// access). Lines and inlier points in full-resolution pixels, lines oriented toward the shaft.
struct SideFit {
  std::array<Eigen::Vector3d, 2> lines{Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
  std::array<std::vector<Eigen::Vector2d>, 2> points;
  Eigen::Vector2d entry = Eigen::Vector2d::Zero(), far = Eigen::Vector2d::Zero();
  int inliers = 0;  ///< LMedS inliers over both sides: the quality of the straight-line pair
  bool merged = false;  ///< the region meets the FOV border more than once (instruments merged)
  bool parallel = false;  ///< a side was not straight from the entry and was found as the stretch parallel to the other
  ContourRejection rejection = ContourRejection::kNone;
  /// Set by scoreSides(): its wide profiles of each side, which refineContour()'s wide pass (the
  /// same profiles, denser) reuses where line and start are still the same.
  std::array<ProfileEdges, 2> scored;
  /// Set by fitSides(): the part of the search that the other searches of the same region share
  /// (fitSidesEach() reuses it).
  std::shared_ptr<SideChains const> chains;
};
/// How fitSides() seeks the two sides. kFromEntry: each followed from the entry; a side that is
/// not straight from there (a grey blob merged with the shaft near its entry: gauze) is sought as
/// the stretch of its chain parallel to the other. The others re-seek the sides of a region whose
/// side pair had no edge in the image (the shaft's boundary with a blob of the same feature level
/// has none; its boundary with the tissue beyond the blob has): kParallelFirst / kParallelSecond,
/// that side (boundary-chain order) only as the parallel stretch, even when straight from the
/// entry; kStretchPair, both as the best facing pair of straight stretches of the whole boundary,
/// on every piece of it between its stretches on the FOV border (a blob on both sides of the
/// shaft, or reaching the border; another instrument joined at the tip). Where the region meets the border
/// more than once, the re-sought side may lie on the other chain beyond the other side's end.
enum class SideSearch { kFromEntry, kParallelFirst, kParallelSecond, kStretchPair };
SideFit fitSides(Region const& region, FieldOfView const& fov, int scale, ContourLinesParams const& params,
                 SideSearch search = SideSearch::kFromEntry);
/// fitSides() with each of `searches` on one region (a fit per search, in order), the part they
/// share done once: the boundary's points on the view's border, the two chains from the entry
/// and the sides followed from it (the costliest part of a search: LMedS along each chain).
/// `fitted`: a fitSides() result of the same region, view and parameters, whose shared part is
/// taken instead of computed again (a region re-sought after its first search failed).
std::vector<SideFit> fitSidesEach(Region const& region, FieldOfView const& fov, int scale, ContourLinesParams const& params,
                                  std::vector<SideSearch> const& searches, SideFit const* fitted = nullptr);
/// Sets fit.far to the side point farthest from fit.entry.
void setFarEnd(SideFit& fit);
/// Cheap quality of a side pair for choosing between candidate regions: one wide, sparse edge
/// pass per side; (edge points) / (1 + RMS residual), or -1 when a side has no edge.
double scoreSides(SideFit& sides, cv::Mat const& bgr_full, ContourLinesParams const& params);
/// The second half: sub-pixel lines, order, tip and the length/width checks.
ContourFit refineContour(SideFit const& sides, Region const& region, FieldOfView const& fov, cv::Mat const& bgr_full,
                         int scale, ContourLinesParams const& params);

/// A refined line (over [t0, t1] along its direction (-b, a)) followed beyond that extent, within
/// [t_lo, t_hi]: one narrow profile every refine_step_px, kept while its edge lies on the line
/// (within max(3 residuals, extend_gate_px)), until extend_max_misses profiles in a row miss;
/// past a gap of more than 3 profiles, the edge counts again only once 4 profiles in a row hold
/// it. The line refitted over all its points, refitted every 16 new ones on the way. nullopt:
/// nothing added, or the extension made the residual worse (another edge).
std::optional<RefinedLine> extendLineSubpixel(cv::Mat const& bgr, RefinedLine const& refined, double t0, double t1,
                                              double t_lo, double t_hi, ContourLinesParams const& params);

/// Lens distortion: the contour lines refitted (least squares, with covariance) to the edge
/// points mapped by `rectify` (distorted pixel -> pixel of the rectified camera), the entry and
/// tip mapped too. The image is never remapped: a straight shaft edge is a curve in the
/// distorted image and a line again after the mapping. nullopt when a side keeps fewer than
/// min_points mapped points or the refitted lines cross. `sigma_floor_px`: as
/// ContourLinesParams::line_sigma_floor_px.
std::optional<geometry::ApparentContour> rectifyContour(geometry::ApparentContour const& contour,
                                              std::array<std::vector<Eigen::Vector2d>, 2> const& edges,
                                              std::function<Eigen::Vector2d(Eigen::Vector2d const&)> const& rectify,
                                              int min_points = 8, double sigma_floor_px = ContourLinesParams{}.line_sigma_floor_px);

}  // namespace endo_guidance::perception
