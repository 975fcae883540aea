// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <vector>

#include "endo_guidance/perception/field_of_view.h"

namespace endo_guidance::perception {

struct SeedSearchParams {
  int threshold = 40;          ///< feature value at or below which the border is "shaft-like"
  int near_threshold = 55;     ///< relaxed threshold on the border arc facing a known trocar image
  int min_width = 3;           ///< run length (processing px) for a seed
  double max_width_fraction = 0.35;  ///< of the border length: longer runs are dark surround/shadow
  double near_angle_deg = 50.0;      ///< half-angle of the arc, seen from the FOV centre, facing a trocar image
  double relative_threshold = 0.7;   ///< where the border is dark: at most this fraction of the local border
                                     ///< background (upper quartile) too (0: never)
  double dark_border_level = 45.0;   ///< the border is dark where its local background feature is below this
  int min_threshold = 6;             ///< the relative threshold never goes below this
  /// On a dark border a run also extends over values up to this where the relative threshold is
  /// lower (0: runs are the relative threshold's alone). Where a shaft and a grey blob beside it
  /// cover most of the background window, the "tissue level" is the shaft's own (rendered hard
  /// scene, bottom border: 8-9, the shaft 6-9 with JPEG noise) and a fraction of it splits the
  /// shaft's run into stubs, or leaves none. The seed of such a run lies in its lowest part.
  int run_floor = 14;
  double background_window = 0.125;  ///< fraction of the border over which the background is taken
};

/// A place where a shaft enters the field of view: a run of low feature values along the border.
struct Seed {
  cv::Point position;          ///< middle of the run, or of its lowest part (processing-scale pixels; see findSeeds())
  int begin = 0, end = 0;      ///< run indices along FieldOfView::border (end exclusive, may wrap)
  int width = 0;               ///< run length
  float mean_value = 0.f;      ///< mean feature value over the run, or over its lowest part
  float background = 0.f;      ///< upper-quartile feature value of the border around it (the tissue's level)
  int insertion_point = -1;    ///< index of the trocar image whose arc it is on, or -1
};

/// 1-D search of low feature values along the field-of-view border ([Doignon07] Sec. 3): runs at
/// or below the threshold (on a dark border, the relative one, or up to run_floor where that is
/// lower). A run holding stretches under the relative threshold alone (of min_width) -- a shaft
/// beside a grey blob of about its level -- is seeded at the middle of the one with the lowest
/// mean, and takes that mean: the shaft is the lower. With
/// trocar images known (homogeneous points in the same pixel scale; [Doignon07] Sec. 4) the
/// arcs that face them are searched first and with the relaxed threshold; seeds come back in
/// that priority order.
std::vector<Seed> findSeeds(cv::Mat const& feature, FieldOfView const& fov, SeedSearchParams const& params = {},
                            std::vector<Eigen::Vector3d> const& trocar_images = {});

}  // namespace endo_guidance::perception
