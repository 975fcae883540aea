// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/rectification.h"

#include <cmath>
#include <memory>
#include <opencv2/calib3d.hpp>
#include <vector>

#include "endo_guidance/perception/line_fit.h"

namespace endo_guidance::perception {

std::optional<geometry::ApparentContour> rectifyContour(geometry::ApparentContour const& contour,
                                              std::array<std::vector<Eigen::Vector2d>, 2> const& edges,
                                              PointRectifier const& rectify,
                                              int min_points, double sigma_floor_px) {
  geometry::ApparentContour out = contour;
  out.entry_px = rectify(contour.entry_px);
  out.tip_px = rectify(contour.tip_px);
  // A point inside the shaft (between the lines, half-way along): it stays inside after the
  // mapping and orients the refitted lines.
  Eigen::Vector2d const mid = 0.5 * (contour.entry_px + contour.tip_px);
  Eigen::Vector2d const inside = rectify(0.5 * (geometry::footOnLine(contour.lines[0], mid) + geometry::footOnLine(contour.lines[1], mid)));
  for (int s = 0; s < 2; ++s) {
    std::vector<Eigen::Vector2d> pts;
    pts.reserve(edges[s].size());
    for (auto const& q : edges[s]) {
      Eigen::Vector2d const r = rectify(q);
      if (r.allFinite()) pts.push_back(r);
    }
    if (static_cast<int>(pts.size()) < min_points) return std::nullopt;
    auto l = fitLineLS(pts);
    if (!l) return std::nullopt;
    if (l->head<2>().dot(inside) + l->z() < 0.0) *l = -*l;
    auto const r = summarizeLine(*l, pts, std::vector<double>(pts.size(), 1.0), min_points, sigma_floor_px);
    if (!r) return std::nullopt;
    out.lines[s] = r->line;
    out.line_covariances[s] = r->covariance;
    out.line_residual_px[s] = r->residual_px;
  }
  out.residual_px = std::sqrt(0.5 * (out.line_residual_px[0] * out.line_residual_px[0] +
                                     out.line_residual_px[1] * out.line_residual_px[1]));
  Eigen::Vector3d const in(inside.x(), inside.y(), 1.0);
  if (!(out.lines[0].dot(in) > 0.0 && out.lines[1].dot(in) > 0.0)) return std::nullopt;
  return out;
}



std::vector<geometry::ApparentContour> rectifyContours(std::vector<geometry::ApparentContour> const& contours,
                                                       std::vector<std::array<std::vector<Eigen::Vector2d>, 2>> const& edges,
                                                       PointRectifier const& rectify, ContourLinesParams const& params) {
  std::vector<geometry::ApparentContour> out;
  for (std::size_t i = 0; i < contours.size() && i < edges.size(); ++i)
    if (auto r = rectifyContour(contours[i], edges[i], rectify, params.min_edge_points, params.line_sigma_floor_px)) out.push_back(*r);
  return out;
}

PointRectifier pointRectifier(cv::Matx33d const& K, cv::Mat const& D, cv::Matx33d const& R, cv::Matx33d const& P, cv::Size size) {
  cv::TermCriteria const crit(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 50, 1e-10);
  cv::Mat const Dc = D.clone();
  auto exact = [K, R, P, Dc, crit](Eigen::Vector2d const& p) {
    std::vector<cv::Point2d> in{{p.x(), p.y()}}, out;
    cv::undistortPoints(in, out, K, Dc, R, P, crit);
    return Eigen::Vector2d(out[0].x, out[0].y);
  };
  int const W = size.width, H = size.height;
  std::vector<cv::Point2d> grid;
  grid.reserve(static_cast<std::size_t>(W) * H);
  for (int v = 0; v < H; ++v)
    for (int u = 0; u < W; ++u) grid.emplace_back(u, v);
  auto table = std::make_shared<std::vector<cv::Point2d>>();
  if (!grid.empty()) cv::undistortPoints(grid, *table, K, Dc, R, P, crit);
  return [table, W, H, exact](Eigen::Vector2d const& p) {
    if (!(p.x() >= 0.0 && p.y() >= 0.0 && p.x() < W - 1 && p.y() < H - 1)) return exact(p);
    int const u = static_cast<int>(p.x()), v = static_cast<int>(p.y());
    double const fx = p.x() - u, fy = p.y() - v;
    auto at = [&](int du, int dv) {
      cv::Point2d const& q = (*table)[static_cast<std::size_t>(v + dv) * W + (u + du)];
      return Eigen::Vector2d(q.x, q.y);
    };
    return Eigen::Vector2d((1 - fy) * ((1 - fx) * at(0, 0) + fx * at(1, 0)) + fy * ((1 - fx) * at(0, 1) + fx * at(1, 1)));
  };
}

}  // namespace endo_guidance::perception
