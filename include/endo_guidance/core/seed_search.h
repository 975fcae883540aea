// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <vector>

#include "endo_guidance/core/field_of_view.h"

namespace endo_guidance::core {

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
  double background_window = 0.125;  ///< fraction of the border over which the background is taken
};

/// A place where a shaft enters the field of view: a run of low feature values along the border.
struct Seed {
  cv::Point position;          ///< middle of the run (processing-scale pixels)
  int begin = 0, end = 0;      ///< run indices along FieldOfView::border (end exclusive, may wrap)
  int width = 0;               ///< run length
  float mean_value = 0.f;      ///< mean feature value over the run
  float background = 0.f;      ///< upper-quartile feature value of the border around it (the tissue's level)
  int insertion_point = -1;    ///< index of the trocar image whose arc it is on, or -1
};

/// 1-D search of low feature values along the field-of-view border ([Doignon07] Sec. 3). With
/// trocar images known (homogeneous points in the same pixel scale; [Doignon07] Sec. 4) the
/// arcs that face them are searched first and with the relaxed threshold; seeds come back in
/// that priority order.
std::vector<Seed> findSeeds(cv::Mat const& feature, FieldOfView const& fov, SeedSearchParams const& params = {},
                            std::vector<Eigen::Vector3d> const& trocar_images = {});

}  // namespace endo_guidance::core
