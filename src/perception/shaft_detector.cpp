// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/shaft_detector.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <opencv2/imgproc.hpp>

#include "endo_guidance/perception/tip_location.h"

namespace endo_guidance::perception {

bool duplicatesAShaft(geometry::ApparentContour const& c, std::vector<geometry::ApparentContour> const& found) {
  geometry::ImageLine const a = geometry::imageAxis(c);
  Eigen::Vector3d const ce = geometry::footOnLine(a, c.entry_px).homogeneous(), ct = geometry::footOnLine(a, c.tip_px).homogeneous();
  for (geometry::ApparentContour const& o : found) {
    geometry::ImageLine const b = geometry::imageAxis(o);
    if (std::abs(a.head<2>().dot(b.head<2>())) < std::cos(kDuplicateMaxAngleDeg * M_PI / 180.0)) continue;
    Eigen::Vector3d const e = o.entry_px.homogeneous();
    double const half_width = 0.5 * (o.lines[0].dot(e) + o.lines[1].dot(e));
    if (std::abs(b.dot(ce)) < half_width && std::abs(b.dot(ct)) < half_width) return true;
  }
  return false;
}

std::vector<std::size_t> overlappingDuplicates(std::vector<geometry::ApparentContour> const& found) {
  std::vector<std::vector<cv::Point2f>> quad;
  std::vector<double> area;
  for (geometry::ApparentContour const& c : found) {
    std::vector<cv::Point2f> q;
    for (Eigen::Vector2d const& f : geometry::shaftQuad(c, c.entry_px, c.tip_px))
      q.emplace_back(static_cast<float>(f.x()), static_cast<float>(f.y()));
    quad.emplace_back();
    cv::convexHull(q, quad.back());  // (convex, as cv::intersectConvexConvex() needs, whatever the lines' convergence)
    area.push_back(std::abs(cv::contourArea(quad.back())));
  }
  // (a residual that is not finite sorts last: the comparison stays a strict weak order)
  auto fit = [&](std::size_t i) {
    double const r = found[i].residual_px;
    return std::isfinite(r) ? r : std::numeric_limits<double>::infinity();
  };
  std::vector<std::size_t> order(found.size());
  std::iota(order.begin(), order.end(), std::size_t{0});
  std::stable_sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return fit(a) < fit(b); });
  std::vector<std::size_t> kept, out;
  for (std::size_t i : order) {
    bool overlaps = false;
    for (std::size_t j : kept) {
      std::vector<cv::Point2f> common;
      float const a = cv::intersectConvexConvex(quad[i], quad[j], common, true);
      if (a > kMaxShaftOverlap * (area[i] + area[j] - a)) {  // intersection over union
        overlaps = true;
        break;
      }
    }
    (overlaps ? out : kept).push_back(i);
  }
  std::sort(out.begin(), out.end());
  return out;
}

std::vector<std::size_t> narrowerDuplicates(std::vector<geometry::ApparentContour> const& found) {
  std::vector<std::size_t> out;
  for (std::size_t i = 0; i < found.size(); ++i) {
    Eigen::Vector2d const mid = 0.5 * (found[i].entry_px + found[i].tip_px);
    double const wi = geometry::shaftWidthAt(found[i], mid);
    for (std::size_t j = 0; j < found.size(); ++j) {
      if (j == i) continue;
      double const wj = geometry::shaftWidthAt(found[j], mid);
      // (equal widths: the later one goes, as when it was found)
      if ((wj > wi || (wj == wi && j < i)) && duplicatesAShaft(found[i], {found[j]})) {
        out.push_back(i);
        break;
      }
    }
  }
  return out;
}

void removeDuplicateShafts(SegmentationResult& res, std::vector<std::size_t>& keys) {
  auto drop = [&](std::vector<std::size_t> const& dup) {  // (ascending)
    for (auto it = dup.rbegin(); it != dup.rend(); ++it) {
      auto const i = static_cast<std::ptrdiff_t>(*it);
      res.region_status[res.contour_regions[*it]] = ContourRejection::kDuplicate;
      res.contours.erase(res.contours.begin() + i);
      res.edges.erase(res.edges.begin() + i);
      res.contour_regions.erase(res.contour_regions.begin() + i);
      if (*it < keys.size()) keys.erase(keys.begin() + i);
    }
  };
  // A shaft found whole and again as a strip inside it; then contours that overlap one that fits
  // better (a wedge between a shaft's edge and a tissue edge).
  drop(narrowerDuplicates(res.contours));
  drop(overlappingDuplicates(res.contours));
}

void locateTips(SegmentationResult& res, DetectionFrame const& frame, cv::Mat const* instrument) {
  res.tip_colours.assign(res.contours.size(), std::nullopt);
  for (std::size_t i = 0; i < res.contours.size() && i < res.contour_regions.size() && i < res.edges.size(); ++i) {
    InstrumentMask mask;
    if (instrument) {
      mask.map = *instrument;
    } else {  // the region: its own mask, or its polygon (a strip's quad) drawn over its box
      Region const& region = res.regions[res.contour_regions[i]];
      if (!region.mask.empty() && region.mask.size() == region.box.size()) {
        mask = {region.mask, region.box.tl()};
      } else if (cv::Rect const box = cv::boundingRect(region.boundary); !box.empty()) {
        mask = {cv::Mat::zeros(box.size(), CV_8U), box.tl()};
        cv::fillPoly(mask.map, std::vector<std::vector<cv::Point>>{region.boundary}, cv::Scalar(255), cv::LINE_8, 0, -box.tl());
      } else {
        continue;
      }
    }
    TipColours colours;
    if (auto const tip = locateTipOnFrame(frame.bgr, res.contours[i], res.edges[i], mask, frame.fov.mask, frame.scale, 20.0, &colours)) {
      res.tip_colours[i] = colours;
      res.contours[i].tip_px = *tip;
      res.contours[i] = onImageAxis(res.contours[i]);
    }
  }
}

geometry::ApparentContour onImageAxis(geometry::ApparentContour c) {
  geometry::ImageLine const ax = geometry::imageAxis(c);
  c.entry_px = geometry::footOnLine(ax, c.entry_px);
  c.tip_px = geometry::footOnLine(ax, c.tip_px);
  return c;
}

}  // namespace endo_guidance::perception
