// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/geometry/insertion_point_image.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <random>

namespace endo_guidance::geometry {

Eigen::Vector3d projectPointHomogeneous(Eigen::Matrix3d const& K, Eigen::Vector3d const& X) {
  Eigen::Vector3d x = K * X;
  if (!x.allFinite()) return Eigen::Vector3d::Zero();  // beyond double range: no image, as for K X = 0
  double const n = x.stableNorm();                      // (no overflow for huge finite entries)
  if (n > 0.0) x /= n;
  if (x.z() < 0.0) x = -x;
  return x;
}

std::optional<ImageLine> imageOfAxis(Eigen::Matrix3d const& K, PluckerLine const& axis) { return axis.project(K); }

namespace {

// Lines in normalised coordinates x' = T x with T = [I/s, -c/s; 0 1]: l' = T^-T l = (a s, b s, a cx + b cy + c).
Eigen::Vector3d toNormalised(ImageLine const& l, Eigen::Vector2d const& c, double s) {
  Eigen::Vector3d const ln(l.x() * s, l.y() * s, l.x() * c.x() + l.y() * c.y() + l.z());
  return ln / ln.norm();
}

// Back from normalised homogeneous point x' to pixels: x = T^-1 x' = (s x'_u + c_u w, s x'_v + c_v w, w).
Eigen::Vector3d fromNormalised(Eigen::Vector3d const& xn, Eigen::Vector2d const& c, double s) {
  Eigen::Vector3d x(s * xn.x() + c.x() * xn.z(), s * xn.y() + c.y() * xn.z(), xn.z());
  x.normalize();
  if (x.z() < 0.0 || (x.z() == 0.0 && (x.x() < 0.0 || (x.x() == 0.0 && x.y() < 0.0)))) x = -x;
  return x;
}

ImagePointEstimate solve(std::vector<Eigen::Vector3d> const& ln, std::vector<ImageLine> const& lines,
                         std::vector<int> const& use, Eigen::Vector2d const& c, double s) {
  ImagePointEstimate e;
  if (use.size() < 2) return e;
  Eigen::Matrix3d AtA = Eigen::Matrix3d::Zero();
  for (int i : use) AtA.noalias() += ln[i] * ln[i].transpose();  // Eq. (5): l_i^T x = 0
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(AtA);
  Eigen::Vector3d xn = es.eigenvectors().col(0);
  if (std::abs(xn.z()) < 1e-12) xn.z() = 0.0;  // at infinity
  e.point = fromNormalised(xn, c, s);
  e.ok = true;
  if (!e.atInfinity()) {
    double ss = 0.0;
    Eigen::Vector3d const x(e.pixel().x(), e.pixel().y(), 1.0);
    for (int i : use) {
      double const r = lines[i].dot(x) / lines[i].head<2>().norm();
      ss += r * r;
    }
    e.rms_px = std::sqrt(ss / use.size());
  }
  e.inliers = use;
  return e;
}

}  // namespace

ImagePointEstimate intersectImageLines(std::vector<ImageLine> const& lines, Eigen::Vector2d const& c, double s) {
  std::vector<Eigen::Vector3d> ln;
  std::vector<int> use;
  for (std::size_t i = 0; i < lines.size(); ++i) {
    ln.push_back(toNormalised(lines[i], c, s));
    if (lines[i].allFinite() && lines[i].head<2>().norm() > 0.0) use.push_back(static_cast<int>(i));
  }
  return solve(ln, lines, use, c, s);
}

ImagePointEstimate intersectImageLinesRobust(std::vector<ImageLine> const& lines, Eigen::Vector2d const& c, double s,
                                             double inlier_fraction, std::uint64_t seed) {
  int const n = static_cast<int>(lines.size());
  if (n <= 2) return intersectImageLines(lines, c, s);
  std::vector<Eigen::Vector3d> ln(lines.size());
  for (int i = 0; i < n; ++i) ln[i] = toNormalised(lines[i], c, s);
  // Residual of line i to the unit homogeneous point x: |l_i . x| (both unit vectors): the sine of
  // the angle between x and the plane l_i on the sphere; well defined at infinity too.
  int const k = std::clamp(static_cast<int>(std::ceil(inlier_fraction * n)) - 1, 0, n - 1);
  std::vector<double> r(lines.size());
  double best = std::numeric_limits<double>::infinity();
  Eigen::Vector3d best_x = Eigen::Vector3d::UnitZ();
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> pick(0, n - 1);
  long const all = static_cast<long>(n) * (n - 1) / 2;
  int const samples = static_cast<int>(std::min<long>(all, 500));
  int i = 0, j = 1;
  for (int t = 0; t < samples; ++t) {
    if (all <= 500) {  // enumerate all pairs
      if (t > 0 && ++j >= n) {
        ++i;
        j = i + 1;
      }
    } else {
      i = pick(rng);
      j = pick(rng);
      if (i == j) continue;
    }
    Eigen::Vector3d x = ln[i].cross(ln[j]);
    double const xn = x.norm();
    if (xn < 1e-12) continue;
    x /= xn;
    for (int m = 0; m < n; ++m) r[m] = std::abs(ln[m].dot(x));
    std::nth_element(r.begin(), r.begin() + k, r.end());
    if (r[k] < best) {
      best = r[k];
      best_x = x;
    }
  }
  if (!std::isfinite(best)) return ImagePointEstimate{};
  double const thr = std::max(2.5 * 1.4826 * (1.0 + 5.0 / std::max(1, n - 2)) * best, 1e-6);
  std::vector<int> use;
  for (int m = 0; m < n; ++m)
    if (std::abs(ln[m].dot(best_x)) < thr) use.push_back(m);
  return solve(ln, lines, use, c, s);
}

}  // namespace endo_guidance::geometry
