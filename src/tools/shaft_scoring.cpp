// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "shaft_scoring.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <tuple>

#include "tool_util.h"

namespace endo_guidance::tools {

MaskShaft maskShaft(cv::Mat const& shaft, cv::Mat const& jaws) {
  CV_Assert(shaft.type() == CV_8U);
  MaskShaft s;
  cv::Mat m = shaft != 0;
  s.pixels = cv::countNonZero(m);
  if (s.pixels < 2) return s;
  // Principal axis of the shaft's pixels.
  cv::Mat er;
  cv::erode(m, er, cv::Mat(), cv::Point(-1, -1), 1, cv::BORDER_CONSTANT, cv::Scalar(0));
  cv::Mat const boundary = m & ~er;
  cv::Mat near_jaws;
  if (!jaws.empty()) cv::dilate(jaws != 0, near_jaws, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(2 * kMaskMarginPx + 1, 2 * kMaskMarginPx + 1)));
  cv::Moments const mo = cv::moments(m, true);
  Eigen::Vector2d const c(mo.m10 / mo.m00, mo.m01 / mo.m00);
  double const th = 0.5 * std::atan2(2.0 * mo.mu11, mo.mu20 - mo.mu02);
  Eigen::Vector2d const normal(-std::sin(th), std::cos(th));  // across the principal axis
  for (int y = kMaskMarginPx; y < m.rows - kMaskMarginPx; ++y)
    for (int x = kMaskMarginPx; x < m.cols - kMaskMarginPx; ++x) {
      if (!boundary.at<std::uint8_t>(y, x) || (!near_jaws.empty() && near_jaws.at<std::uint8_t>(y, x))) continue;
      Eigen::Vector2d const q(x, y);
      s.sides[normal.dot(q - c) < 0.0 ? 0 : 1].push_back(q);
    }
  if (s.sides[0].empty() || s.sides[1].empty()) s.sides = {};
  return s;
}

double sideMedianPx(std::vector<Eigen::Vector2d> const& side, geometry::ImageLine const& l) {
  std::vector<double> d;
  d.reserve(side.size());
  for (Eigen::Vector2d const& q : side) d.push_back(std::abs(l.dot(q.homogeneous())));
  return percentile(d, 0.5);
}

double findCost(MaskShaft const& s, geometry::ApparentContour const& c) {
  if (s.sides[0].empty()) return std::numeric_limits<double>::infinity();
  double const a00 = sideMedianPx(s.sides[0], c.lines[0]), a11 = sideMedianPx(s.sides[1], c.lines[1]);
  double const a01 = sideMedianPx(s.sides[0], c.lines[1]), a10 = sideMedianPx(s.sides[1], c.lines[0]);
  return std::min(std::max(a00, a11), std::max(a01, a10));
}

StrictScore& StrictScore::operator+=(StrictScore const& o) {
  shafts += o.shafts;
  detections += o.detections;
  for (std::size_t k = 0; k < found.size(); ++k) found[k] += o.found[k];
  false_detections += o.false_detections;
  side_median_px.insert(side_median_px.end(), o.side_median_px.begin(), o.side_median_px.end());
  return *this;
}

StrictScore scoreStrict(std::vector<MaskShaft> const& shafts, std::vector<geometry::ApparentContour> const& detections) {
  StrictScore r;
  r.shafts = static_cast<int>(shafts.size());
  r.detections = static_cast<int>(detections.size());
  std::vector<std::tuple<double, int, int>> pairs;  // cost, shaft, detection
  for (std::size_t i = 0; i < shafts.size(); ++i)
    for (std::size_t j = 0; j < detections.size(); ++j) {
      double const cost = findCost(shafts[i], detections[j]);
      if (cost <= kFoundPx.back()) pairs.emplace_back(cost, static_cast<int>(i), static_cast<int>(j));
    }
  std::sort(pairs.begin(), pairs.end());
  r.match.assign(shafts.size(), -1);
  for (std::size_t k = 0; k < kFoundPx.size(); ++k) {
    std::vector<char> used_s(shafts.size()), used_d(detections.size());
    for (auto const& [cost, i, j] : pairs) {
      if (cost > kFoundPx[k] || used_s[i] || used_d[j]) continue;
      used_s[i] = used_d[j] = 1;
      ++r.found[k];
      if (k + 1 == kFoundPx.size()) r.match[i] = j;
    }
    if (k + 1 == kFoundPx.size()) r.false_detections = r.detections - r.found[k];
  }
  for (std::size_t i = 0; i < shafts.size(); ++i) {
    if (r.match[i] < 0) continue;
    geometry::ApparentContour const& c = detections[r.match[i]];
    double const a00 = sideMedianPx(shafts[i].sides[0], c.lines[0]), a11 = sideMedianPx(shafts[i].sides[1], c.lines[1]);
    double const a01 = sideMedianPx(shafts[i].sides[0], c.lines[1]), a10 = sideMedianPx(shafts[i].sides[1], c.lines[0]);
    bool const straight = std::max(a00, a11) <= std::max(a01, a10);
    r.side_median_px.push_back(straight ? a00 : a01);
    r.side_median_px.push_back(straight ? a11 : a10);
  }
  return r;
}

}  // namespace endo_guidance::tools
