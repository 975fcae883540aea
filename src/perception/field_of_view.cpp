// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/field_of_view.h"

#include <algorithm>
#include <cmath>

#include <opencv2/imgproc.hpp>

namespace endo_guidance::perception {

FieldOfView detectFieldOfView(cv::Mat const& bgr, FieldOfViewParams const& p) {
  CV_Assert(bgr.type() == CV_8UC3);
  FieldOfView fov;
  cv::Mat mx;
  {
    std::vector<cv::Mat> ch;
    cv::split(bgr, ch);
    cv::max(ch[0], ch[1], mx);
    cv::max(mx, ch[2], mx);
  }
  cv::Mat lit;
  cv::threshold(mx, lit, p.dark_threshold, 255, cv::THRESH_BINARY);
  cv::morphologyEx(lit, lit, cv::MORPH_OPEN, cv::getStructuringElement(cv::MORPH_RECT, {3, 3}));
  std::vector<std::vector<cv::Point>> contours;
  cv::findContours(lit, contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_SIMPLE);
  double best = 0.0;
  int bi = -1;
  for (int i = 0; i < static_cast<int>(contours.size()); ++i) {
    double const a = cv::contourArea(contours[i]);
    if (a > best) {
      best = a;
      bi = i;
    }
  }
  cv::Mat area = cv::Mat::zeros(bgr.size(), CV_8U);
  double const total = static_cast<double>(bgr.rows) * bgr.cols;
  std::vector<cv::Point> hull;
  if (bi >= 0 && best >= p.min_area_fraction * total) {
    cv::convexHull(contours[bi], hull);
    cv::fillConvexPoly(area, hull, 255);
  } else {
    area.setTo(255);
  }
  fov.bounds = cv::boundingRect(area);
  double const fill = cv::countNonZero(area) / std::max(1.0, static_cast<double>(fov.bounds.area()));
  fov.circular = fill < 0.9;  // a disc fills pi/4 = 0.785 of its box, a clipped disc a bit more
  cv::Moments const mo = cv::moments(area, true);
  fov.centre = mo.m00 > 0 ? cv::Point2f(mo.m10 / mo.m00, mo.m01 / mo.m00) : cv::Point2f(bgr.cols / 2.f, bgr.rows / 2.f);
  // The image rectangle also bounds the area: erode with a 0 border.
  cv::Mat er;
  cv::erode(area, er, cv::getStructuringElement(cv::MORPH_ELLIPSE, {2 * p.inset + 1, 2 * p.inset + 1}), {-1, -1}, 1,
            cv::BORDER_CONSTANT, 0);
  fov.mask = er;
  // Distance to the area's edge, the image's edge included (a zero frame around it).
  cv::Mat padded, dist;
  cv::copyMakeBorder(area, padded, 1, 1, 1, 1, cv::BORDER_CONSTANT, 0);
  cv::distanceTransform(padded, dist, cv::DIST_L2, cv::DIST_MASK_PRECISE);
  fov.depth = dist(cv::Rect(1, 1, area.cols, area.rows)).clone();
  std::vector<std::vector<cv::Point>> c2;
  cv::findContours(er.clone(), c2, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_NONE);
  std::size_t bj = 0;
  for (std::size_t i = 1; i < c2.size(); ++i)
    if (c2[i].size() > c2[bj].size()) bj = i;
  if (!c2.empty()) fov.border = std::move(c2[bj]);
  return fov;
}

double depthAt(FieldOfView const& fov, Eigen::Vector2d const& x) {
  if (fov.depth.empty()) return 0.0;
  int const c = std::clamp(static_cast<int>(std::lround(x.x())), 0, fov.depth.cols - 1);
  int const r = std::clamp(static_cast<int>(std::lround(x.y())), 0, fov.depth.rows - 1);
  return fov.depth.at<float>(r, c);
}

Eigen::Vector2d depthGradient(FieldOfView const& fov, cv::Point p) {
  if (fov.depth.cols < 7 || fov.depth.rows < 7) return Eigen::Vector2d::Zero();
  int const x = std::clamp(p.x, 3, fov.depth.cols - 4), y = std::clamp(p.y, 3, fov.depth.rows - 4);
  return {fov.depth.at<float>(y, x + 3) - fov.depth.at<float>(y, x - 3),
          fov.depth.at<float>(y + 3, x) - fov.depth.at<float>(y - 3, x)};
}

bool insideView(FieldOfView const& fov, Eigen::Vector2d const& x) {
  int const u = static_cast<int>(std::lround(x.x())), v = static_cast<int>(std::lround(x.y()));
  return u >= 0 && v >= 0 && u < fov.mask.cols && v < fov.mask.rows && fov.mask.at<std::uint8_t>(v, u) != 0;
}

std::optional<Eigen::Vector2d> walkToEdge(FieldOfView const& fov, Eigen::Vector2d p, Eigen::Vector2d const& dir, int max_steps,
                                          bool* at_edge) {
  if (at_edge) *at_edge = true;
  int k = 0;
  if (insideView(fov, p)) {
    for (; k < max_steps && insideView(fov, p - dir); ++k) p -= dir;  // out to the edge
    if (at_edge) *at_edge = k < max_steps;
  } else {
    for (; k < max_steps && !insideView(fov, p); ++k) p += dir;  // into the area
    if (!insideView(fov, p)) return std::nullopt;
  }
  return p;
}

bool nearViewEdge(FieldOfView const& fov, cv::Point q, int margin) {
  for (cv::Point const d : {cv::Point(margin, 0), cv::Point(-margin, 0), cv::Point(0, margin), cv::Point(0, -margin)}) {
    cv::Point const r = q + d;
    if (r.x < 0 || r.y < 0 || r.x >= fov.mask.cols || r.y >= fov.mask.rows || fov.mask.at<std::uint8_t>(r) == 0) return true;
  }
  return false;
}

}  // namespace endo_guidance::perception
