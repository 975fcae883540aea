// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/tip_location.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <opencv2/imgproc.hpp>
#include <vector>

#include "endo_guidance/perception/image_reduction.h"

namespace endo_guidance::perception {

namespace {
// Two colours of the samples: k-means from a split at the median brightness (deterministic), on
// at most about 150 of them (a wide shaft's window has thousands); one when they are alike, none
// when they are fewer than 8.
std::vector<cv::Vec3f> twoColours(std::vector<cv::Vec3f> const& all) {
  if (all.size() < 8) return {};
  std::vector<cv::Vec3f> colours;
  std::size_t const step = all.size() / 150 + 1;
  for (std::size_t i = 0; i < all.size(); i += step) colours.push_back(all[i]);
  cv::Mat const samples(static_cast<int>(colours.size()), 3, CV_32F, colours.data());
  cv::Mat brightness;
  cv::reduce(samples, brightness, 1, cv::REDUCE_SUM);
  cv::Mat sorted;
  cv::sort(brightness, sorted, cv::SORT_EVERY_COLUMN | cv::SORT_ASCENDING);
  float const mid = sorted.at<float>(sorted.rows / 2);
  cv::Mat labels(samples.rows, 1, CV_32S), centres;
  for (int i = 0; i < samples.rows; ++i) labels.at<int>(i) = brightness.at<float>(i) > mid ? 1 : 0;
  if (cv::countNonZero(labels) < 4 || cv::countNonZero(labels) > samples.rows - 4) {
    cv::Mat m;
    cv::reduce(samples, m, 0, cv::REDUCE_AVG);
    return {cv::Vec3f(m.ptr<float>())};
  }
  cv::kmeans(samples, 2, labels, cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 10, 0.5), 1,
             cv::KMEANS_USE_INITIAL_LABELS, centres);
  return {cv::Vec3f(centres.ptr<float>(0)), cv::Vec3f(centres.ptr<float>(1))};
}

// The bilinear B, G, R of the frame at (x, y), which lies in [0, cols - 1) x [0, rows - 1).
cv::Vec3f bilinearColour(cv::Mat const& bgr, double x, double y) {
  int const x0 = static_cast<int>(x), y0 = static_cast<int>(y);
  float const fx = static_cast<float>(x - x0), fy = static_cast<float>(y - y0);
  cv::Vec3b const* a = bgr.ptr<cv::Vec3b>(y0) + x0;
  cv::Vec3b const* b = bgr.ptr<cv::Vec3b>(y0 + 1) + x0;
  cv::Vec3f c;
  for (int ch = 0; ch < 3; ++ch)
    c[ch] = (1.f - fy) * ((1.f - fx) * a[0][ch] + fx * a[1][ch]) + fy * ((1.f - fx) * b[0][ch] + fx * b[1][ch]);
  return c;
}

// The distance from colour x to the nearest of `colours`.
float distanceTo(std::vector<cv::Vec3f> const& colours, cv::Vec3f const& x) {
  float d = std::numeric_limits<float>::infinity();
  for (cv::Vec3f const& c : colours) d = std::min(d, (x - c).dot(x - c));
  return std::sqrt(d);
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
  // The shaft's end: where the shorter of its two lines' edge points ends.
  double t_end = std::numeric_limits<double>::infinity();
  for (auto const& side : edges) {
    double t = -std::numeric_limits<double>::infinity();
    for (auto const& q : side) t = std::max(t, u.dot(q - e));
    t_end = std::min(t_end, t);
  }
  if (!(t_end > 1.0)) return std::nullopt;
  Eigen::Vector2d const end = e + t_end * u;
  double const width = geometry::shaftWidthAt(c, end);
  if (!(width >= 2.0)) return std::nullopt;
  // The window: columns along the axis from a width before the shaft's end to 2.5 widths beyond
  // it; rows across it (the strip between the lines and 0.3 width beyond each, for open jaws).
  // Every px on a thin shaft; a wide one, near the lens, at 48 columns and 24 rows per width.
  double const dc = std::max(1.0, width / 48.0), dr = std::max(1.0, width / 24.0);
  double const back = width / dc;  // (in columns)
  int const cols = static_cast<int>(std::ceil(3.5 * width / dc)) + 1;
  int const half = static_cast<int>(std::ceil(0.8 * width / dr));
  int const rows = 2 * half + 1;
  // Each sample: the frame's colour (bilinear), the mask (bilinear, processing scale) and whether
  // it lies in the field of view and the frame (a window past them is out).
  cv::Mat colour(rows, cols, CV_32FC3), prob(rows, cols, CV_32F), inside(rows, cols, CV_8U);
  for (int r = 0; r < rows; ++r)
    for (int k = 0; k < cols; ++k) {
      Eigen::Vector2d const x = end + (k - back) * dc * u + (r - half) * dr * v;
      Eigen::Vector2d const q = toProcessing(x, scale);
      int const qx = static_cast<int>(std::floor(q.x())), qy = static_cast<int>(std::floor(q.y()));
      bool const in = x.x() >= 0.0 && x.y() >= 0.0 && x.x() < bgr.cols - 1 && x.y() < bgr.rows - 1 && qx >= 0 && qy >= 0 &&
                      qx < fov.cols - 1 && qy < fov.rows - 1 && fov.at<std::uint8_t>(static_cast<int>(std::lround(q.y())),
                                                                                   static_cast<int>(std::lround(q.x()))) != 0;
      inside.at<std::uint8_t>(r, k) = in;
      if (!in) {
        colour.at<cv::Vec3f>(r, k) = cv::Vec3f(0.f, 0.f, 0.f);
        prob.at<float>(r, k) = 0.5f;
        continue;
      }
      colour.at<cv::Vec3f>(r, k) = bilinearColour(bgr, x.x(), x.y());
      float const fx = static_cast<float>(q.x() - qx), fy = static_cast<float>(q.y() - qy);
      float const* p0 = instrument.ptr<float>(qy) + qx;
      float const* p1 = instrument.ptr<float>(qy + 1) + qx;
      prob.at<float>(r, k) = (1.f - fy) * ((1.f - fx) * p0[0] + fx * p0[1]) + fy * ((1.f - fx) * p1[0] + fx * p1[1]);
    }
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
  cv::Mat share(rows, cols, CV_32F), reached = cv::Mat::zeros(rows, cols, CV_8U);
  std::vector<cv::Point> stack;
  for (int r = 0; r < rows; ++r)
    for (int k = 0; k < cols; ++k) {
      cv::Vec3f const& x = colour.at<cv::Vec3f>(r, k);
      float const lambda = span > 0.f ? std::clamp((x - i0).dot(i1 - i0) / span, 0.f, 1.f) : 0.f;
      float const dt = distanceTo(tissue, x), di = std::sqrt((x - i0 - lambda * (i1 - i0)).dot(x - i0 - lambda * (i1 - i0)));
      float const s = inside.at<std::uint8_t>(r, k) && dt + di > 0.f ? dt / (dt + di) : 0.f;
      share.at<float>(r, k) = s;
      if (s > 0.5f && k <= back && std::abs(r - half) * dr <= 0.35 * width && prob.at<float>(r, k) >= 0.8f) {  // the shaft's end
        reached.at<std::uint8_t>(r, k) = 1;
        stack.emplace_back(k, r);
      }
    }
  if (stack.empty()) return std::nullopt;
  while (!stack.empty()) {
    cv::Point const q = stack.back();
    stack.pop_back();
    for (cv::Point const n : {q + cv::Point(1, 0), q - cv::Point(1, 0), q + cv::Point(0, 1), q - cv::Point(0, 1)}) {
      if (n.x < 0 || n.y < 0 || n.x >= cols || n.y >= rows || reached.at<std::uint8_t>(n) || !(share.at<float>(n) > 0.5f)) continue;
      reached.at<std::uint8_t>(n) = 1;
      stack.push_back(n);
    }
  }
  // The farthest reach, sub-pixel: where the share crosses one half beyond the last sample reached.
  double best = -1.0;
  int best_row = half;
  for (int r = 0; r < rows; ++r)
    for (int k = cols - 1; k >= 0; --k) {
      if (!reached.at<std::uint8_t>(r, k)) continue;
      if (k == cols - 1) return std::nullopt;  // runs on past the jaws' reach
      float const a = share.at<float>(r, k), b = share.at<float>(r, k + 1);
      double const t = k + (a - 0.5) / std::max(1e-6, static_cast<double>(a - b));
      if (t > best) best = t, best_row = r;
      break;
    }
  return end + (best - back) * dc * u + (best_row - half) * dr * v;
}

}  // namespace endo_guidance::perception
