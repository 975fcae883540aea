// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/region_growing.h"

#include <opencv2/imgproc.hpp>

#include <algorithm>
#include <cmath>

namespace endo_guidance::perception {

void RegionGrower::reset(cv::Mat const& feature, FieldOfView const& fov) {
  CV_Assert(feature.type() == CV_8U && fov.mask.size() == feature.size());
  feature_ = feature;
  base_.create(feature.rows + 2, feature.cols + 2, CV_8U);
  base_.setTo(1);
  // 0 (free) inside the field of view; floodFill never enters non-zero mask pixels.
  base_(cv::Rect(1, 1, feature.cols, feature.rows)).setTo(0, fov.mask);
  labels_ = cv::Mat::zeros(feature.size(), CV_8U);
}

std::optional<Region> RegionGrower::grow(cv::Point seed, int threshold, int seed_index) {
  if (seed.x < 0 || seed.y < 0 || seed.x >= feature_.cols || seed.y >= feature_.rows) return std::nullopt;
  int const v = feature_.at<std::uint8_t>(seed);
  if (v > threshold || claimed(seed)) return std::nullopt;
  cv::Rect box;
  // Fixed range [0, threshold] around the seed value: loDiff = v, upDiff = threshold - v. Filled
  // into the claim mask itself (value 2), read back and cleared within the region's box only:
  // no copy of the whole mask per growth.
  int const area = cv::floodFill(feature_, base_, seed, 255, &box, cv::Scalar(v), cv::Scalar(threshold - v),
                                 4 | (2 << 8) | cv::FLOODFILL_MASK_ONLY | cv::FLOODFILL_FIXED_RANGE);
  Region r;
  r.seed_index = seed_index;
  r.threshold = threshold;
  r.seed = seed;
  r.box = box;
  r.area = area;
  cv::Mat m = base_(cv::Rect(box.x + 1, box.y + 1, box.width, box.height));
  cv::Mat const roi = m == 2;
  m.setTo(0, roi);
  std::vector<std::vector<cv::Point>> contours;
  cv::findContours(roi, contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_NONE, box.tl());
  if (contours.empty()) return std::nullopt;
  std::size_t bj = 0;
  for (std::size_t i = 1; i < contours.size(); ++i)
    if (contours[i].size() > contours[bj].size()) bj = i;
  r.boundary = std::move(contours[bj]);
  r.mask = roi;
  return r;
}

void RegionGrower::claim(Region const& r, int label, std::vector<cv::Point> const& polygon) {
  // Re-grow into the mask (value 2) to mark exactly this region, then, within its box: claimed
  // (1) inside the polygon, free again (0) outside it.
  int const v = feature_.at<std::uint8_t>(r.seed);
  cv::Rect box;
  int const n = cv::floodFill(feature_, base_, r.seed, 255, &box, cv::Scalar(v), cv::Scalar(std::max(0, r.threshold - v)),
                              4 | (2 << 8) | cv::FLOODFILL_MASK_ONLY | cv::FLOODFILL_FIXED_RANGE);
  if (n <= 0 || box.empty()) return;
  cv::Mat m = base_(cv::Rect(box.x + 1, box.y + 1, box.width, box.height));
  cv::Mat const filled = m == 2;
  cv::Mat in;  // (not a header of `filled`: assigning an expression to it would overwrite `filled`)
  if (polygon.empty()) {
    in = filled;
  } else {
    cv::Mat poly = cv::Mat::zeros(box.size(), CV_8U);
    std::vector<cv::Point> shifted;
    for (auto const& q : polygon) shifted.push_back(q - box.tl());
    cv::fillConvexPoly(poly, shifted, 255);
    cv::bitwise_and(filled, poly, in);
  }
  m.setTo(0, filled);
  m.setTo(1, in);
  labels_(box).setTo(label, in);
}

GrowthLevels growthLevels(RegionGrowingParams const& p, float seed, float background) {
  GrowthLevels g;
  g.thresholds = p.thresholds;
  auto& T = g.thresholds;
  if (T.empty()) return g;
  // only on a dark border, and where the tissue around is brighter than the seed
  if (background < p.dark_border_level && background > seed + 4.f)
    for (std::size_t i = 0; i < T.size() && i < p.background_fractions.size(); ++i) {
      int const rel = static_cast<int>(std::lround(seed + p.background_fractions[i] * (background - seed)));
      T[i] = std::min(T[i], std::max(rel, static_cast<int>(seed) + 2));  // only ever lowered
    }
  g.strip_level = *std::max_element(T.begin(), T.end());
  // Tried only after the lowered ones (ascending: in a full search a region that leaks stops it).
  for (int t : p.thresholds)
    if (t > g.strip_level) T.push_back(t);
  return g;
}

int rememberedLevel(std::vector<int> const& levels, int configured, int level, int threshold) {
  int const n = static_cast<int>(levels.size());
  if (n == 0) return -1;
  if (level >= 0 && level < std::min(configured, n)) return level;
  int best = 0;
  for (int i = 1; i < n; ++i)
    if (std::abs(levels[i] - threshold) < std::abs(levels[best] - threshold)) best = i;
  return best;
}

}  // namespace endo_guidance::perception
