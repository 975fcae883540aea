// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/contour_tracking.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace endo_guidance::perception {

namespace {

Eigen::Vector2d axisDirection(geometry::ApparentContour const& c) {
  Eigen::Vector2d const d = c.tip_px - c.entry_px;
  return d.norm() > 1e-9 ? Eigen::Vector2d(d.normalized()) : Eigen::Vector2d(c.lines[0].y(), -c.lines[0].x());
}

double widthAt(geometry::ApparentContour const& c, Eigen::Vector2d const& q) {
  Eigen::Vector3d const x(q.x(), q.y(), 1.0);
  return c.lines[0].dot(x) + c.lines[1].dot(x);  // both positive inside
}

// The extent of the edge points along the axis from `entry`.
void edgeExtent(std::array<std::vector<Eigen::Vector2d>, 2> const& edges, Eigen::Vector2d const& entry, Eigen::Vector2d const& dir,
                double* start, double* end) {
  *start = std::numeric_limits<double>::infinity();
  *end = -*start;
  for (auto const& side : edges)
    for (auto const& q : side) {
      double const t = dir.dot(q - entry);
      *start = std::min(*start, t);
      *end = std::max(*end, t);
    }
  if (*start > *end) *start = *end = 0.0;
}

}  // namespace

TrackedShaft startTrack(geometry::ApparentContour const& contour, std::array<std::vector<Eigen::Vector2d>, 2> const& edges,
                        std::optional<TipColours> const& tip_colours) {
  TrackedShaft s;
  s.contour = contour;
  s.edges = edges;
  s.tip_colours = tip_colours;
  Eigen::Vector2d const dir = axisDirection(contour);
  edgeExtent(edges, contour.entry_px, dir, &s.edge_start, &s.edge_end);
  // (the detection follows each edge to its end, which can lie a fraction of a px beyond the
  // tip the region gave: the tracked extent is cut at the tip)
  s.detected_edge_end = s.edge_end = std::min(s.edge_end, std::max(0.0, dir.dot(contour.tip_px - contour.entry_px)));
  return s;
}

namespace {
// The two passes of refineContour() per line: wide about last frame's line (the shaft moved by up
// to coarse_halfwidth_px), then narrow about the line found; then the parallelism check.
ContourRejection refineTrackedLines(TrackedShaft const& prev, cv::Mat const& bgr, ContourLinesParams const& p,
                                    ContourTrackingParams const& tp, RefinedLine (&ref)[2]) {
  geometry::ApparentContour const& pc = prev.contour;
  Eigen::Vector2d const dir0 = axisDirection(pc);
  ContourLinesParams wide = widePass(p);
  wide.refine_step_px = tp.coarse_step_px;  // the narrow pass uses every profile
  wide.min_edge_points = std::max(3, static_cast<int>(p.min_edge_points * p.refine_step_px / tp.coarse_step_px));
  for (int s = 0; s < 2; ++s) {
    geometry::ImageLine const& l = pc.lines[s];
    Eigen::Vector2d const d(-l.y(), l.x());
    double t0 = d.dot(geometry::footOnLine(l, pc.entry_px + prev.edge_start * dir0));
    double t1 = d.dot(geometry::footOnLine(l, pc.entry_px + prev.edge_end * dir0));
    if (t0 > t1) std::swap(t0, t1);
    auto const r0 = refineLineSubpixel(bgr, l, t0, t1, wide);
    if (!r0) return ContourRejection::kWeakEdges;
    auto const r = refineLineSubpixel(bgr, r0->line, t0, t1, p);
    if (!r) return ContourRejection::kWeakEdges;
    if (r->residual_px > p.max_residual_px) return ContourRejection::kResidual;
    ref[s] = *r;
  }
  double const cosang = std::abs(ref[0].line.head<2>().dot(ref[1].line.head<2>()));
  if (cosang < std::cos(p.max_angle_deg * M_PI / 180.0)) return ContourRejection::kNotParallel;
  return ContourRejection::kNone;
}

// The entry on the new axis `ax` (direction `dir`): where it leaves the field of view, at most
// 16 processing px away (a shaft pivoting about its trocar slides along the border), else last
// frame's entry moved onto it.
Eigen::Vector2d trackedEntry(geometry::ImageLine const& ax, Eigen::Vector2d const& dir, Eigen::Vector2d const& prev_entry,
                             FieldOfView const* fov, int scale) {
  Eigen::Vector2d const e0 = geometry::footOnLine(ax, prev_entry);
  if (!fov || fov->mask.empty()) return e0;
  double const sc = std::max(1, scale), off = 0.5 * (sc - 1);
  bool at_edge = false;
  auto const e = walkToEdge(*fov, (e0 - Eigen::Vector2d(off, off)) / sc, dir, 16, &at_edge);
  return e && at_edge ? geometry::footOnLine(ax, *e * sc + Eigen::Vector2d(off, off)) : e0;
}

// The fitted extent of `now` (its lines and edges set) from last frame's, moved by `shift` along
// the axis with the entry: the detection's, cut at the tip (a withdrawal; grown with the tip it
// would take in a wrist in line with the shaft).
void moveExtent(TrackedShaft const& prev, TrackedShaft& now, double shift, double tip_distance) {
  now.edge_start = prev.edge_start + shift;
  now.detected_edge_end = prev.detected_edge_end + shift;
  now.edge_end = std::max(now.edge_start + 0.5 * (now.detected_edge_end - now.edge_start), std::min(tip_distance, now.detected_edge_end));
}

// The detection's shape checks on the followed contour c, and its width against last frame's.
ContourRejection trackedShapeCheck(geometry::ApparentContour const& c, geometry::ApparentContour const& pc,
                                   ContourLinesParams const& p, ContourTrackingParams const& tp) {
  double const len = (c.tip_px - c.entry_px).norm();
  if (len < p.min_length_px) return ContourRejection::kTooShort;
  double const we = widthAt(c, c.entry_px), wt = widthAt(c, c.tip_px);
  // Positive widths at both ends: the lines do not cross between them.
  if (we < p.min_width_px || wt < p.min_width_px) return ContourRejection::kTooThin;
  double const we0 = widthAt(pc, pc.entry_px);
  if (std::abs(we - we0) > tp.max_width_change * we0 + 2.0) return ContourRejection::kWidthJump;
  if (len < p.min_elongation * 0.5 * (we + wt)) return ContourRejection::kNotElongated;
  return ContourRejection::kNone;
}
}  // namespace

TrackingResult trackContour(TrackedShaft const& prev, cv::Mat const& bgr, ContourLinesParams const& p,
                            ContourTrackingParams const& tp, FieldOfView const* fov, int scale) {
  TrackingResult out;
  RefinedLine ref[2];
  out.rejection = refineTrackedLines(prev, bgr, p, tp, ref);
  if (out.rejection != ContourRejection::kNone) return out;
  geometry::ApparentContour const& pc = prev.contour;
  TrackedShaft now;
  geometry::ApparentContour& c = now.contour;
  c = pc;  // ids carried over
  c.lines = {ref[0].line, ref[1].line};
  c.line_covariances = {ref[0].covariance, ref[1].covariance};
  c.line_residual_px = {ref[0].residual_px, ref[1].residual_px};
  c.residual_px = std::sqrt(0.5 * (ref[0].residual_px * ref[0].residual_px + ref[1].residual_px * ref[1].residual_px));
  now.edges = {ref[0].inliers, ref[1].inliers};
  // The new axis, oriented as before, and its entry; last frame's distances along the axis are
  // then measured from the new entry.
  geometry::ImageLine const ax = geometry::imageAxis(c);
  Eigen::Vector2d dir(-ax.y(), ax.x());
  if (dir.dot(axisDirection(pc)) < 0.0) dir = -dir;
  Eigen::Vector2d const entry = trackedEntry(ax, dir, pc.entry_px, fov, scale);
  double const shift = dir.dot(geometry::footOnLine(ax, pc.entry_px) - entry);
  // The tip: last frame's moved onto the new axis, then located on this frame with the
  // detection's colours where it can be.
  double tip_distance = dir.dot(geometry::footOnLine(ax, pc.tip_px) - entry);
  c.entry_px = entry;
  c.tip_px = entry + tip_distance * dir;
  now.tip_colours = prev.tip_colours;
  if (prev.tip_colours && fov && !fov->mask.empty())
    if (auto const tip = locateTipWithColours(bgr, c, now.edges, *prev.tip_colours, fov->mask, scale))
      tip_distance = dir.dot(geometry::footOnLine(ax, *tip) - entry);
  moveExtent(prev, now, shift, tip_distance);
  c.tip_px = entry + tip_distance * dir;
  out.rejection = trackedShapeCheck(c, pc, p, tp);
  if (out.rejection == ContourRejection::kNone) out.shaft = std::move(now);
  return out;
}

}  // namespace endo_guidance::perception
