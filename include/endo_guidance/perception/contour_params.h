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

}  // namespace endo_guidance::perception
