// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/sim/synthetic_scene.h"

#include <cmath>

#include "endo_guidance/geometry/cylinder_pose.h"

namespace endo_guidance::sim {

std::vector<SyntheticInstrument> defaultInstruments() {
  std::vector<SyntheticInstrument> v(3);
  // Left, right and top trocars, a few cm behind or in front of the optical centre.
  v[0] = {{-0.10, 0.03, 0.01}, {-0.005, 0.01, 0.12}, {0.045, 0.035, 0.025}, {0.11, 0.07, 0.05}, 0.004};
  v[1] = {{0.11, 0.02, 0.02}, {0.01, 0.015, 0.13}, {0.04, 0.04, 0.025}, {0.09, 0.13, 0.04}, 0.004};
  v[2] = {{0.01, -0.12, 0.03}, {0.0, -0.005, 0.14}, {0.05, 0.03, 0.025}, {0.07, 0.10, 0.06}, 0.004};
  return v;
}

SyntheticScene::SyntheticScene(std::vector<SyntheticInstrument> instruments, SyntheticSceneOptions const& options)
    : instruments_(std::move(instruments)), options_(options), rng_(options.seed) {}

Eigen::Vector3d SyntheticScene::trocarAt(int i, int k) const {
  double const t = k / options_.fps;
  double const b = options_.breathing_amplitude * std::sin(2.0 * M_PI * t / options_.breathing_period + 0.7 * i);
  return instruments_[i].trocar_c + b * options_.breathing_direction;
}

std::optional<SyntheticView> viewOfInstrument(Eigen::Matrix3d const& K, int width, int height, Eigen::Vector3d const& trocar_c,
                                              Eigen::Vector3d const& tip_c, double radius, int instrument, double jaw_length) {
  SyntheticView v;
  v.instrument = instrument;
  v.radius = radius;
  v.trocar_c = trocar_c;
  v.tip_c = tip_c;
  auto axis = geometry::PluckerLine::through(trocar_c, tip_c);
  if (!axis) return std::nullopt;
  v.axis = *axis;
  auto const lines = geometry::projectCylinder(K, v.axis, radius);
  if (!lines) return std::nullopt;
  // Tip pixel; entry: where the imaged axis leaves the image on the trocar side.
  Eigen::Vector3d const tp = K * tip_c;
  if (tp.z() <= 0.0) return std::nullopt;
  Eigen::Vector2d const tip_px = tp.head<2>() / tp.z();
  if (tip_px.x() < 5 || tip_px.y() < 5 || tip_px.x() > width - 6 || tip_px.y() > height - 6) return std::nullopt;
  auto const axis_img = v.axis.project(K);
  if (!axis_img) return std::nullopt;
  auto const seg = geometry::clipLineToImage(*axis_img, width, height);
  if (!seg) return std::nullopt;
  // Image direction entry -> tip: the projection of d at the tip.
  Eigen::Vector3d const tp2 = K * (tip_c + 1e-3 * v.axis.direction());
  Eigen::Vector2d const dir = (tp2.head<2>() / tp2.z() - tip_px).normalized();
  Eigen::Vector2d entry = ((*seg)[0] - tip_px).dot(dir) < ((*seg)[1] - tip_px).dot(dir) ? (*seg)[0] : (*seg)[1];
  if ((entry - tip_px).dot(dir) > 0.0 || (entry - tip_px).norm() < 40.0) return std::nullopt;  // tip must be past the entry
  v.truth.lines = *lines;
  v.truth.entry_px = entry;
  v.truth.tip_px = tip_px;
  v.measured = v.truth;
  if (jaw_length > 0.0) {
    Eigen::Vector3d const je = K * (tip_c + jaw_length * v.axis.direction());
    if (je.z() <= 0.0) return std::nullopt;
    v.jaw_end_px = je.head<2>() / je.z();
    if (v.jaw_end_px.x() < 0 || v.jaw_end_px.y() < 0 || v.jaw_end_px.x() > width - 1 || v.jaw_end_px.y() > height - 1)
      return std::nullopt;
  }
  return v;
}

std::vector<SyntheticView> SyntheticScene::frame(int k) {
  std::vector<SyntheticView> out;
  double const t = k / options_.fps;
  std::normal_distribution<double> noise(0.0, 1.0);
  Eigen::Matrix3d const& K = options_.K;
  for (int i = 0; i < static_cast<int>(instruments_.size()); ++i) {
    SyntheticInstrument const& ins = instruments_[i];
    Eigen::Vector3d tip = ins.tip_centre_c;
    for (int a = 0; a < 3; ++a) tip(a) += ins.tip_amplitude(a) * std::sin(2.0 * M_PI * ins.tip_frequency(a) * t + a);
    auto view = viewOfInstrument(K, options_.width, options_.height, trocarAt(i, k), tip, ins.radius, i);
    if (!view) continue;
    SyntheticView& v = *view;
    // Measured lines: each contour between the perpendicular feet of entry and tip, endpoints
    // displaced along the normal by N(0, sigma), refitted; orientation kept.
    double rs = 0.0;
    for (int j = 0; j < 2; ++j) {
      geometry::ImageLine const& l = v.truth.lines[j];
      Eigen::Vector2d const n = l.head<2>();
      Eigen::Vector2d p = geometry::footOnLine(l, v.truth.entry_px);
      Eigen::Vector2d q = geometry::footOnLine(l, v.truth.tip_px);
      Eigen::Vector2d const p0 = p, q0 = q;
      double const s = options_.line_noise_px;
      if (s > 0.0) {
        p += n * s * noise(rng_);
        q += n * s * noise(rng_);
      }
      auto lm = geometry::lineThrough(p, q);
      if (!lm) lm = l;
      if (lm->head<2>().dot(n) < 0.0) *lm = -*lm;
      v.measured.lines[j] = *lm;
      v.measured.line_covariances[j] = geometry::lineCovarianceFromSegment(*lm, p0, q0, std::max(s, 1e-3), 2);
      rs += s * s;
    }
    v.measured.residual_px = std::sqrt(rs / 2.0);
    v.measured.line_residual_px = {options_.line_noise_px, options_.line_noise_px};
    out.push_back(v);
  }
  return out;
}

}  // namespace endo_guidance::sim
