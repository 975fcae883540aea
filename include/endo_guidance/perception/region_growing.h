// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "endo_guidance/perception/field_of_view.h"
#include "endo_guidance/perception/seed_search.h"

namespace endo_guidance::perception {

struct RegionGrowingParams {
  /// Growth thresholds tried for each seed, ascending: pixels with feature at or below join the
  /// region. Pale tissue (membranes, peritoneum) is low in some images and not in others; the
  /// segmentation keeps the level whose boundary is the best pair of straight lines.
  std::vector<int> thresholds{18, 24, 30, 37, 45};
  /// The levels actually tried for a seed are min(threshold, seed + f (background - seed)) for the
  /// fractions below (paired with `thresholds`): between the shaft's and the tissue's levels where
  /// the border is dark, the absolute levels where it is bright.
  std::vector<double> background_fractions{0.4, 0.52, 0.64, 0.76, 0.88};
  double dark_border_level = 45.0;  ///< the fractions apply to seeds whose border background is below this
  int min_area = 40;               ///< processing px: smaller regions are not shafts
  double max_area_fraction = 0.35; ///< of the field of view: larger ones have leaked into tissue
  int max_regions = 8;             ///< accepted regions per frame
};

/// The growth levels of one seed, ascending.
struct GrowthLevels {
  std::vector<int> thresholds;  ///< first the configured list (lowered on a dark border), then the absolute levels above them
  int strip_level = 0;          ///< the highest of the configured list: the strip search's interior level
};
/// The levels tried for a seed of mean feature `seed` whose border background is `background`:
/// on a dark border, the configured thresholds lowered toward the seed's level
/// (min(t_i, seed + f_i (background - seed)), at least seed + 2), then the absolute thresholds
/// above the highest lowered one (the background taken along the border is also low where a
/// grey blob or a dark corner lies on it, not beside the shaft); elsewhere the thresholds.
GrowthLevels growthLevels(RegionGrowingParams const& p, float seed, float background);
/// The index in `levels` (a seed's levels this frame) of the level remembered from the last frame
/// as index `level` of threshold `threshold`: a place in the configured list is kept (the lowered
/// levels follow the tissue's level), an absolute level added above them is found again by its
/// threshold, the nearest if it is not there (the list is shorter where the border is no longer dark).
int rememberedLevel(std::vector<int> const& levels, int configured, int level, int threshold);

/// A grown region and its ordered outer boundary.
struct Region {
  int seed_index = -1;               ///< the seed it grew from
  int threshold = 0;                 ///< growth threshold used
  cv::Point seed;                    ///< processing-scale pixels
  cv::Rect box;
  int area = 0;
  std::vector<cv::Point> boundary;   ///< closed, ordered (8-connected) outer boundary
  cv::Mat mask;                      ///< CV_8U over `box`, non-zero on its pixels (a grown region; empty for a strip's quad)
};

/// Region growing from a seed over the 4-connected pixels whose (filtered) feature is at most a
/// threshold, inside the field of view and outside the regions already claimed in this frame.
class RegionGrower {
 public:
  /// Starts a frame: the filtered feature and the field of view (same size).
  void reset(cv::Mat const& feature, FieldOfView const& fov);
  /// The region of `seed` at `threshold`; nullopt if the seed is above it or already claimed.
  std::optional<Region> grow(cv::Point seed, int threshold, int seed_index = -1);
  /// Marks a region as taken (later seeds inside it are skipped; it is drawn in labels()). With a
  /// polygon (processing px), only the region's pixels inside it are taken: an accepted shaft
  /// claims its own strip, not the touching instrument that grew into the same region.
  void claim(Region const& r, int label, std::vector<cv::Point> const& polygon = {});
  bool claimed(cv::Point p) const { return base_.at<std::uint8_t>(p.y + 1, p.x + 1) != 0; }
  /// Label image (CV_8U, feature size): 0 = none, k = k-th claimed region.
  cv::Mat const& labels() const { return labels_; }

 private:
  cv::Mat feature_;
  cv::Mat base_;     // (rows+2)x(cols+2): 1 outside the FOV and on claimed regions
  cv::Mat labels_;
};

}  // namespace endo_guidance::perception
