// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <cstdint>

namespace endo_guidance::perception {

/// The parameters of the contour fit: side search (side_fit.h), sub-pixel edges (edge_profile.h)
/// and shape checks (contour_checks.h), in full-resolution px unless said.
struct ContourLinesParams {
  int border_margin = 2;          ///< processing px: boundary points this close to the FOV edge are the entry
  int min_side_points = 10;       ///< boundary points per side (processing px)
  double min_inlier_fraction = 0.5;  ///< LMedS inliers per side: fewer and the side is not a straight line
  double max_angle_deg = 20.0;    ///< between the two contour lines
  double min_length_px = 30.0;    ///< entry to tip
  double min_width_px = 8.0;      ///< shaft width at entry and tip (narrower bands are tissue creases)
  int lmeds_samples = 30;         ///< random pairs per side (P(no clean pair) < 1e-3 at 20 % outliers)
  int max_gap_points = 6;         ///< a side ends after this many consecutive boundary points off its line
  double refine_step_px = 2.0;    ///< spacing of the edge profiles along a line (not capped: every profile counts on real images)
  double refine_halfwidth_px = 3.5;  ///< half length of each profile across the line (final pass)
  double coarse_halfwidth_px = 9.0;  ///< the same for the first, wide pass
  double profile_step_px = 0.5;   ///< sampling along each profile (the wide pass uses 2x)
  double score_step_px = 6.0;     ///< profile spacing when scoring candidate regions
  double min_edge_contrast = 2.5; ///< edgeChannel() units per px: weaker profiles carry no edge
  /// Final pass: an edge is the centroid of its slope's lobe down to this fraction of the peak
  /// (within +-2.5 px), not of every descent in the window (< 0: the window; the wide pass always is).
  double edge_lobe_floor = 0.05;
  int min_edge_points = 8;        ///< sub-pixel edge points per line
  /// A refined line is followed beyond its region side until this many profiles in a row give no
  /// edge on it, so that an occluder across the shaft (another tip) is crossed; beyond a gap of
  /// more than 3 profiles, 4 in a row must confirm the edge (0: not followed).
  int extend_max_misses = 40;
  double extend_gate_px = 0.75;   ///< ... "on it": within max(3 residuals, this)
  /// Systematic error at each end of a line, added to the covariance the residuals give: they miss
  /// the errors common to all edge points (compression, shading), which mis-rank the axes' weights
  /// in the trocar estimate.
  double line_sigma_floor_px = 0.25;
  double max_residual_px = 3.0;   ///< RMS of the sub-pixel edge points to their line
  double min_elongation = 2.0;    ///< length (entry to tip) over mean width
  /// Width at the tip over width at the entry: a shaft pointing toward the camera widens toward
  /// its tip, but not this much (dark wedges in a corner of the view do).
  double max_widening = 2.0;
  /// Sine of the angle between the shaft and the FOV border where its axis leaves the view: a
  /// band along the border is not an instrument entering.
  double min_entry_sine = 0.1;
  /// A side that is not a straight line from the entry (a shaft merged with a grey blob there)
  /// may be the straight stretch of its chain parallel to the other side, at least this long
  /// relative to it and beside it over this fraction of its own length (0: never).
  double min_parallel_side_ratio = 0.5;
  double min_fill = 0.45;         ///< fraction of the strip between the lines covered by the region
  double min_inside = 0.6;        ///< fraction of the region inside that strip (near it)
  double min_inside_merged = 0.3; ///< the same for a region that meets the FOV border more than once
  /// Of the samples between the lines (acrossContour()): more glare (near white, achromatic) and
  /// it is a reflection on wet tissue, not a shaft.
  double max_glare_fraction = 0.5;
  std::uint64_t seed = 7;
};

enum class ContourRejection {
  kNone = 0, kTooFewPoints, kNotStraight, kNotParallel, kTooShort, kTooThin, kCrossing, kWeakEdges, kResidual,
  kNotElongated, kNotFilled, kAlongBorder, kLowContrast, kWidthJump, kDuplicate, kWidens, kGlare, kTipOnBorder,
  kNotContinued, kNotShaftAtEntry
};
char const* toString(ContourRejection r);

}  // namespace endo_guidance::perception
