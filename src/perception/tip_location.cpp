// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/tip_location.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <utility>
#include <vector>

#include "endo_guidance/perception/edge_profile.h"
#include "endo_guidance/perception/image_reduction.h"

namespace endo_guidance::perception {

namespace {
// Two colours of the samples (a black shaft and its metal jaws; tissue in and out of shade), on
// at most about 256 of them: the means of the darker and the brighter, split half-way between
// the 5th and 95th brightness percentiles, then half-way between the two means (two steps of
// k-means in brightness, so a few metal samples among many black ones keep their own colour).
// One when the two are alike, none when the samples are fewer than 8.
std::vector<cv::Vec3f> twoColours(std::vector<cv::Vec3f> const& all) {
  if (all.size() < 8) return {};
  std::size_t const step = all.size() / 256 + 1;
  std::vector<cv::Vec3f> c;
  std::vector<float> b;
  for (std::size_t i = 0; i < all.size(); i += step) c.push_back(all[i]), b.push_back(all[i][0] + all[i][1] + all[i][2]);
  std::vector<float> order = b;
  auto const p5 = order.begin() + order.size() / 20, p95 = order.end() - 1 - order.size() / 20;
  std::nth_element(order.begin(), p5, order.end());
  std::nth_element(p5, p95, order.end());
  float split = 0.5f * (*p5 + *p95);
  cv::Vec3f lo, hi;
  for (int pass = 0; pass < 2; ++pass) {
    lo = hi = cv::Vec3f(0.f, 0.f, 0.f);
    int n_lo = 0, n_hi = 0;
    for (std::size_t i = 0; i < c.size(); ++i) b[i] <= split ? (lo += c[i], ++n_lo) : (hi += c[i], ++n_hi);
    if (n_lo == 0 || n_hi == 0) return {(lo + hi) / static_cast<float>(c.size())};
    lo /= static_cast<float>(n_lo);
    hi /= static_cast<float>(n_hi);
    split = 0.5f * (lo[0] + lo[1] + lo[2] + hi[0] + hi[1] + hi[2]);
  }
  if ((hi - lo).dot(hi - lo) < 1.f) return {0.5f * (lo + hi)};
  return {lo, hi};
}

// The distance from colour x to the nearest of `colours`.
float distanceTo(std::vector<cv::Vec3f> const& colours, cv::Vec3f const& x) {
  float d = std::numeric_limits<float>::infinity();
  for (cv::Vec3f const& c : colours) d = std::min(d, (x - c).dot(x - c));
  return std::sqrt(d);
}
// The instrument's share of a colour x: its distance to the tissue's colours over that plus its
// distance to the instrument's (the segment between its two: a shaft's end blends into its jaws).
// On a blend of tissue and instrument it is the instrument's fraction.
struct Share {
  cv::Vec3f t0, t1, i0, d;  // the tissue's two colours (one twice), the instrument's from i0 to i0 + d
  float inv_span;           // 1 / |d|^2, 0 when the instrument has one colour
  // Over n colours given as planes (b, g, r), 0 where !inside; one loop the compiler vectorises.
  void operator()(float const* __restrict b, float const* __restrict g, float const* __restrict r, std::uint8_t const* __restrict inside,
                  int n, float* __restrict out) const {
    float const t00 = t0[0], t01 = t0[1], t02 = t0[2], t10 = t1[0], t11 = t1[1], t12 = t1[2];
    float const i00 = i0[0], i01 = i0[1], i02 = i0[2], d0 = d[0], d1 = d[1], d2 = d[2], inv = inv_span;
    for (int i = 0; i < n; ++i) {
      float const x0 = b[i], x1 = g[i], x2 = r[i];
      float const a0 = x0 - t00, a1 = x1 - t01, a2 = x2 - t02, b0 = x0 - t10, b1 = x1 - t11, b2 = x2 - t12;
      float const da = a0 * a0 + a1 * a1 + a2 * a2, db = b0 * b0 + b1 * b1 + b2 * b2;
      float const dt = std::sqrt(da < db ? da : db);
      float const y0 = x0 - i00, y1 = x1 - i01, y2 = x2 - i02;
      float const along = (y0 * d0 + y1 * d1 + y2 * d2) * inv;
      float const lambda = along < 0.f ? 0.f : along > 1.f ? 1.f : along;
      float const o0 = y0 - lambda * d0, o1 = y1 - lambda * d1, o2 = y2 - lambda * d2;
      float const di = std::sqrt(o0 * o0 + o1 * o1 + o2 * o2);
      float const sum = dt + di;
      float const share = dt / (sum > 1e-20f ? sum : 1e-20f);
      out[i] = inside[i] != 0 ? share : 0.f;
    }
  }
  float operator()(cv::Vec3f const& x) const {
    float s;
    std::uint8_t const in = 1;
    (*this)(&x[0], &x[1], &x[2], &in, 1, &s);
    return s;
  }
};

// How far along u from e the shaft runs: where the shorter of its two lines' edge points ends.
double shaftEndAlong(std::array<std::vector<Eigen::Vector2d>, 2> const& edges, Eigen::Vector2d const& e, Eigen::Vector2d const& u) {
  double t_end = std::numeric_limits<double>::infinity();
  for (auto const& side : edges) {
    double t = -std::numeric_limits<double>::infinity();
    for (auto const& q : side) t = std::max(t, u.dot(q - e));
    t_end = std::min(t_end, t);
  }
  return t_end;
}

// Marks in `reached` (CV_8U) the samples with share over one half connected (4-neighbours) to the
// seeds in `stack`, which are marked already.
void flood(cv::Mat const& share, cv::Mat& reached, std::vector<cv::Point> stack) {
  while (!stack.empty()) {
    cv::Point const q = stack.back();
    stack.pop_back();
    for (cv::Point const n : {q + cv::Point(1, 0), q - cv::Point(1, 0), q + cv::Point(0, 1), q - cv::Point(0, 1)}) {
      if (n.x < 0 || n.y < 0 || n.x >= share.cols || n.y >= share.rows || reached.at<std::uint8_t>(n) || !(share.at<float>(n) > 0.5f))
        continue;
      reached.at<std::uint8_t>(n) = 1;
      stack.push_back(n);
    }
  }
}
// The colours where the mask (`prob`, over the window's samples) is sure of them, two of each:
// the instrument's (a black shaft's jaws are metal), and the tissue's beside the shaft, outside
// its lines (beyond its end, and between the lines where closed jaws continue them, the mask may
// miss the jaws). false when either is missing or no instrument colour differs from the tissue's
// by min_contrast.
bool coloursOfMask(cv::Mat const& colour, cv::Mat const& prob, cv::Mat const& inside, double back, int half, double dr, double width,
                   double min_contrast, TipColours& out) {
  std::vector<cv::Vec3f> tissue_s, instrument_s;
  for (int r = 0; r < colour.rows; ++r)
    for (int k = 0; k < colour.cols; ++k) {
      if (!inside.at<std::uint8_t>(r, k)) continue;
      float const p = prob.at<float>(r, k);
      if (p >= 0.8f) instrument_s.push_back(colour.at<cv::Vec3f>(r, k));
      else if (p <= 0.2f && k <= back && std::abs(r - half) * dr > 0.5 * width) tissue_s.push_back(colour.at<cv::Vec3f>(r, k));
    }
  std::vector<cv::Vec3f> const tissue = twoColours(tissue_s);
  std::vector<cv::Vec3f> tool;
  for (cv::Vec3f const& m : twoColours(instrument_s))  // (one as the tissue's is the tissue between open jaws)
    if (distanceTo(tissue, m) >= min_contrast) tool.push_back(m);
  if (tissue.empty() || tool.empty()) return false;
  out = {tissue.front(), tissue.back(), tool.front(), tool.back()};
  return true;
}

// locateTipOnFrame() with its colours taken from `instrument` (then set in `colours`), or with
// `colours` as given when `instrument` is null.
std::optional<Eigen::Vector2d> locateTip(cv::Mat const& bgr, geometry::ApparentContour const& c,
                                         std::array<std::vector<Eigen::Vector2d>, 2> const& edges, InstrumentMask const* instrument,
                                         cv::Mat const& fov, int scale, double min_contrast, TipColours& colours) {
  CV_Assert(bgr.type() == CV_8UC3 && fov.type() == CV_8U &&
            (!instrument || instrument->map.type() == CV_32F || instrument->map.type() == CV_8U));
  if (instrument && instrument->map.empty()) return std::nullopt;
  geometry::ImageLine const ax = geometry::imageAxis(c);
  Eigen::Vector2d const e = geometry::footOnLine(ax, c.entry_px), to_tip = geometry::footOnLine(ax, c.tip_px) - e;
  if (!(to_tip.norm() > 1.0) || edges[0].empty() || edges[1].empty()) return std::nullopt;
  Eigen::Vector2d const u = to_tip.normalized(), v(-u.y(), u.x());
  double const t_end = shaftEndAlong(edges, e, u);
  if (!(t_end > 1.0)) return std::nullopt;
  Eigen::Vector2d const end = e + t_end * u;
  double const width = geometry::shaftWidthAt(c, end);
  if (!(width >= 2.0)) return std::nullopt;
  // The window: columns along the axis from a width before the shaft's end to 2.5 widths beyond
  // it; rows across it (the strip between the lines and 0.3 width beyond each, for open jaws).
  // 16 columns and 12 rows per width (every px on a thin shaft); the end is then sought every
  // quarter px along the rows that reach farthest.
  double const dc = std::max(1.0, width / 16.0), dr = std::max(1.0, width / 12.0);
  double const back = width / dc;  // (in columns)
  int const cols = static_cast<int>(std::ceil(3.5 * width / dc)) + 1;
  int const half = static_cast<int>(std::ceil(0.8 * width / dr));
  int const rows = 2 * half + 1;
  // A sample at x (full resolution) for the fine search: whether it lies in the frame and the
  // field of view, and the frame's colour there (bilinear).
  auto sample = [&](Eigen::Vector2d const& x, cv::Vec3f& colour_x) {
    Eigen::Vector2d const q = toProcessing(x, scale);
    int const qx = static_cast<int>(std::lround(q.x())), qy = static_cast<int>(std::lround(q.y()));
    if (!(x.x() >= 0.0 && x.y() >= 0.0 && x.x() < bgr.cols - 1 && x.y() < bgr.rows - 1 && qx >= 0 && qy >= 0 && qx < fov.cols &&
          qy < fov.rows && fov.at<std::uint8_t>(qy, qx) != 0))
      return false;
    bilinearAt(bgr, x.x(), x.y(), colour_x.val);
    return true;
  };
  auto at = [&](double t, double a) { return Eigen::Vector2d(end + t * u + a * v); };  // t, a in px from the shaft's end
  // The window's samples, one warp per image: sample (k, r) lies at at((k - back) dc, (r - half) dr),
  // at toProcessing() of that in the mask and the field of view (bilinear, and nearest).
  Eigen::Vector2d const origin = at(-back * dc, -half * dr);
  cv::Matx23d const to_frame(dc * u.x(), dr * v.x(), origin.x(), dc * u.y(), dr * v.y(), origin.y());
  double const off = 0.5 * (scale - 1);
  cv::Matx23d const to_fov(to_frame(0, 0) / scale, to_frame(0, 1) / scale, (origin.x() - off) / scale,  //
                           to_frame(1, 0) / scale, to_frame(1, 1) / scale, (origin.y() - off) / scale);
  cv::Mat colour8, prob, inside;
  cv::warpAffine(bgr, colour8, to_frame, {cols, rows}, cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_REPLICATE);
  cv::warpAffine(fov, inside, to_fov, {cols, rows}, cv::INTER_NEAREST | cv::WARP_INVERSE_MAP, cv::BORDER_CONSTANT, cv::Scalar(0));
  cv::Mat colour;
  colour8.convertTo(colour, CV_32FC3);
  if (instrument) {
    cv::Matx23d to_mask = to_fov;
    to_mask(0, 2) -= instrument->origin.x;
    to_mask(1, 2) -= instrument->origin.y;
    cv::warpAffine(instrument->map, prob, to_mask, {cols, rows}, cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_CONSTANT, cv::Scalar(0));
    if (prob.type() == CV_8U) prob.convertTo(prob, CV_32F, 1.0 / 255.0);
    if (!coloursOfMask(colour, prob, inside, back, half, dr, width, min_contrast, colours)) return std::nullopt;
  }
  cv::Vec3f const d = colours.tool1 - colours.tool0;
  Share const shareOf{colours.tissue0, colours.tissue1, colours.tool0, d, d.dot(d) > 0.f ? 1.f / d.dot(d) : 0.f};
  // The instrument: the samples of share over one half connected (4-neighbours) to the shaft's end.
  cv::Mat planes[3], share(rows, cols, CV_32F), reached = cv::Mat::zeros(rows, cols, CV_8U);
  cv::split(colour, planes);
  shareOf(planes[0].ptr<float>(), planes[1].ptr<float>(), planes[2].ptr<float>(), inside.ptr<std::uint8_t>(), rows * cols,
          share.ptr<float>());
  std::vector<cv::Point> stack;
  for (int r = 0; r < rows; ++r)
    for (int k = 0; k <= back; ++k)
      // the shaft's end (where the mask is sure of it; without a mask, the colours alone decide)
      if (share.at<float>(r, k) > 0.5f && std::abs(r - half) * dr <= 0.35 * width && (!instrument || prob.at<float>(r, k) >= 0.8f)) {
        reached.at<std::uint8_t>(r, k) = 1;
        stack.emplace_back(k, r);
      }
  if (stack.empty()) return std::nullopt;
  flood(share, reached, std::move(stack));
  // The farthest reach: the rows whose last sample reached is farthest, each sought every quarter
  // px from there to the next column for where the share crosses one half (linear between samples).
  int k_far = -1;
  std::vector<int> last(rows, -1);
  for (int r = 0; r < rows; ++r) {
    for (int k = cols - 1; k >= 0 && last[r] < 0; --k)
      if (reached.at<std::uint8_t>(r, k)) last[r] = k;
    k_far = std::max(k_far, last[r]);
  }
  if (k_far == cols - 1) return std::nullopt;  // runs on past the jaws' reach
  double best = -1e300;
  int best_row = half;
  int const steps = std::max(1, static_cast<int>(std::ceil(4.0 * dc)));
  for (int r = 0; r < rows; ++r) {
    if (last[r] != k_far) continue;
    double const t0 = (k_far - back) * dc, a = (r - half) * dr;
    float prev = share.at<float>(r, k_far);
    double t = t0 + dc;  // (the next column's sample, if no finer one crosses before it)
    for (int i = 1; i <= steps; ++i) {
      double const ti = t0 + dc * i / steps;
      cv::Vec3f col;
      float const si = i == steps ? share.at<float>(r, k_far + 1) : sample(at(ti, a), col) ? shareOf(col) : 0.f;
      if (si <= 0.5f) {
        t = ti - (dc / steps) * (0.5f - si) / std::max(1e-6f, prev - si);
        break;
      }
      prev = si;
    }
    if (t > best) best = t, best_row = r;
  }
  return at(best, (best_row - half) * dr);
}

}  // namespace

std::optional<Eigen::Vector2d> locateTipOnFrame(cv::Mat const& bgr, geometry::ApparentContour const& c,
                                                std::array<std::vector<Eigen::Vector2d>, 2> const& edges, InstrumentMask const& instrument,
                                                cv::Mat const& fov, int scale, double min_contrast, TipColours* colours) {
  TipColours taken;
  auto const tip = locateTip(bgr, c, edges, &instrument, fov, scale, min_contrast, taken);
  if (tip && colours) *colours = taken;
  return tip;
}

std::optional<Eigen::Vector2d> locateTipWithColours(cv::Mat const& bgr, geometry::ApparentContour const& c,
                                                    std::array<std::vector<Eigen::Vector2d>, 2> const& edges, TipColours const& colours,
                                                    cv::Mat const& fov, int scale) {
  TipColours given = colours;
  return locateTip(bgr, c, edges, nullptr, fov, scale, 0.0, given);
}

}  // namespace endo_guidance::perception
