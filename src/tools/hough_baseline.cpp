// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "hough_baseline.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>

namespace endo_guidance::tools {

using geometry::ApparentContour;
using geometry::ImageLine;

namespace {

struct Segment {
  Eigen::Vector2d p0, p1, d;  // ends, unit direction p0 -> p1
  ImageLine line;             // normalised, a^2 + b^2 = 1
  double len;
};

double dist(ImageLine const& l, Eigen::Vector2d const& q) { return l.head<2>().dot(q) + l.z(); }

// The chroma at pixel q (nearest), or -1 outside the image.
int chromaNear(cv::Mat const& chroma, Eigen::Vector2d const& q) {
  int const x = static_cast<int>(std::lround(q.x())), y = static_cast<int>(std::lround(q.y()));
  if (x < 0 || y < 0 || x >= chroma.cols || y >= chroma.rows) return -1;
  return chroma.at<std::uint8_t>(y, x);
}

double median(std::vector<int>& v) {
  if (v.empty()) return -1.0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// The point of line `s` (through its segment) at abscissa t along the unit direction a.
Eigen::Vector2d at(Segment const& s, Eigen::Vector2d const& a, double t) {
  double const c = s.d.dot(a);  // (near +-1: the pair is near-parallel)
  return s.p0 + (t - a.dot(s.p0)) / c * s.d;
}

}  // namespace

std::vector<ApparentContour> detectShaftsHough(cv::Mat const& bgr, HoughBaselineParams const& p) {
  CV_Assert(bgr.type() == CV_8UC3);
  cv::Mat ch[3], mx, mn, chroma, smooth, edges;
  cv::split(bgr, ch);
  mx = cv::max(cv::max(ch[0], ch[1]), ch[2]);
  mn = cv::min(cv::min(ch[0], ch[1]), ch[2]);
  cv::subtract(mx, mn, chroma);
  cv::GaussianBlur(chroma, smooth, cv::Size(0, 0), p.blur_sigma);
  cv::Canny(smooth, edges, p.canny_low, p.canny_high);
  std::vector<cv::Vec4i> raw;
  cv::HoughLinesP(edges, raw, 1.0, CV_PI / 360.0, p.hough_threshold, p.min_segment_px, p.max_gap_px);
  std::vector<Segment> seg;
  for (auto const& r : raw) {
    Segment s;
    s.p0 = Eigen::Vector2d(r[0], r[1]);
    s.p1 = Eigen::Vector2d(r[2], r[3]);
    s.len = (s.p1 - s.p0).norm();
    if (s.len < 1.0) continue;
    s.d = (s.p1 - s.p0) / s.len;
    s.line = *geometry::lineThrough(s.p0, s.p1);  // (|p1 - p0| >= 1)
    seg.push_back(s);
  }
  double const cos_max = std::cos(p.max_pair_angle_deg * M_PI / 180.0);
  // Candidate pairs: near-parallel, at a shaft's width, overlapping, around a grey strip.
  struct Pair {
    int i, j;
    double overlap;
  };
  std::vector<Pair> pairs;
  for (int i = 0; i < static_cast<int>(seg.size()); ++i)
    for (int j = i + 1; j < static_cast<int>(seg.size()); ++j) {
      Segment const &A = seg[i], &B = seg[j];
      if (std::abs(A.d.dot(B.d)) < cos_max) continue;
      double const w0 = dist(A.line, B.p0), w1 = dist(A.line, B.p1);
      if (w0 * w1 <= 0.0) continue;
      double const w = 0.5 * std::abs(w0 + w1);
      if (w < p.min_width_px || w > p.max_width_px) continue;
      Eigen::Vector2d const a = A.d;
      double const ta0 = std::min(a.dot(A.p0), a.dot(A.p1)), ta1 = std::max(a.dot(A.p0), a.dot(A.p1));
      double const tb0 = std::min(a.dot(B.p0), a.dot(B.p1)), tb1 = std::max(a.dot(B.p0), a.dot(B.p1));
      double const lo = std::max(ta0, tb0), hi = std::min(ta1, tb1);
      if (hi - lo < p.min_overlap * std::min(A.len, B.len)) continue;
      std::vector<int> in, outA, outB;
      for (double t = lo; t <= hi; t += 3.0) {
        Eigen::Vector2d const xa = at(A, a, t), xb = at(B, a, t);
        Eigen::Vector2d const u = (xb - xa).normalized();
        int const ci = chromaNear(chroma, 0.5 * (xa + xb)), ca = chromaNear(chroma, xa - 4.0 * u), cb = chromaNear(chroma, xb + 4.0 * u);
        if (ci >= 0) in.push_back(ci);
        if (ca >= 0) outA.push_back(ca);
        if (cb >= 0) outB.push_back(cb);
      }
      double const mi = median(in), ma = median(outA), mb = median(outB);
      if (mi < 0.0 || ma < 0.0 || mb < 0.0 || mi > p.max_strip_ratio * std::min(ma, mb)) continue;
      pairs.push_back({i, j, hi - lo});
    }
  std::sort(pairs.begin(), pairs.end(), [](Pair const& x, Pair const& y) { return x.overlap > y.overlap; });
  std::vector<bool> used(seg.size(), false);
  std::vector<ApparentContour> out;
  for (auto const& pr : pairs) {
    if (used[pr.i] || used[pr.j]) continue;
    Segment const* side[2] = {&seg[pr.i], &seg[pr.j]};
    Eigen::Vector2d const a = side[0]->d;
    // Each side: its segment and the collinear ones (Hough splits an edge into several).
    double T0 = 1e300, T1 = -1e300;
    ImageLine fitted[2];
    bool ok = true;
    for (int s = 0; s < 2 && ok; ++s) {
      double t0 = 1e300, t1 = -1e300;
      for (std::size_t k = 0; k < seg.size(); ++k) {
        Segment const& q = seg[k];
        if (std::abs(q.d.dot(side[s]->d)) < cos_max || std::abs(dist(side[s]->line, q.p0)) > p.collinear_px ||
            std::abs(dist(side[s]->line, q.p1)) > p.collinear_px)
          continue;
        used[k] = true;
        t0 = std::min({t0, a.dot(q.p0), a.dot(q.p1)});
        t1 = std::max({t1, a.dot(q.p0), a.dot(q.p1)});
      }
      T0 = std::min(T0, t0);
      T1 = std::max(T1, t1);
      // Least-squares refit on the Canny edge pixels near the side.
      std::vector<int> idx;  // edge pixels (y * cols + x) within the band, each once
      Eigen::Vector2d const n = side[s]->line.head<2>();
      for (double t = t0; t <= t1; t += 1.0)
        for (double o = -std::ceil(p.refit_band_px); o <= std::ceil(p.refit_band_px); o += 1.0) {
          Eigen::Vector2d const q = at(*side[s], a, t) + o * n;
          int const x = static_cast<int>(std::lround(q.x())), y = static_cast<int>(std::lround(q.y()));
          if (x < 0 || y < 0 || x >= edges.cols || y >= edges.rows || !edges.at<std::uint8_t>(y, x)) continue;
          if (std::abs(dist(side[s]->line, Eigen::Vector2d(x, y))) > p.refit_band_px) continue;
          idx.push_back(y * edges.cols + x);
        }
      std::sort(idx.begin(), idx.end());
      idx.erase(std::unique(idx.begin(), idx.end()), idx.end());
      std::vector<cv::Point2f> pts;
      for (int k : idx) pts.emplace_back(static_cast<float>(k % edges.cols), static_cast<float>(k / edges.cols));
      if (pts.size() < 10) {
        ok = false;
        break;
      }
      cv::Vec4f f;
      cv::fitLine(pts, f, cv::DIST_L2, 0, 0.01, 0.01);
      Eigen::Vector2d const c(f[2], f[3]);
      fitted[s] = *geometry::lineThrough(c, c + Eigen::Vector2d(f[0], f[1]));  // (fitLine's direction is a unit vector)
    }
    if (!ok) continue;
    // Normals toward the other side.
    for (int s = 0; s < 2; ++s) {
      Segment const& o = *side[1 - s];
      if (dist(fitted[s], 0.5 * (o.p0 + o.p1)) < 0.0) fitted[s] = -fitted[s];
    }
    ApparentContour c;
    c.lines = {fitted[0], fitted[1]};
    ImageLine const axis = geometry::imageAxis(c);
    Eigen::Vector2d const e0 = geometry::footOnLine(axis, at(*side[0], a, T0)), e1 = geometry::footOnLine(axis, at(*side[0], a, T1));
    auto border = [&](Eigen::Vector2d const& q) {
      return std::min({q.x(), q.y(), bgr.cols - 1 - q.x(), bgr.rows - 1 - q.y()});
    };
    // One shaft once: a pair about the axis of one found already (the specular stripe's edges,
    // an edge split by Hough) is not another shaft.
    bool dup = false;
    Eigen::Vector2d const m = 0.5 * (e0 + e1);
    for (auto const& o : out) {
      ImageLine const oa = geometry::imageAxis(o);
      dup |= std::abs(oa.head<2>().dot(axis.head<2>())) >= cos_max && std::abs(dist(oa, m)) < p.duplicate_px;
    }
    if (dup) continue;
    bool const first = border(e0) <= border(e1);
    if (std::min(border(e0), border(e1)) > p.max_entry_border_px) continue;  // instruments enter across the border
    c.entry_px = first ? e0 : e1;
    c.tip_px = first ? e1 : e0;
    Eigen::Vector2d const dir = (c.tip_px - c.entry_px).normalized();
    Eigen::Vector2d const left(dir.y(), -dir.x());
    if (c.lines[0].head<2>().dot(left) > 0.0) std::swap(c.lines[0], c.lines[1]);  // the left line's normal points right
    out.push_back(c);
  }
  return out;
}

}  // namespace endo_guidance::tools
