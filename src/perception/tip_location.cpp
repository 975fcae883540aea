// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/tip_location.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
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
  std::vector<float> sorted = b;
  std::sort(sorted.begin(), sorted.end());
  float split = 0.5f * (sorted[sorted.size() / 20] + sorted[sorted.size() - 1 - sorted.size() / 20]);
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
}  // namespace

std::optional<Eigen::Vector2d> locateTipOnFrame(cv::Mat const& bgr, geometry::ApparentContour const& c,
                                                std::array<std::vector<Eigen::Vector2d>, 2> const& edges, cv::Mat const& instrument,
                                                cv::Mat const& fov, int scale, double min_contrast) {
  CV_Assert(bgr.type() == CV_8UC3 && instrument.type() == CV_32F && fov.type() == CV_8U && instrument.size() == fov.size());
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
  // A sample at x (full resolution): whether it lies in the field of view and the frame (a window
  // past them is out), the frame's colour (bilinear) and the mask (bilinear, processing scale).
  auto sample = [&](Eigen::Vector2d const& x, cv::Vec3f& colour_x, float& prob_x) {
    Eigen::Vector2d const q = toProcessing(x, scale);
    int const qx = static_cast<int>(std::floor(q.x())), qy = static_cast<int>(std::floor(q.y()));
    if (!(x.x() >= 0.0 && x.y() >= 0.0 && x.x() < bgr.cols - 1 && x.y() < bgr.rows - 1 && qx >= 0 && qy >= 0 && qx < fov.cols - 1 &&
          qy < fov.rows - 1 && fov.at<std::uint8_t>(static_cast<int>(std::lround(q.y())), static_cast<int>(std::lround(q.x()))) != 0))
      return false;
    bilinearAt(bgr, x.x(), x.y(), colour_x.val);
    float const fx = static_cast<float>(q.x() - qx), fy = static_cast<float>(q.y() - qy);
    float const* p0 = instrument.ptr<float>(qy) + qx;
    float const* p1 = instrument.ptr<float>(qy + 1) + qx;
    prob_x = (1.f - fy) * ((1.f - fx) * p0[0] + fx * p0[1]) + fy * ((1.f - fx) * p1[0] + fx * p1[1]);
    return true;
  };
  auto at = [&](double t, double a) { return Eigen::Vector2d(end + t * u + a * v); };  // t, a in px from the shaft's end
  cv::Mat colour(rows, cols, CV_32FC3, cv::Scalar::all(0)), prob(rows, cols, CV_32F, cv::Scalar(0.5)), inside(rows, cols, CV_8U);
  for (int r = 0; r < rows; ++r)
    for (int k = 0; k < cols; ++k)
      inside.at<std::uint8_t>(r, k) = sample(at((k - back) * dc, (r - half) * dr), colour.at<cv::Vec3f>(r, k), prob.at<float>(r, k));
  // The colours where the mask is sure of them, two of each: the instrument's (a black shaft's
  // jaws are metal), and the tissue's beside the shaft, outside its lines (beyond its end, and
  // between the lines where closed jaws continue them, the mask may miss the jaws).
  std::vector<cv::Vec3f> tissue_s, instrument_s;
  for (int r = 0; r < rows; ++r)
    for (int k = 0; k < cols; ++k) {
      if (!inside.at<std::uint8_t>(r, k)) continue;
      float const p = prob.at<float>(r, k);
      if (p >= 0.8f) instrument_s.push_back(colour.at<cv::Vec3f>(r, k));
      else if (p <= 0.2f && k <= back && std::abs(r - half) * dr > 0.5 * width) tissue_s.push_back(colour.at<cv::Vec3f>(r, k));
    }
  std::vector<cv::Vec3f> const tissue = twoColours(tissue_s);
  std::vector<cv::Vec3f> tool;
  for (cv::Vec3f const& m : twoColours(instrument_s))  // (one as the tissue's is the tissue between open jaws)
    if (distanceTo(tissue, m) >= min_contrast) tool.push_back(m);
  if (tissue.empty() || tool.empty()) return std::nullopt;
  cv::Vec3f const i0 = tool.front(), i1 = tool.back();
  float const span = (i1 - i0).dot(i1 - i0);
  // The instrument's share of each sample: its distance to the tissue's colours over that plus
  // its distance to the instrument's (the segment between its two: a shaft's end blends into its
  // jaws). On a blend of tissue and instrument it is the instrument's fraction; its part
  // connected to the shaft's end (4-neighbours, share over one half) is the instrument.
  auto shareOf = [&](cv::Vec3f const& x) {
    float const lambda = span > 0.f ? std::clamp((x - i0).dot(i1 - i0) / span, 0.f, 1.f) : 0.f;
    cv::Vec3f const off = x - i0 - lambda * (i1 - i0);
    float const dt = distanceTo(tissue, x), di = std::sqrt(off.dot(off));
    return dt + di > 0.f ? dt / (dt + di) : 0.f;
  };
  cv::Mat share(rows, cols, CV_32F), reached = cv::Mat::zeros(rows, cols, CV_8U);
  std::vector<cv::Point> stack;
  for (int r = 0; r < rows; ++r)
    for (int k = 0; k < cols; ++k) {
      float const s = inside.at<std::uint8_t>(r, k) ? shareOf(colour.at<cv::Vec3f>(r, k)) : 0.f;
      share.at<float>(r, k) = s;
      if (s > 0.5f && k <= back && std::abs(r - half) * dr <= 0.35 * width && prob.at<float>(r, k) >= 0.8f) {  // the shaft's end
        reached.at<std::uint8_t>(r, k) = 1;
        stack.emplace_back(k, r);
      }
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
      float p = 0.f;
      float const si = i == steps ? share.at<float>(r, k_far + 1) : sample(at(ti, a), col, p) ? shareOf(col) : 0.f;
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

}  // namespace endo_guidance::perception
