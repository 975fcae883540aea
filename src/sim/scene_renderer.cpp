// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/sim/scene_renderer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <random>

namespace endo_guidance::sim {

namespace {

// Smooth random field in [0, 1]: random coarse grid upsampled bicubically.
cv::Mat smoothField(int w, int h, int cells, std::mt19937_64& rng) {
  cv::Mat coarse(cells * h / w + 2, cells + 2, CV_32F);
  std::uniform_real_distribution<float> U(0.f, 1.f);
  for (int y = 0; y < coarse.rows; ++y)
    for (int x = 0; x < coarse.cols; ++x) coarse.at<float>(y, x) = U(rng);
  cv::Mat f;
  cv::resize(coarse, f, cv::Size(w, h), 0, 0, cv::INTER_CUBIC);
  cv::normalize(f, f, 0.0, 1.0, cv::NORM_MINMAX);
  return f;
}

float clamp01(double v) { return static_cast<float>(std::clamp(v, 0.0, 1.0)); }

// Paints the convex quad q (px) in colour col over img with each pixel's coverage (the product of
// the box-filtered coverages of its four half-planes, as the shaft's silhouette), and label 2
// (jaws) where that is at least one half.
void fillQuad(cv::Mat& img, cv::Mat* labels, std::array<Eigen::Vector2d, 4> const& q, cv::Vec3f const& col) {
  Eigen::Vector2d const centre = 0.25 * (q[0] + q[1] + q[2] + q[3]);
  std::array<Eigen::Vector3d, 4> edge;  // normalised lines, positive inside
  for (int i = 0; i < 4; ++i) {
    Eigen::Vector2d const a = q[i], b = q[(i + 1) % 4];
    Eigen::Vector3d l(a.y() - b.y(), b.x() - a.x(), a.x() * b.y() - a.y() * b.x());
    double const n = l.head<2>().norm();
    if (!(n > 1e-9)) return;
    l /= n;
    edge[i] = l.dot(centre.homogeneous()) < 0.0 ? Eigen::Vector3d(-l) : l;
  }
  double x0 = q[0].x(), x1 = x0, y0 = q[0].y(), y1 = y0;
  for (auto const& p : q) x0 = std::min(x0, p.x()), x1 = std::max(x1, p.x()), y0 = std::min(y0, p.y()), y1 = std::max(y1, p.y());
  int const c0 = std::max(0, static_cast<int>(std::floor(x0)) - 1), c1 = std::min(img.cols - 1, static_cast<int>(std::ceil(x1)) + 1);
  int const r0 = std::max(0, static_cast<int>(std::floor(y0)) - 1), r1 = std::min(img.rows - 1, static_cast<int>(std::ceil(y1)) + 1);
  for (int y = r0; y <= r1; ++y)
    for (int x = c0; x <= c1; ++x) {
      Eigen::Vector3d const p(x, y, 1.0);
      float cov = 1.f;
      for (auto const& l : edge) cov *= clamp01(0.5 + l.dot(p));
      if (cov <= 0.f) continue;
      cv::Vec3f& dst = img.at<cv::Vec3f>(y, x);
      dst = dst * (1.f - cov) + col * cov;
      if (labels && cov >= 0.5f) labels->at<std::uint8_t>(y, x) = 2;
    }
}

// The angle (rad) of each jaw to the axis in frame k.
double jawOpening(SyntheticView const& v, int k) { return 0.15 + 0.1 * std::sin(0.2 * k + v.instrument); }
}  // namespace

SceneRenderer::SceneRenderer(int width, int height, RenderOptions const& o) : width_(width), height_(height), options_(o) {
  std::mt19937_64 rng(o.seed);
  cv::Mat const hue = smoothField(width, height, 6, rng);      // red <-> yellow (fat)
  cv::Mat const shade = smoothField(width, height, 4, rng);    // illumination
  cv::Mat const fine = smoothField(width, height, 40, rng);    // fine texture
  cv::Mat const memb = smoothField(width, height, 5, rng);     // membranes
  tissue_.create(height, width, CV_32FC3);
  cv::Vec3f const red(70, 60, 175), yellow(70, 165, 215), white(205, 200, 225);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      float const t = std::pow(hue.at<float>(y, x), 1.5f);
      cv::Vec3f c = red * (1 - t) + yellow * t;
      if (o.membranes) {
        float const m = clamp01((memb.at<float>(y, x) - 0.72) / 0.15) * 0.7f;  // semi-transparent
        c = c * (1 - m) + white * m;
      }
      float const b = 0.65f + 0.45f * shade.at<float>(y, x) + 0.12f * (fine.at<float>(y, x) - 0.5f);
      tissue_.at<cv::Vec3f>(y, x) = c * b;
    }
  // Vessels: a few thin dark-red curves.
  std::uniform_real_distribution<double> U(0.0, 1.0);
  for (int v = 0; v < 12; ++v) {
    cv::Point2d p(U(rng) * width, U(rng) * height);
    double a = U(rng) * 2 * M_PI;
    std::vector<cv::Point> pts;
    for (int k = 0; k < 40; ++k) {
      pts.emplace_back(static_cast<int>(p.x), static_cast<int>(p.y));
      a += (U(rng) - 0.5) * 0.5;
      p += cv::Point2d(std::cos(a), std::sin(a)) * 6.0;
    }
    cv::polylines(tissue_, pts, false, cv::Scalar(40, 30, 120), 1, cv::LINE_AA);
  }
  if (o.specular)
    for (int s = 0; s < 10; ++s)
      cv::ellipse(tissue_, cv::Point(static_cast<int>(U(rng) * width), static_cast<int>(U(rng) * height)),
                  cv::Size(static_cast<int>(2 + 6 * U(rng)), static_cast<int>(1 + 3 * U(rng))), U(rng) * 180, 0, 360,
                  cv::Scalar(250, 250, 250), -1, cv::LINE_AA);
  if (o.gauze) {
    // A grey, low-chroma, textured blob touching the image border (where seeds are searched).
    cv::Mat g = cv::Mat::zeros(height, width, CV_32F);
    cv::ellipse(g, cv::Point(width / 5, height - height / 8), cv::Size(width / 6, height / 7), 20, 0, 360, 1.0, -1);
    cv::GaussianBlur(g, g, cv::Size(0, 0), 3.0);
    for (int y = 0; y < height; ++y)
      for (int x = 0; x < width; ++x) {
        float const m = g.at<float>(y, x);
        if (m <= 0.f) continue;
        float const tex = 170.f + 40.f * (fine.at<float>(y, x) - 0.5f) + 25.f * (((x / 3 + y / 3) % 2) - 0.5f);
        tissue_.at<cv::Vec3f>(y, x) = tissue_.at<cv::Vec3f>(y, x) * (1 - m) + cv::Vec3f(tex, tex, tex + 4) * m;
      }
  }
  fov_ = cv::Mat::ones(height, width, CV_32F);
  if (o.circular_fov) {
    double const cx = (width - 1) / 2.0, cy = (height - 1) / 2.0, r = 0.52 * std::hypot(width, height) * 0.8;
    for (int y = 0; y < height; ++y)
      for (int x = 0; x < width; ++x) {
        double const d = std::hypot(x - cx, y - cy);
        fov_.at<float>(y, x) = clamp01((r - d) / 6.0) * clamp01(1.0 - 0.35 * std::pow(d / r, 4));  // vignetting
      }
  }
}

cv::Mat SceneRenderer::render(std::vector<SyntheticView> const& views, int k, cv::Mat* labels) const {
  cv::Mat out, scratch;
  render(views, k, out, scratch, labels);
  return out;
}

Eigen::Vector2d SceneRenderer::visibleTip(SyntheticView const& v, int k) {
  if (v.jaw_end_px.allFinite()) return v.jaw_end_px;
  // Without a 3D jaw length, the jaws are 1.6 shaft widths (at the tip) long.
  geometry::ApparentContour const& c = v.truth;
  double const w_tip = c.lines[0].dot(c.tip_px.homogeneous()) + c.lines[1].dot(c.tip_px.homogeneous());
  return c.tip_px + (c.tip_px - c.entry_px).normalized() * (1.6 * w_tip * std::cos(jawOpening(v, k)));
}

void SceneRenderer::render(std::vector<SyntheticView> const& views, int k, cv::Mat& out, cv::Mat& scratch,
                           cv::Mat* labels) const {
  tissue_.copyTo(scratch);
  cv::Mat& img = scratch;
  if (labels) *labels = cv::Mat::zeros(height_, width_, CV_8U);
  // Far to near (by tip depth), so nearer shafts occlude farther ones.
  std::vector<SyntheticView const*> order;
  for (auto const& v : views) order.push_back(&v);
  std::sort(order.begin(), order.end(), [](auto a, auto b) { return a->tip_c.z() > b->tip_c.z(); });
  std::mt19937_64 rng(options_.seed + 1000 + static_cast<std::uint64_t>(k));
  for (SyntheticView const* v : order) {
    geometry::ApparentContour const& c = v->truth;
    Eigen::Vector2d const dir = (c.tip_px - c.entry_px).normalized();
    double const t_tip = dir.dot(c.tip_px - c.entry_px);
    Eigen::Vector3d const tip_h(c.tip_px.x(), c.tip_px.y(), 1.0);
    double const w_tip = c.lines[0].dot(tip_h) + c.lines[1].dot(tip_h);  // width at the tip
    bool const black = options_.black_shafts;
    float const base = black ? 38.f : 150.f;
    for (int y = 0; y < height_; ++y) {
      float* row = img.ptr<float>(y);
      for (int x = 0; x < width_; ++x) {
        Eigen::Vector3d const p(x, y, 1.0);
        double const s0 = c.lines[0].dot(p), s1 = c.lines[1].dot(p);
        if (s0 < -1.0 || s1 < -1.0) continue;
        double const t = dir.dot(p.head<2>() - c.entry_px);
        if (t > t_tip + 1.0) continue;
        // Exact-enough coverage of the pixel by each half-plane (box filter of a straight edge).
        float const cov = clamp01(0.5 + s0) * clamp01(0.5 + s1) * clamp01(0.5 + (t_tip - t));
        if (cov <= 0.f) continue;
        // Across-shaft coordinate a in [-1, 1] and cylinder shading.
        double const a = std::clamp((s0 - s1) / std::max(s0 + s1, 1e-6), -1.0, 1.0);
        double const lam = std::sqrt(std::max(0.0, 1.0 - a * a));  // cos of the surface normal angle
        double const spec = options_.specular ? std::exp(-std::pow((a - 0.35) / 0.12, 2)) : 0.0;
        float const I = static_cast<float>(base * (0.45 + 0.6 * lam) + (black ? 60.0 : 90.0) * spec);
        cv::Vec3f const col(I * 1.0f, I * 1.0f, I * 1.03f);
        cv::Vec3f& dst = reinterpret_cast<cv::Vec3f*>(row)[x];
        dst = dst * (1.f - cov) + col * cov;
        if (labels && cov >= 0.5f) labels->at<std::uint8_t>(y, x) = 1;
      }
    }
    // Jaws: two metal wedges beyond the tip, opening and closing with k, ending at visibleTip().
    double const open = jawOpening(*v, k);
    double const jaw = (visibleTip(*v, k) - c.tip_px).norm() / std::cos(open);
    Eigen::Vector2d const nrm(-dir.y(), dir.x());
    for (int j = -1; j <= 1; j += 2) {
      Eigen::Vector2d const a0 = c.tip_px + nrm * (0.25 * j * w_tip);
      Eigen::Vector2d const jd = (dir + nrm * (j * open)).normalized();
      Eigen::Vector2d const a1 = a0 + jd * jaw + nrm * (0.12 * j * w_tip);
      Eigen::Vector2d const a2 = a0 + jd * jaw - nrm * (0.12 * j * w_tip);
      Eigen::Vector2d const a3 = a0 - nrm * (0.25 * j * w_tip);
      fillQuad(img, labels, {a0, a1, a2, a3}, cv::Vec3f(175.f, 175.f, 180.f));
    }
  }
  // Field of view, noise, 8-bit.
  out.create(height_, width_, CV_8UC3);
  std::normal_distribution<float> N(0.f, static_cast<float>(options_.noise_sigma));
  bool const noisy = options_.noise_sigma > 0.0;
  for (int y = 0; y < height_; ++y)
    for (int x = 0; x < width_; ++x) {
      cv::Vec3f v = img.at<cv::Vec3f>(y, x) * fov_.at<float>(y, x);
      cv::Vec3b& o = out.at<cv::Vec3b>(y, x);
      for (int ch = 0; ch < 3; ++ch) o[ch] = cv::saturate_cast<std::uint8_t>(v[ch] + (noisy ? N(rng) : 0.f));
    }
  if (labels) labels->setTo(0, fov_ < 0.5f);
  if (options_.jpeg_quality > 0) {
    std::vector<std::uint8_t> buf;
    cv::imencode(".jpg", out, buf, {cv::IMWRITE_JPEG_QUALITY, options_.jpeg_quality});
    cv::imdecode(buf, cv::IMREAD_COLOR).copyTo(out);
  }
}

}  // namespace endo_guidance::sim
