// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/contour_fit.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <variant>

#include "endo_guidance/perception/contour_checks.h"
#include "endo_guidance/perception/edge_profile.h"
#include "endo_guidance/perception/image_reduction.h"

namespace endo_guidance::perception {

namespace {

// The extent [t0, t1] of points along the direction (-b, a) of `line`.
std::pair<double, double> extentOn(Eigen::Vector3d const& line, std::vector<Eigen::Vector2d> const& pts) {
  Eigen::Vector2d const d(-line.y(), line.x());
  double t0 = std::numeric_limits<double>::infinity(), t1 = -t0;
  for (auto const& q : pts) {
    t0 = std::min(t0, d.dot(q));
    t1 = std::max(t1, d.dot(q));
  }
  return {t0, t1};
}

// Side s's sub-pixel line on the full-resolution image, over the extent of its points (2 px in
// from each end): a wide pass (the region's boundary can sit several px inside the shaft's shaded
// rim), a narrow one about it, then followed along its edge past where the region's side stopped
// (a highlight, JPEG, a touching blob) back to the entry and on: a longer baseline.
std::variant<RefinedLine, ContourRejection> refineSide(SideFit const& sides, int s, cv::Mat const& bgr, ContourLinesParams const& p) {
  auto const [t0, t1] = extentOn(sides.lines[s], sides.points[s]);
  ColourDirection const* dir = sides.colour_direction[s] ? &*sides.colour_direction[s] : nullptr;
  ContourLinesParams wide = widePass(p);
  wide.max_residual_px = 1e9;
  auto const r0 = refineLineProfiles(bgr, sides.lines[s], t0 + 2.0, t1 - 2.0, wide, dir ? nullptr : &sides.scored[s], nullptr, dir);
  if (!r0) return ContourRejection::kWeakEdges;
  auto r = refineLineSubpixel(bgr, r0->line, t0 + 2.0, t1 - 2.0, p, dir);
  if (!r) return ContourRejection::kWeakEdges;
  if (r->residual_px > p.max_residual_px) return ContourRejection::kResidual;
  Eigen::Vector2d const dr(-r->line.y(), r->line.x());
  double const te = dr.dot(geometry::footOnLine(r->line, sides.entry)), tf = dr.dot(geometry::footOnLine(r->line, sides.far));
  double const inf = std::numeric_limits<double>::infinity();
  if (auto const x = extendLineSubpixel(bgr, *r, t0 + 2.0, t1 - 2.0, tf > te ? te : -inf, tf > te ? inf : te, p, dir)) r = x;
  if (sides.mask_gate_px > 0.0) {  // a mask's side: edges farther from it at either end are another edge's
    Eigen::Vector2d const d(-sides.lines[s].y(), sides.lines[s].x()), o = geometry::footOnLine(sides.lines[s], Eigen::Vector2d::Zero());
    for (double const t : {t0, t1})
      if (std::abs(r->line.dot((o + t * d).homogeneous())) > sides.mask_gate_px) return ContourRejection::kWeakEdges;
  }
  return *r;
}

// Side s without edges in the frame as its own line (a mask's side): the covariance of its points'
// residuals plus mask_side_sigma_px at each end; no edge points.
std::optional<RefinedLine> maskSideLine(SideFit const& sides, int s, ContourLinesParams const& p) {
  std::vector<double> const w(sides.points[s].size(), 1.0);
  auto r = summarizeLine(sides.lines[s], sides.points[s], w, std::max(3, p.min_side_points), sides.mask_side_sigma_px);
  if (r) r->inliers.clear(), r->points = 0;
  return r;
}

// The two refined lines as a contour: lines[0] on the left walking from the entry toward the
// tip (v down), each oriented toward the shaft; nullopt when they cross or do not enclose it.
// `axis_dir`: the unit direction entry -> tip; `edges`: the lines' edge points, in that order.
std::optional<geometry::ApparentContour> orderLines(RefinedLine const (&ref)[2], SideFit const& sides, Eigen::Vector2d& axis_dir,
                                                    std::array<std::vector<Eigen::Vector2d>, 2>& edges) {
  axis_dir = Eigen::Vector2d(-(ref[0].line.y() - ref[1].line.y()), ref[0].line.x() - ref[1].line.x());
  if (axis_dir.norm() < 1e-9) return std::nullopt;
  axis_dir.normalize();
  if (axis_dir.dot(sides.far - sides.entry) < 0.0) axis_dir = -axis_dir;
  Eigen::Vector2d const left(axis_dir.y(), -axis_dir.x());
  int const L = ref[0].line.head<2>().dot(left) < 0.0 ? 0 : 1;  // normal pointing right: left line
  if (!(ref[L].line.head<2>().dot(left) < 0.0 && ref[1 - L].line.head<2>().dot(left) > 0.0)) return std::nullopt;
  geometry::ApparentContour c;
  c.lines = {ref[L].line, ref[1 - L].line};
  c.line_covariances = {ref[L].covariance, ref[1 - L].covariance};
  c.line_residual_px = {ref[L].residual_px, ref[1 - L].residual_px};
  edges = {ref[L].inliers, ref[1 - L].inliers};
  c.residual_px = std::sqrt(0.5 * (ref[0].residual_px * ref[0].residual_px + ref[1].residual_px * ref[1].residual_px));
  return c;
}

// The tip: the region point farthest from the entry along the axis among those in the strip
// between the lines (not the jaws' spread, nor a touching instrument beyond the tip), at most
// 2.5 widths beyond the end of the straight sides (the jaws, not a blob the region ran into).
Eigen::Vector2d findTip(geometry::ApparentContour const& c, SideFit const& sides, Region const& region, Eigen::Vector2d const& axis_dir,
                        int scale) {
  Eigen::Vector2d const entry = sides.entry;
  double t_sides = 0.0;
  for (int s = 0; s < 2; ++s)
    for (auto const& q : sides.points[s]) t_sides = std::max(t_sides, axis_dir.dot(q - entry));
  Eigen::Vector2d const end = entry + t_sides * axis_dir;
  double const end_width = c.lines[0].dot(Eigen::Vector3d(end.x(), end.y(), 1.0)) + c.lines[1].dot(Eigen::Vector3d(end.x(), end.y(), 1.0));
  double const t_limit = t_sides + 2.5 * std::max(end_width, 2.0 * scale);
  double best = -1e300;
  Eigen::Vector2d tip = end;
  for (auto const& q : region.boundary) {
    Eigen::Vector2d const x = toFullRes(Eigen::Vector2d(q.x, q.y), scale);
    Eigen::Vector3d const xh(x.x(), x.y(), 1.0);
    if (c.lines[0].dot(xh) < -scale || c.lines[1].dot(xh) < -scale) continue;
    double const t = axis_dir.dot(x - entry);
    if (t > t_limit) continue;
    if (t > best) {
      best = t;
      tip = x;
    }
  }
  return tip;
}

// The shape checks of a contour with its entry and tip set: length, width at both ends, widening,
// entering the view across its border, elongation and fill (contour_checks.h).
ContourRejection checkShape(geometry::ApparentContour const& c, SideFit const& sides, Region const& region, FieldOfView const& fov,
                            Eigen::Vector2d const& axis_dir, int scale, ContourLinesParams const& p) {
  Eigen::Vector2d const entry = c.entry_px, tip = c.tip_px;
  if ((tip - entry).norm() < p.min_length_px) return ContourRejection::kTooShort;
  // Width where the shaft is seen: the sum of the signed distances (both positive inside).
  double width_at[2];
  for (int k = 0; k < 2; ++k) {
    Eigen::Vector3d const x = (k == 0 ? entry : tip).homogeneous();
    width_at[k] = c.lines[0].dot(x) + c.lines[1].dot(x);
    if (width_at[k] < p.min_width_px) return ContourRejection::kTooThin;
  }
  if (p.max_widening > 0.0 && width_at[1] > p.max_widening * width_at[0]) return ContourRejection::kWidens;
  if (enteringSine(c, fov, entry, axis_dir, std::max(1.0, width_at[0] / scale), scale) < p.min_entry_sine)
    return ContourRejection::kAlongBorder;
  double const width = 0.5 * (width_at[0] + width_at[1]);
  if ((tip - entry).norm() < p.min_elongation * width) return ContourRejection::kNotElongated;
  // A region merged with a crossing or touching instrument has its pixels near the strip too, and
  // one with a side found as the parallel stretch the blob beside it: only the fill counts then.
  double const inside = sides.merged || sides.parallel ? p.min_inside_merged : p.min_inside;
  if (!fillsStrip(c, region, axis_dir, width, scale, p.min_fill, inside)) return ContourRejection::kNotFilled;
  return ContourRejection::kNone;
}

}  // namespace

ContourFit refineContour(SideFit const& sides, Region const& region, FieldOfView const& fov, cv::Mat const& bgr,
                         int scale, ContourLinesParams const& p) {
  ContourFit fit;
  auto reject = [&](ContourRejection r) {
    fit.rejection = r;
    return fit;
  };
  if (sides.rejection != ContourRejection::kNone) return reject(sides.rejection);
  RefinedLine ref[2];
  bool from_mask = false;
  for (int s = 0; s < 2; ++s) {
    auto r = refineSide(sides, s, bgr, p);
    if (auto const* why = std::get_if<ContourRejection>(&r)) {
      if (*why != ContourRejection::kWeakEdges || !(sides.mask_side_sigma_px > 0.0) || from_mask) return reject(*why);
      auto m = maskSideLine(sides, s, p);
      if (!m) return reject(*why);
      from_mask = true;
      ref[s] = std::move(*m);
      continue;
    }
    ref[s] = std::move(std::get<RefinedLine>(r));
    fit.edge_points += ref[s].points;
  }
  Eigen::Vector2d axis_dir;
  auto c = orderLines(ref, sides, axis_dir, fit.edges);
  if (!c) return reject(ContourRejection::kCrossing);
  c->entry_px = sides.entry;
  c->tip_px = findTip(*c, sides, region, axis_dir, scale);
  if (auto const why = checkShape(*c, sides, region, fov, axis_dir, scale, p); why != ContourRejection::kNone) return reject(why);
  fit.contour = *c;
  return fit;
}

double scoreSides(SideFit& sides, cv::Mat const& bgr, ContourLinesParams const& p) {
  if (sides.rejection != ContourRejection::kNone) return -1.0;
  ContourLinesParams wide = widePass(p);
  wide.refine_step_px = p.score_step_px;
  wide.min_edge_points = std::max(3, p.min_edge_points / 3);
  double score = 0.0;
  for (int s = 0; s < 2; ++s) {
    auto const [t0, t1] = extentOn(sides.lines[s], sides.points[s]);
    auto const r = refineLineProfiles(bgr, sides.lines[s], t0 + 2.0, t1 - 2.0, wide, nullptr, &sides.scored[s]);
    if (!r) return -1.0;
    score += r->points / (1.0 + r->residual_px);
  }
  return score;
}

ContourFit fitApparentContour(Region const& region, FieldOfView const& fov, cv::Mat const& bgr, int scale,
                              ContourLinesParams const& p) {
  return refineContour(fitSides(region, fov, scale, p), region, fov, bgr, scale, p);
}

}  // namespace endo_guidance::perception
