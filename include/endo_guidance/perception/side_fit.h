// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <array>
#include <memory>
#include <optional>
#include <vector>

#include "endo_guidance/perception/contour_params.h"
#include "endo_guidance/perception/edge_profile.h"
#include "endo_guidance/perception/field_of_view.h"
#include "endo_guidance/perception/region_growing.h"

namespace endo_guidance::perception {

struct SideChains;  // what every side search of a region shares (side_fit.cpp)
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
  /// Per side, the colour direction its edge is located along (edge_profile.h); unset: edgeChannel().
  std::array<std::optional<ColourDirection>, 2> colour_direction;
  /// > 0: one side without edges in the frame keeps its own line (a mask's side) in the contour,
  /// with this systematic error (full-resolution px) at each end in its covariance; 0: refused.
  double mask_side_sigma_px = 0.0;
  /// > 0: the sides are a mask's outline, within this (full-resolution px) of the shaft's edge: a
  /// side whose frame edges lie farther from it at either end has none of its own (kWeakEdges).
  double mask_gate_px = 0.0;
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

}  // namespace endo_guidance::perception
