// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/contour_checks.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

#include "endo_guidance/perception/colour_feature.h"
#include "endo_guidance/perception/edge_profile.h"
#include "endo_guidance/perception/image_reduction.h"

namespace endo_guidance::perception {

char const* toString(ContourRejection r) {
  switch (r) {
    case ContourRejection::kNone: return "accepted";
    case ContourRejection::kTooFewPoints: return "too few boundary points on a side";
    case ContourRejection::kNotStraight: return "a side is not a straight line";
    case ContourRejection::kNotParallel: return "the two sides are not near-parallel";
    case ContourRejection::kTooShort: return "shaft too short";
    case ContourRejection::kTooThin: return "shaft too thin";
    case ContourRejection::kCrossing: return "the sides cross or do not enclose the region";
    case ContourRejection::kWeakEdges: return "too few sub-pixel edge points";
    case ContourRejection::kResidual: return "sub-pixel edge residual too large";
    case ContourRejection::kNotElongated: return "not elongated";
    case ContourRejection::kNotFilled: return "region does not fill the strip between its lines";
    case ContourRejection::kAlongBorder: return "runs along the field-of-view border instead of into the view";
    case ContourRejection::kLowContrast: return "not less chromatic than the tissue beside it (full resolution)";
    case ContourRejection::kWidthJump: return "tracked shaft's width changed too much since the last frame";
    case ContourRejection::kDuplicate: return "a shaft already found";
    case ContourRejection::kWidens: return "widens toward the tip more than a shaft can";
    case ContourRejection::kGlare: return "mostly glare between its lines (near white, achromatic)";
    case ContourRejection::kTipOnBorder: return "its tip is on the field-of-view border (a band across the view, not a shaft entering it)";
    case ContourRejection::kNotContinued: return "found beyond another shaft, but not continued on its other side (not a crossing shaft)";
    case ContourRejection::kNotShaftAtEntry: return "where it enters, the network sees jaws rather than shaft (a tool's head, not its shaft)";
  }
  return "unknown";
}

// The steepest crossing of the view's border by the contour's axis or either line, as the sine
// of its angle with the border (the inward unit normal dotted with axis_dir, the direction into
// the view): each line is followed back from its foot of `entry` to where it leaves the view,
// within two widths (w_proc, processing px); the axis falls back to the entry itself.
double enteringSine(geometry::ApparentContour const& c, FieldOfView const& fov, Eigen::Vector2d const& entry,
                    Eigen::Vector2d const& axis_dir, double w_proc, int scale) {
  int const kmax = static_cast<int>(std::ceil(std::max(10.0, 2.0 * w_proc)));
  double best = -1.0;
  for (int k = 0; k < 3; ++k) {
    geometry::ImageLine const l = k == 0 ? geometry::imageAxis(c) : c.lines[static_cast<std::size_t>(k - 1)];
    Eigen::Vector2d d(-l.y(), l.x());
    if (k == 0 || d.norm() < 1e-12) d = axis_dir;
    d.normalize();
    if (d.dot(axis_dir) < 0.0) d = -d;
    std::optional<Eigen::Vector2d> q = walkToEdge(fov, toProcessing(geometry::footOnLine(l, entry), scale), d, kmax);
    if (!q) {
      if (k > 0) continue;  // a line that never meets the view near the entry crosses no border there
      q = toProcessing(entry, scale);  // no exit found: the seed
    }
    Eigen::Vector2d const g =
        depthGradient(fov, cv::Point(static_cast<int>(std::lround(q->x())), static_cast<int>(std::lround(q->y()))));
    if (g.norm() <= 1e-6) return 1.0;  // no border in reach: nothing to run along
    best = std::max(best, g.normalized().dot(axis_dir));
  }
  return best;
}

AcrossSamples acrossContour(cv::Mat const& bgr, geometry::ApparentContour const& c) {
  CV_Assert(bgr.type() == CV_8UC3);
  AcrossSamples s;
  Eigen::Vector2d const e = c.entry_px, ax = c.tip_px - c.entry_px;
  auto at = [&](Eigen::Vector2d const& q, std::vector<float>& v, bool inside) {
    int const x = static_cast<int>(std::lround(q.x())), y = static_cast<int>(std::lround(q.y()));
    if (x < 0 || y < 0 || x >= bgr.cols || y >= bgr.rows) return;
    cv::Vec3b const& px = bgr.at<cv::Vec3b>(y, x);
    v.push_back(edgeChannel(px[0], px[1], px[2]));
    if (inside && std::max({px[0], px[1], px[2]}) >= 230 && ColourFeature::chroma(px[0], px[1], px[2]) < 30.f) ++s.glare;
  };
  for (int i = 1; i < 40; ++i) {
    Eigen::Vector2d const m = e + (i / 40.0) * ax;
    Eigen::Vector2d const f0 = geometry::footOnLine(c.lines[0], m), f1 = geometry::footOnLine(c.lines[1], m);
    double const d = std::max(3.0, 0.3 * (f1 - f0).norm());
    for (double f : {0.25, 0.5, 0.75}) at(f0 + f * (f1 - f0), s.inside, true);
    at(f0 - d * c.lines[0].head<2>(), s.outside[0], false);  // the normals point into the shaft
    at(f1 - d * c.lines[1].head<2>(), s.outside[1], false);
  }
  return s;
}

bool mostlyGlare(AcrossSamples const& s, ContourLinesParams const& p) {
  return !s.inside.empty() && s.glare > p.max_glare_fraction * static_cast<double>(s.inside.size());
}

bool mostlyGlare(cv::Mat const& bgr, geometry::ApparentContour const& contour, ContourLinesParams const& p) {
  return mostlyGlare(acrossContour(bgr, contour), p);
}


bool fillsStrip(geometry::ApparentContour const& c, Region const& region, Eigen::Vector2d const& axis_dir, double width, int scale,
                double min_fill, double min_inside) {
  Eigen::Vector2d const entry = c.entry_px, tip = c.tip_px;
  auto toBox = [&](Eigen::Vector2d const& full, cv::Rect const& box) {
    Eigen::Vector2d const ps = toProcessing(full, scale);
    return cv::Point(static_cast<int>(std::lround(ps.x())) - box.x, static_cast<int>(std::lround(ps.y())) - box.y);
  };
  cv::Rect const box = region.box + cv::Size(4, 4) - cv::Point(2, 2);  // the region's box with a margin
  cv::Mat reg = cv::Mat::zeros(box.size(), CV_8U), quad = cv::Mat::zeros(box.size(), CV_8U);
  std::vector<std::vector<cv::Point>> poly{region.boundary};
  cv::fillPoly(reg, poly, 255, cv::LINE_8, 0, -box.tl());
  std::vector<cv::Point> q;
  for (Eigen::Vector2d const& foot : geometry::shaftQuad(c, entry, tip)) q.push_back(toBox(foot, box));
  cv::fillConvexPoly(quad, q, 255);
  // The nearby slab: the same axial extent, four widths to each side. Region pixels beyond the tip
  // or far to the side (a touching or crossing instrument) do not count against the shaft.
  cv::Mat slab = cv::Mat::zeros(box.size(), CV_8U);
  Eigen::Vector2d const nrm(-axis_dir.y(), axis_dir.x());
  double const half = 4.0 * width + 4.0 * scale;
  std::vector<cv::Point> const sp{toBox(entry + nrm * half, box), toBox(tip + nrm * half, box), toBox(tip - nrm * half, box),
                                  toBox(entry - nrm * half, box)};
  cv::fillConvexPoly(slab, sp, 255);
  double const nq = cv::countNonZero(quad), nr = cv::countNonZero(reg & slab), both = cv::countNonZero(quad & reg);
  return !(nq <= 0 || nr <= 0 || both < min_fill * nq || both < min_inside * nr);
}

}  // namespace endo_guidance::perception
