// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/mask_line_pairs.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>

#include "endo_guidance/perception/image_reduction.h"
#include "endo_guidance/perception/line_fit.h"

namespace endo_guidance::perception {

namespace {

constexpr int kAngleBins = 360;       // oriented normals, 1 deg
constexpr int kVoteSpreadBins = 6;    // a point votes for the lines within 6 deg of its gradient
constexpr double kMinGradient = 0.05; // probability per px: a weaker step is no side
constexpr double kGatePx = 2.0;       // a side's points lie this close to its line
constexpr double kMaxTurnDeg = 20.0;  // ... with their gradient this close to its normal
constexpr int kEdgeMarginPx = 3;      // the mask's outline along the view's edge is no side
constexpr double kBeyondPx = 3.0;     // where the instrument goes on this far outside, the outline is no side
constexpr double kMinFacingCos = 0.5; // a part's side points face its axis within 60 deg (not its ends)
constexpr double kPartInStrip = 0.9;   // a part that is one shaft lies this much between its sides
constexpr double kPartMaxAngleDeg = 35.0;  // between a part's own sides (the annotated stills' p95: 33 deg)
constexpr double kAtEdgePx = 5.0;      // a side's end this far inside the margin is at the view's edge

struct Edgel {
  Eigen::Vector2d x;
  Eigen::Vector2d g;  // unit gradient, into the mask
  double angle;       // its direction
  int component;      // the mask's connected part it bounds
  bool side;          // the network calls it a side (always, without a side map)
};

struct Side {
  Eigen::Vector2d n;  // unit normal into the mask
  double rho = 0.0;   // n . x = rho on the line
  std::vector<Eigen::Vector2d> points;
  Eigen::Vector2d along() const { return {-n.y(), n.x()}; }
};

// The boundary points of the mask (p >= 1/2 after a light smoothing) with their gradient and
// connected part (`labels`, CV_32S, 0 off the mask). A point where `beyond` (the instrument's
// probability; may be empty) stays at 1/2 or more just outside is where the shaft meets its own
// jaws, not a side. Each is marked a side where `sides` (the network's side probability; may be
// empty: every point) is 1/2 or more.
std::vector<Edgel> maskEdgels(cv::Mat const& prob, cv::Mat const& beyond, cv::Mat const& sides, FieldOfView const& fov,
                              cv::Mat& smooth, cv::Mat& labels) {
  cv::GaussianBlur(prob, smooth, cv::Size(), 1.0);
  cv::Mat gx, gy, mask, inner;
  cv::Sobel(smooth, gx, CV_32F, 1, 0, 3, 1.0 / 8.0);
  cv::Sobel(smooth, gy, CV_32F, 0, 1, 3, 1.0 / 8.0);
  cv::compare(smooth, 0.5, mask, cv::CMP_GE);
  cv::erode(mask, inner, cv::Mat());
  cv::connectedComponents(mask, labels, 8, CV_32S);
  std::vector<Edgel> out;
  for (int y = 0; y < mask.rows; ++y)
    for (int x = 0; x < mask.cols; ++x) {
      if (!mask.at<std::uint8_t>(y, x) || inner.at<std::uint8_t>(y, x) || nearViewEdge(fov, cv::Point(x, y), kEdgeMarginPx)) continue;
      double const u = gx.at<float>(y, x), v = gy.at<float>(y, x), g = std::hypot(u, v);
      if (g < kMinGradient) continue;
      if (!beyond.empty()) {
        int const bx = static_cast<int>(std::lround(x - kBeyondPx * u / g)), by = static_cast<int>(std::lround(y - kBeyondPx * v / g));
        if (bx >= 0 && by >= 0 && bx < beyond.cols && by < beyond.rows && beyond.at<float>(by, bx) >= 0.5f) continue;
      }
      // Sub-pixel: out along the gradient to p = 1/2 (first order), at most 1.5 px.
      double const out_px = std::clamp((smooth.at<float>(y, x) - 0.5) / g, 0.0, 1.5);
      Eigen::Vector2d const q(x - out_px * u / g, y - out_px * v / g);
      bool const side = sides.empty() || sides.at<float>(std::clamp(static_cast<int>(std::lround(q.y())), 0, sides.rows - 1),
                                                         std::clamp(static_cast<int>(std::lround(q.x())), 0, sides.cols - 1)) >= 0.5f;
      out.push_back({q, Eigen::Vector2d(u / g, v / g), std::atan2(v, u), labels.at<int>(y, x), side});
    }
  return out;
}

// Hough accumulator over (normal angle, rho), each point voting about its own gradient only;
// returns its peaks (angle bin, rho) strongest first: bins whose votes, summed over 3 rho bins
// (rounding splits a line's votes between neighbours), are at least min_votes and the most
// within +-4 rho bins and the votes' spread in angle (so that the spread of a long side forms no
// peaks of its own). Only the bins voted for are visited.
std::vector<std::pair<int, int>> houghPeaks(std::vector<Edgel> const& edgels, cv::Size size, double min_votes) {
  int const offset = static_cast<int>(std::ceil(std::hypot(size.width, size.height))) + 5, R = 2 * offset + 1;
  std::vector<float> acc(static_cast<std::size_t>(kAngleBins) * R, 0.f);
  std::vector<int> voted;
  double const bin = 2.0 * M_PI / kAngleBins;
  std::array<double, kAngleBins> c{}, s{};
  for (int k = 0; k < kAngleBins; ++k) c[k] = std::cos(k * bin), s[k] = std::sin(k * bin);
  for (Edgel const& e : edgels) {
    int const k0 = static_cast<int>(std::lround(e.angle / bin));
    for (int dk = -kVoteSpreadBins; dk <= kVoteSpreadBins; ++dk) {
      int const k = ((k0 + dk) % kAngleBins + kAngleBins) % kAngleBins;
      int const i = k * R + static_cast<int>(std::lround(e.x.x() * c[k] + e.x.y() * s[k])) + offset;
      if (acc[i] == 0.f) voted.push_back(i);
      acc[i] += 1.f;
    }
  }
  auto summed = [&](int k, int r) { return acc[k * R + r - 1] + acc[k * R + r] + acc[k * R + r + 1]; };
  std::vector<std::pair<float, std::pair<int, int>>> found;
  for (int i : voted) {
    int const k = i / R, r = i % R;
    float const v = summed(k, r);
    if (v < 3.0 * min_votes) continue;
    bool peak = true;
    for (int dk = -kVoteSpreadBins; dk <= kVoteSpreadBins && peak; ++dk)
      for (int dr = -4, kk = ((k + dk) % kAngleBins + kAngleBins) % kAngleBins; dr <= 4 && peak; ++dr)
        peak = summed(kk, r + dr) <= v;
    if (peak) found.push_back({v, {k, r - offset}});
  }
  std::sort(found.begin(), found.end(), [](auto const& a, auto const& b) { return a.first > b.first; });
  std::vector<std::pair<int, int>> out;
  for (auto const& f : found) out.push_back(f.second);
  return out;
}

// The total least-squares line through the points (fitLineLS()) as (n, rho), its normal on n's side.
void fitTls(std::vector<Eigen::Vector2d> const& pts, Eigen::Vector2d& n, double& rho) {
  auto const l = fitLineLS(pts);
  if (!l) return;
  double const sign = l->head<2>().dot(n) < 0.0 ? -1.0 : 1.0;
  n = sign * l->head<2>();
  rho = -sign * l->z();
}

// The side a peak stands for: the unused points near it, refined; none unless the network's side
// map calls min_points of them a side (a tool's head, an occluder's edge, the network's noise).
bool sideOfPeak(double angle, double rho, std::vector<Edgel> const& edgels, std::vector<char>& used, int min_points, Side& side) {
  Eigen::Vector2d n(std::cos(angle), std::sin(angle));
  double const cos_turn = std::cos(kMaxTurnDeg * M_PI / 180.0);
  std::vector<int> sel;
  auto select = [&](double gate) {
    sel.clear();
    for (std::size_t i = 0; i < edgels.size(); ++i)
      if (!used[i] && std::abs(n.dot(edgels[i].x) - rho) <= gate && n.dot(edgels[i].g) > cos_turn) sel.push_back(static_cast<int>(i));
    return static_cast<int>(sel.size()) >= min_points;
  };
  if (!select(kGatePx + 0.5)) return false;
  for (int it = 0; it < 2; ++it) {
    std::vector<Eigen::Vector2d> pts;
    for (int i : sel) pts.push_back(edgels[i].x);
    fitTls(pts, n, rho);
    if (!select(kGatePx)) return false;
  }
  if (std::count_if(sel.begin(), sel.end(), [&](int i) { return edgels[i].side; }) < min_points) return false;
  // Every point on the line: the pieces of a side broken by an occluder or a crossing shaft.
  side.points.clear();
  for (int i : sel) {
    used[i] = 1;
    side.points.push_back(edgels[i].x);
  }
  side.n = n;
  fitTls(side.points, side.n, side.rho);
  return true;
}

double median(std::vector<double> v) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
  return v[v.size() / 2];
}

// Sides a and b as a shaft: facing, overlapping, apart and with mask between them. The pair with
// its support, width and the ends of the overlap on its axis; support 0 when they are none. With
// `fov` (a mask part's own sides), the sides of a stub that both run into the view's edge face
// each other up to the farther one; without (the Hough's sides, which may run along a tool's head
// to the border), the overlap ends where either side does.
MaskLinePair pairSides(Side const& a, Side const& b, cv::Mat const& smooth, FieldOfView const* fov, double cos_max_angle,
                       int min_points, double min_width, double min_fill) {
  MaskLinePair p;
  if (a.n.dot(b.n) > -cos_max_angle) return p;
  Eigen::Vector2d const u = a.along();
  struct Extent {
    double t0, t1;     // along u
    bool edge0, edge1; // its ends there at the view's edge
  };
  auto extent = [&](Side const& s) {
    Eigen::Vector2d q0 = s.points.front(), q1 = q0;
    for (auto const& q : s.points) {
      if (u.dot(q) < u.dot(q0)) q0 = q;
      if (u.dot(q) > u.dot(q1)) q1 = q;
    }
    auto atEdge = [&](Eigen::Vector2d const& q) { return fov && depthAt(*fov, q) <= kEdgeMarginPx + kAtEdgePx; };
    return Extent{u.dot(q0), u.dot(q1), atEdge(q0), atEdge(q1)};
  };
  Extent const ea = extent(a), eb = extent(b);
  double lo = std::max(ea.t0, eb.t0), hi = std::min(ea.t1, eb.t1);  // where the two face each other
  if (hi <= lo) return p;
  std::vector<double> wb, wa;
  auto widths = [&](double& w, double& w2) {  // each side's median distance from the other's line
    wb.clear(), wa.clear();
    for (auto const& q : b.points)
      if (double const t = u.dot(q); t >= lo && t <= hi) wb.push_back(a.n.dot(q) - a.rho);
    for (auto const& q : a.points)
      if (double const t = u.dot(q); t >= lo && t <= hi) wa.push_back(b.n.dot(q) - b.rho);
    w = median(wb), w2 = median(wa);
    return wa.size() >= 3 && wb.size() >= 3;
  };
  double w = 0.0, w2 = 0.0;
  bool measured = hi - lo >= min_points && widths(w, w2);
  // Sides that face each other over less than half their distance are a blob's, or the two ends
  // of a shaft's piece; unless both run into the view's edge there: the view cut them, not the
  // shaft (a stub entering obliquely across the border), and they face each other up to the farther.
  bool const cut0 = ea.edge0 && eb.edge0, cut1 = ea.edge1 && eb.edge1;
  if ((!measured || hi - lo < 0.5 * std::max(w, w2)) && (cut0 || cut1)) {
    if (cut0) lo = std::min(ea.t0, eb.t0);
    if (cut1) hi = std::max(ea.t1, eb.t1);
    measured = hi - lo >= min_points && widths(w, w2);
  }
  if (!measured || !(w >= min_width && w2 >= min_width) || hi - lo < 0.5 * std::max(w, w2)) return p;
  // The strip between them in the view: samples at 20 stations along, 5 across (its middle 60 %).
  int inside = 0, total = 0;
  for (int i = 0; i < 20; ++i)
    for (int j = 0; j < 5; ++j) {
      double const t = lo + (hi - lo) * i / 19.0, f = 0.2 + 0.15 * j;
      Eigen::Vector2d const x = u * t + a.n * (a.rho + f * w);
      int const xi = static_cast<int>(std::lround(x.x())), yi = static_cast<int>(std::lround(x.y()));
      bool const in_view = fov ? insideView(*fov, x) : xi >= 0 && yi >= 0 && xi < smooth.cols && yi < smooth.rows;
      if (!in_view) continue;
      ++total;
      if (smooth.at<float>(yi, xi) >= 0.5f) ++inside;
    }
  double const fill = total > 0 ? static_cast<double>(inside) / total : 0.0;
  if (fill < min_fill) return p;
  p.sides[0] = {Eigen::Vector3d(a.n.x(), a.n.y(), -a.rho), a.points};
  p.sides[1] = {Eigen::Vector3d(b.n.x(), b.n.y(), -b.rho), b.points};
  // A side is where it faces the other: beyond, a side's line runs on along a jaw or another shaft.
  for (auto& side : p.sides) {
    auto& pts = side.points;
    pts.erase(std::remove_if(pts.begin(), pts.end(), [&](Eigen::Vector2d const& q) { return u.dot(q) < lo || u.dot(q) > hi; }), pts.end());
  }
  p.width = 0.5 * (w + w2);
  p.support = static_cast<double>(std::min(wa.size(), wb.size())) * fill;
  p.entry = u * lo + a.n * (a.rho + 0.5 * w);
  p.far = u * hi + a.n * (a.rho + 0.5 * w);
  return p;
}

// A side of a mask part from its points (`idx`): an LMedS line ([Rousseeuw87]), then the points
// within kGatePx of it whose gradient turns from its normal by under kMaxTurnDeg, refined by total
// least squares; false unless min_points and half of the points are on it (not a straight side) and
// the network's side map calls min_points of them a side.
bool sideOfPoints(std::vector<int> const& idx, std::vector<Edgel> const& edgels, int min_points, ContourLinesParams const& p, Side& side) {
  if (static_cast<int>(idx.size()) < min_points) return false;
  std::vector<Eigen::Vector2d> pts;
  Eigen::Vector2d g = Eigen::Vector2d::Zero();
  for (int i : idx) pts.push_back(edgels[i].x), g += edgels[i].g;
  auto const r = fitLineLMedS(pts, p.lmeds_samples, p.seed);
  if (!r) return false;
  Eigen::Vector2d n = r->line.head<2>();
  double rho = -r->line.z();
  if (n.dot(g) < 0.0) n = -n, rho = -rho;
  double const cos_turn = std::cos(kMaxTurnDeg * M_PI / 180.0);
  int sides = 0;
  for (int it = 0; it < 3; ++it) {
    pts.clear(), sides = 0;
    for (int i : idx)
      if (std::abs(n.dot(edgels[i].x) - rho) <= kGatePx && n.dot(edgels[i].g) > cos_turn) pts.push_back(edgels[i].x), sides += edgels[i].side;
    if (static_cast<int>(pts.size()) < min_points || 2 * pts.size() < idx.size()) return false;
    fitTls(pts, n, rho);
  }
  if (sides < min_points) return false;
  side.n = n;
  side.rho = rho;
  side.points = std::move(pts);
  return true;
}

// Whether side b lies on side a's line: the same normal within 3 deg, its points within kGatePx.
bool onLine(Side const& a, Side const& b) {
  if (a.n.dot(b.n) < std::cos(3.0 * M_PI / 180.0)) return false;
  std::vector<double> d;
  for (auto const& q : b.points) d.push_back(std::abs(a.n.dot(q) - a.rho));
  return median(d) <= kGatePx;
}

// One side through the points of both, refined by total least squares.
Side joinSides(Side const& a, Side const& b) {
  Side s = a;
  s.points.insert(s.points.end(), b.points.begin(), b.points.end());
  fitTls(s.points, s.n, s.rho);
  return s;
}

// The pairs of the mask's parts that are one shaft each: a part whose outline, split by its
// principal axis (second moments), is one straight side on each half facing the axis (its ends
// left out). These pairs hold whatever the angle between the sides (a shaft near the lens narrows
// fast toward its tip) and wherever the view's border or the jaws cut the part; parts without one
// (shafts that touch or cross) are the Hough transform's. Marks the pairs' points used.
std::vector<MaskLinePair> partPairs(std::vector<Edgel> const& edgels, cv::Mat const& labels, cv::Mat const& smooth, FieldOfView const& fov,
                                    std::vector<char>& used, int min_points, double min_width, ContourLinesParams const& p) {
  double max_label = 0.0;
  cv::minMaxLoc(labels, nullptr, &max_label);
  std::vector<std::vector<int>> members(static_cast<std::size_t>(max_label) + 1);
  for (std::size_t i = 0; i < edgels.size(); ++i) members[edgels[i].component].push_back(static_cast<int>(i));
  double const cos_max = std::cos(kPartMaxAngleDeg * M_PI / 180.0);
  std::vector<MaskLinePair> out;
  std::vector<std::array<Side, 2>> sides;  // per pair in out
  for (std::size_t k = 1; k < members.size(); ++k) {
    if (static_cast<int>(members[k].size()) < 2 * min_points) continue;
    cv::Rect box(cv::Point(labels.cols, labels.rows), cv::Point(0, 0));
    for (int i : members[k]) box |= cv::Rect(static_cast<int>(edgels[i].x.x()) - 2, static_cast<int>(edgels[i].x.y()) - 2, 5, 5);
    box &= cv::Rect(0, 0, labels.cols, labels.rows);
    cv::Moments const m = cv::moments(labels(box) == static_cast<int>(k), true);
    if (m.m00 <= 0.0) continue;
    Eigen::Vector2d const c(box.x + m.m10 / m.m00, box.y + m.m01 / m.m00);
    double const th = 0.5 * std::atan2(2.0 * m.mu11, m.mu20 - m.mu02);
    Eigen::Vector2d const across(-std::sin(th), std::cos(th));
    std::array<std::vector<int>, 2> half;
    for (int i : members[k]) {
      double const d = across.dot(edgels[i].x - c), facing = across.dot(edgels[i].g);
      if (d < 0.0 && facing > kMinFacingCos) half[0].push_back(i);
      else if (d > 0.0 && facing < -kMinFacingCos) half[1].push_back(i);
    }
    Side a, b;
    if (!sideOfPoints(half[0], edgels, min_points, p, a) || !sideOfPoints(half[1], edgels, min_points, p, b)) continue;
    MaskLinePair pair = pairSides(a, b, smooth, &fov, cos_max, min_points, min_width, p.min_fill);
    if (pair.support <= 0.0) continue;
    // The part is this shaft only when it lies between the two lines (shafts that touch or cross
    // fill the lines' strip and more).
    int inside = 0;
    for (int y = box.y; y < box.br().y; ++y)
      for (int x = box.x; x < box.br().x; ++x)
        if (labels.at<int>(y, x) == static_cast<int>(k) && a.n.dot(Eigen::Vector2d(x, y)) - a.rho >= -kGatePx &&
            b.n.dot(Eigen::Vector2d(x, y)) - b.rho >= -kGatePx)
          ++inside;
    if (inside < kPartInStrip * m.m00) continue;
    for (int i : members[k])
      if (std::abs(a.n.dot(edgels[i].x) - a.rho) <= kGatePx || std::abs(b.n.dot(edgels[i].x) - b.rho) <= kGatePx) used[i] = 1;
    // Parts on the same two lines are one shaft broken by an occluder (a suture, a jaw across it).
    bool merged = false;
    for (std::size_t j = 0; j < out.size() && !merged; ++j) {
      auto& [c, d] = sides[j];
      bool const straight = onLine(a, c) && onLine(b, d), crossed = onLine(a, d) && onLine(b, c);
      if (!straight && !crossed) continue;
      Side& ca = straight ? c : d;
      Side& db = straight ? d : c;
      Side ja = joinSides(ca, a), jb = joinSides(db, b);
      MaskLinePair joined = pairSides(ja, jb, smooth, &fov, cos_max, min_points, min_width, p.min_fill);
      if (joined.support <= 0.0) continue;
      ca = std::move(ja), db = std::move(jb);
      out[j] = std::move(joined);
      merged = true;
    }
    if (merged) continue;
    out.push_back(std::move(pair));
    sides.push_back({std::move(a), std::move(b)});
  }
  return out;
}

// Where the mask goes on from x along dir (steps of 1 px, gaps up to 3 px) until it leaves the
// view; returns the last mask point and whether the view's edge was reached.
std::pair<Eigen::Vector2d, bool> followMask(Eigen::Vector2d x, Eigen::Vector2d const& dir, cv::Mat const& smooth, FieldOfView const& fov) {
  Eigen::Vector2d last = x;
  for (int gap = 0, step = 0; gap <= 3 && step < smooth.cols + smooth.rows; ++step) {
    x += dir;
    if (!insideView(fov, x) || depthAt(fov, x) <= kEdgeMarginPx) return {last, depthAt(fov, last) <= kEdgeMarginPx + 4};
    int const xi = static_cast<int>(std::lround(x.x())), yi = static_cast<int>(std::lround(x.y()));
    if (smooth.at<float>(yi, xi) >= 0.5f) last = x, gap = 0;
    else ++gap;
  }
  return {last, false};
}

// The entry: the end of the pair whose mask reaches the view's edge (moved there); of a shaft
// whose mask reaches it at both ends (it crosses the view), the wider end: the nearer to the lens,
// as a shaft seen from its trocar's side narrows toward its tip (the shape check's max_widening);
// else the end nearer to the edge.
void setEntry(MaskLinePair& p, cv::Mat const& smooth, FieldOfView const& fov) {
  Eigen::Vector2d const u = (p.far - p.entry).normalized();
  auto const [back, back_edge] = followMask(p.entry, -u, smooth, fov);
  auto const [ahead, ahead_edge] = followMask(p.far, u, smooth, fov);
  auto width = [&](Eigen::Vector2d const& x) { return p.sides[0].line.dot(x.homogeneous()) + p.sides[1].line.dot(x.homogeneous()); };
  bool const ahead_wider = width(ahead) > width(back);
  if (back_edge && (!ahead_edge || !ahead_wider)) {
    p.entry = back;
  } else if (ahead_edge) {
    p.far = p.entry;
    p.entry = ahead;
  } else if (depthAt(fov, p.far) < depthAt(fov, p.entry)) {
    std::swap(p.entry, p.far);
  }
}

}  // namespace

std::vector<MaskLinePair> findMaskLinePairs(cv::Mat const& probability, FieldOfView const& fov, int scale,
                                            ContourLinesParams const& params, cv::Mat const& beyond, cv::Mat const& side_probability) {
  CV_Assert(probability.type() == CV_32F && probability.size() == fov.mask.size() && scale >= 1);
  CV_Assert(beyond.empty() || (beyond.type() == CV_32F && beyond.size() == probability.size()));
  CV_Assert(side_probability.empty() || (side_probability.type() == CV_32F && side_probability.size() == probability.size()));
  thread_local cv::Mat smooth, labels;  // (their buffers kept from call to call: no page faults per frame)
  std::vector<Edgel> const edgels = maskEdgels(probability, beyond, side_probability, fov, smooth, labels);
  int const min_points = std::max(3, params.min_side_points);
  double const min_width = params.min_width_px / scale;
  std::vector<char> used(edgels.size(), 0);
  std::vector<MaskLinePair> out = partPairs(edgels, labels, smooth, fov, used, min_points, min_width, params);
  std::vector<Side> sides;
  double const bin = 2.0 * M_PI / kAngleBins;
  for (auto const& [k, rho] : houghPeaks(edgels, probability.size(), 0.8 * min_points)) {
    Side s;
    if (sideOfPeak(k * bin, rho, edgels, used, min_points, s)) sides.push_back(std::move(s));
  }
  double const cos_max = std::cos(params.max_angle_deg * M_PI / 180.0);
  struct Candidate {
    MaskLinePair pair;
    std::size_t a, b;
  };
  std::vector<Candidate> candidates;
  for (std::size_t i = 0; i < sides.size(); ++i)
    for (std::size_t j = i + 1; j < sides.size(); ++j)
      if (MaskLinePair p = pairSides(sides[i], sides[j], smooth, nullptr, cos_max, min_points, min_width, params.min_fill); p.support > 0.0)
        candidates.push_back({std::move(p), i, j});
  std::stable_sort(candidates.begin(), candidates.end(), [](auto const& x, auto const& y) { return x.pair.support > y.pair.support; });
  std::vector<char> taken(sides.size(), 0);
  for (Candidate& c : candidates) {
    if (taken[c.a] || taken[c.b]) continue;
    taken[c.a] = taken[c.b] = 1;
    out.push_back(std::move(c.pair));
  }
  for (MaskLinePair& p : out) setEntry(p, smooth, fov);
  return out;
}

SideFit sideFitOf(MaskLinePair const& pair, int scale) {
  SideFit fit;
  double const s = scale, h = 0.5 * (s - 1.0);
  for (int k = 0; k < 2; ++k) {
    Eigen::Vector3d const& l = pair.sides[k].line;
    fit.lines[k] = Eigen::Vector3d(l.x(), l.y(), s * l.z() - h * (l.x() + l.y()));
    for (auto const& q : pair.sides[k].points) fit.points[k].push_back(toFullRes(q, scale));
    fit.inliers += static_cast<int>(pair.sides[k].points.size());
  }
  fit.entry = toFullRes(pair.entry, scale);
  fit.far = toFullRes(pair.far, scale);
  return fit;
}

std::optional<Region> regionOf(MaskLinePair const& pair, cv::Mat const& mask) {
  Eigen::Vector2d const u = (pair.far - pair.entry).normalized(), v(-u.y(), u.x());
  auto onSide = [&](int k, double t) {  // side k on the perpendicular to the axis at t, 2 px out
    Eigen::Vector3d const& l = pair.sides[k].line;
    Eigen::Vector2d const c = pair.entry + t * u;
    double const nv = l.head<2>().dot(v);
    double a = std::abs(nv) > 0.1 ? -(l.head<2>().dot(c) + l.z()) / nv : 0.0;
    a += a < 0.0 ? -2.0 : 2.0;
    Eigen::Vector2d const x = c + a * v;
    return cv::Point(static_cast<int>(std::lround(x.x())), static_cast<int>(std::lround(x.y())));
  };
  double const t0 = -2.0 * pair.width - 4.0, t1 = (pair.far - pair.entry).norm() + 2.5 * pair.width + 2.0;
  std::vector<cv::Point> quad{onSide(0, t0), onSide(0, t1), onSide(1, t1), onSide(1, t0)};
  // (within the strip's box only: a pair costs its own pixels, not the frame's)
  cv::Rect const roi = cv::boundingRect(quad) & cv::Rect(cv::Point(0, 0), mask.size());
  if (roi.empty()) return std::nullopt;
  for (cv::Point& q : quad) q -= roi.tl();
  cv::Mat strip = cv::Mat::zeros(roi.size(), CV_8U);
  cv::fillConvexPoly(strip, quad, 255);
  strip &= mask(roi);
  std::vector<std::vector<cv::Point>> contours;
  cv::findContours(strip, contours, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_NONE, roi.tl());
  if (contours.empty()) return std::nullopt;
  Region r;
  r.boundary = std::move(*std::max_element(contours.begin(), contours.end(), [](auto const& a, auto const& b) { return a.size() < b.size(); }));
  r.box = cv::boundingRect(r.boundary);
  r.area = cv::countNonZero(strip(r.box - roi.tl()));
  r.seed = cv::Point(static_cast<int>(std::lround(pair.entry.x())), static_cast<int>(std::lround(pair.entry.y())));
  return r;
}

}  // namespace endo_guidance::perception
