// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/contour_tracking.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include "endo_guidance/perception/colour_feature.h"

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

double chromaNearest(cv::Mat const& bgr, Eigen::Vector2d const& q, bool* ok) {
  int const x = static_cast<int>(std::lround(q.x())), y = static_cast<int>(std::lround(q.y()));
  *ok = x >= 0 && y >= 0 && x < bgr.cols && y < bgr.rows;
  if (!*ok) return 0.0;
  cv::Vec3b const& px = bgr.at<cv::Vec3b>(y, x);
  return ColourFeature::chroma(px[0], px[1], px[2]);
}

double median(std::vector<double>& v) {
  std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

// The tip along the axis (distance from `entry`), measured as the region's end is in the
// detection: where the low chroma between the lines (shaft, jaws, and their highlights) gives way
// to tissue for `run` px. The threshold is halfway between the chroma inside the fitted part and
// beside it; the search covers t_pred +- reach. nullopt without contrast or samples.
std::optional<double> tipAlongAxis(cv::Mat const& bgr, geometry::ApparentContour const& c, Eigen::Vector2d const& entry,
                                   Eigen::Vector2d const& dir, double edge_start, double edge_end, double t_pred, double reach) {
  Eigen::Vector2d const nrm(-dir.y(), dir.x());
  auto widthAtT = [&](double t) { return widthAt(c, entry + t * dir); };
  // Across the axis at t: the lowest of the middle and +-1/4 width (the jaws, narrower than the
  // shaft, need not cover all three).
  auto inside = [&](double t, bool* ok) {
    double const w = widthAtT(t), q = 0.25 * std::max(w, 0.0);
    Eigen::Vector2d const m = entry + t * dir;
    double lo = std::numeric_limits<double>::infinity();
    for (double o : {-q, 0.0, q}) {
      bool in = false;
      double const v = chromaNearest(bgr, m + o * nrm, &in);
      if (in) lo = std::min(lo, v);
    }
    *ok = std::isfinite(lo);
    return *ok ? lo : 0.0;
  };
  std::vector<double> vin, vout;
  for (double t = edge_start; t <= edge_end; t += 4.0) {
    bool ok = false;
    double const v = inside(t, &ok);
    if (ok) vin.push_back(v);
    double const w = std::max(widthAtT(t), 0.0);
    Eigen::Vector2d const m = entry + t * dir;
    for (double side : {-1.0, 1.0}) {
      double const o = side * (w + 4.0);  // half a width and 4 px beyond each line
      double const u = chromaNearest(bgr, m + o * nrm, &ok);
      if (ok) vout.push_back(u);
    }
  }
  if (vin.size() < 5 || vout.size() < 5) return std::nullopt;
  double const lo = median(vin), hi = median(vout);
  if (hi - lo < 8.0) return std::nullopt;  // no chroma contrast to measure the end by
  double const thr = 0.5 * (lo + hi);
  int const run = 3;
  int above = 0;
  double const t0 = std::max(edge_start, t_pred - reach), t1 = t_pred + reach;
  for (double t = t0; t <= t1; t += 1.0) {
    bool ok = false;
    double const v = inside(t, &ok);
    if (!ok || v > thr) {
      if (++above >= run) return std::max(t0, t - run);  // the last shaft-like sample
    } else {
      above = 0;
    }
  }
  return t1;  // pushed in beyond the search: the rest next frame
}

}  // namespace

TrackedShaft startTrack(geometry::ApparentContour const& contour, std::array<std::vector<Eigen::Vector2d>, 2> const& edges,
                        cv::Mat const& bgr, ContourTrackingParams const& tp) {
  TrackedShaft s;
  s.contour = contour;
  s.edges = edges;
  Eigen::Vector2d const dir = axisDirection(contour);
  edgeExtent(edges, contour.entry_px, dir, &s.edge_start, &s.edge_end);
  s.tip_distance = std::max(0.0, dir.dot(contour.tip_px - contour.entry_px));
  // (the detection follows each edge to its end, which can lie a fraction of a px beyond the
  // tip the region gave: the tracked extent is cut at the tip)
  s.edge_end = std::min(s.edge_end, s.tip_distance);
  s.detected_edge_end = s.edge_end;
  double const reach = std::max(tp.tip_reach_px, 1.5 * widthAt(contour, contour.entry_px + s.tip_distance * dir));
  s.chroma_tip = tipAlongAxis(bgr, contour, contour.entry_px, dir, s.edge_start, s.edge_end, s.tip_distance, reach)
                     .value_or(s.tip_distance);
  s.tip_offset = s.tip_distance - s.chroma_tip;
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

// The tip and the fitted extent of `now` (its lines, edges and entry set), from last frame's
// distances moved by `shift` along the axis (the entry moved, the tip does not move with it).
// The tip moves as the end of the shaft-like interior along the axis moves (the end of the edges
// jumps where highlights break them and a wrist continues them), from where the detection put it
// (tip_offset); without contrast, or beyond the search window, it keeps its position.
void followTip(TrackedShaft const& prev, TrackedShaft& now, cv::Mat const& bgr, ContourTrackingParams const& tp,
               Eigen::Vector2d const& entry, Eigen::Vector2d const& dir, double shift, int scale) {
  geometry::ApparentContour const& c = now.contour;
  double const edge_start = prev.edge_start + shift, edge_end = prev.edge_end + shift;
  double const detected_edge_end = prev.detected_edge_end + shift;
  double const reach = std::max(tp.tip_reach_px, 1.5 * widthAt(c, entry + (prev.tip_distance + shift) * dir));
  // (searched about the tip, as at the detection: the search returns the first end it meets)
  auto const tip = tipAlongAxis(bgr, c, entry, dir, edge_start, edge_end, prev.tip_distance + shift, reach);
  now.chroma_tip = tip ? *tip : prev.chroma_tip + shift;
  now.tip_offset = prev.tip_offset;
  now.tip_distance = now.chroma_tip + now.tip_offset;
  // As in the detection (refineContour), beyond the end of the straight sides only the jaws may
  // follow, up to 2.5 widths: not pale membranes, as achromatic as metal.
  double t_start = 0.0, t_sides = 0.0;
  edgeExtent(now.edges, entry, dir, &t_start, &t_sides);
  double const end_width = std::max(widthAt(c, entry + t_sides * dir), 2.0 * std::max(1, scale));
  now.tip_distance = std::min(now.tip_distance, std::max(t_sides + 2.5 * end_width, prev.tip_distance + shift));
  // The fitted extent is the detection's, cut at the tip (a withdrawal): grown with the tip it
  // takes in a wrist in line with the shaft, shrunk by the tip's steps it ratchets down on a
  // still image.
  now.edge_start = edge_start;
  now.detected_edge_end = detected_edge_end;
  now.edge_end = std::max(edge_start + 0.5 * (detected_edge_end - edge_start), std::min(now.tip_distance, detected_edge_end));
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
  followTip(prev, now, bgr, tp, entry, dir, shift, scale);
  c.entry_px = entry;
  c.tip_px = entry + now.tip_distance * dir;
  out.rejection = trackedShapeCheck(c, pc, p, tp);
  if (out.rejection == ContourRejection::kNone) out.shaft = std::move(now);
  return out;
}

}  // namespace endo_guidance::perception
