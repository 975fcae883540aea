// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/geometry/apparent_contour.h"

#include <algorithm>
#include <cmath>
#include <vector>

namespace endo_guidance::geometry {

std::optional<ImageLine> normalizeLine(Eigen::Vector3d const& l) {
  double const n = l.head<2>().norm();
  if (!(n > 1e-300) || !l.allFinite()) return std::nullopt;
  return ImageLine(l / n);
}

std::optional<ImageLine> lineThrough(Eigen::Vector2d const& p, Eigen::Vector2d const& q) {
  // l = p~ x q~ has l.x > 0 for x on the left of p -> q when v points down... check sign:
  // for p = (0,0), q = (1,0) (walking right), the left side is v < 0 (up in the image).
  // p~ x q~ = (0, 1, 0): positive for v > 0, i.e. the right side, so negate.
  Eigen::Vector3d const l = -Eigen::Vector3d(p.x(), p.y(), 1.0).cross(Eigen::Vector3d(q.x(), q.y(), 1.0));
  if ((q - p).norm() < 1e-12) return std::nullopt;
  return normalizeLine(l);
}

Eigen::Matrix3d lineCovariance(ImageLine const& l, Eigen::Vector2d const& centre, double var_angle, double var_offset) {
  Eigen::Matrix<double, 3, 2> J;
  double const a = l.x(), b = l.y();
  // d(a,b,c)/dt with c = -(a,b).c0 ; d(a,b,c)/d(delta) = (0, 0, -1)
  J << -b, 0.0, a, 0.0, -(-b * centre.x() + a * centre.y()), -1.0;
  Eigen::Matrix2d S = Eigen::Matrix2d::Zero();
  S(0, 0) = var_angle;
  S(1, 1) = var_offset;
  return J * S * J.transpose();
}

Eigen::Matrix3d lineCovarianceFromSegment(ImageLine const& l, Eigen::Vector2d const& p, Eigen::Vector2d const& q,
                                          double sigma_px, int n) {
  n = std::max(n, 2);
  double const L = (q - p).norm();
  // Points at t_i evenly over [-L/2, L/2]: var(offset) = s^2/n, var(angle) = s^2 / sum t_i^2.
  double sum_t2 = 0.0;
  for (int i = 0; i < n; ++i) {
    double const t = -0.5 * L + L * i / (n - 1);
    sum_t2 += t * t;
  }
  double const s2 = sigma_px * sigma_px;
  return lineCovariance(l, 0.5 * (p + q), s2 / std::max(sum_t2, 1e-12), s2 / n);
}

std::optional<std::array<Eigen::Vector2d, 2>> clipLineToImage(ImageLine const& l, int width, int height) {
  double const W = width - 1.0, H = height - 1.0;
  std::vector<Eigen::Vector2d> pts;
  auto add = [&](double u, double v) {
    if (u >= -1e-9 && u <= W + 1e-9 && v >= -1e-9 && v <= H + 1e-9) pts.emplace_back(u, v);
  };
  double const a = l.x(), b = l.y(), c = l.z();
  if (std::abs(b) > 1e-12) {
    add(0.0, -c / b);
    add(W, -(c + a * W) / b);
  }
  if (std::abs(a) > 1e-12) {
    add(-c / a, 0.0);
    add(-(c + b * H) / a, H);
  }
  if (pts.size() < 2) return std::nullopt;
  // The two farthest-apart intersections (corners can produce duplicates).
  double best = -1.0;
  std::array<Eigen::Vector2d, 2> seg{pts[0], pts[1]};
  for (size_t i = 0; i < pts.size(); ++i)
    for (size_t j = i + 1; j < pts.size(); ++j)
      if ((pts[i] - pts[j]).norm() > best) {
        best = (pts[i] - pts[j]).norm();
        seg = {pts[i], pts[j]};
      }
  if (best < 1e-9) return std::nullopt;
  return seg;
}

}  // namespace endo_guidance::geometry
