// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/line_fit.h"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>
#include <random>

namespace endo_guidance::perception {

// Total least squares line through weighted points.
std::optional<Eigen::Vector3d> fitLineLS(std::vector<Eigen::Vector2d> const& pts, std::vector<double> const* w) {
  double sw = 0.0;
  Eigen::Vector2d c = Eigen::Vector2d::Zero();
  for (std::size_t i = 0; i < pts.size(); ++i) {
    double const wi = w ? (*w)[i] : 1.0;
    c += wi * pts[i];
    sw += wi;
  }
  if (sw <= 0.0) return std::nullopt;
  c /= sw;
  Eigen::Matrix2d S = Eigen::Matrix2d::Zero();
  for (std::size_t i = 0; i < pts.size(); ++i) {
    double const wi = w ? (*w)[i] : 1.0;
    Eigen::Vector2d const d = pts[i] - c;
    S += wi * d * d.transpose();
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(S);
  Eigen::Vector2d const n = es.eigenvectors().col(0);  // normal: smallest scatter
  return Eigen::Vector3d(n.x(), n.y(), -n.dot(c));
}

// Residual, inliers and covariance of the line l fitted to weighted points (weight 0 = outlier).
std::optional<RefinedLine> summarizeLine(Eigen::Vector3d const& l, std::vector<Eigen::Vector2d> const& pts,
                                         std::vector<double> const& w, int min_points, double sigma_floor_px) {
  RefinedLine out;
  out.line = l;
  double sw = 0.0, ss = 0.0, st = 0.0;
  Eigen::Vector2d c = Eigen::Vector2d::Zero();
  int used = 0;
  for (std::size_t i = 0; i < pts.size(); ++i) {
    if (w[i] <= 0.0) continue;
    double const e = l.head<2>().dot(pts[i]) + l.z();
    ss += w[i] * e * e;
    sw += w[i];
    c += w[i] * pts[i];
    out.inliers.push_back(pts[i]);
    ++used;
  }
  if (used < min_points || sw <= 0.0) return std::nullopt;
  c /= sw;
  Eigen::Vector2d const ld(-l.y(), l.x());
  for (std::size_t i = 0; i < pts.size(); ++i)
    if (w[i] > 0.0) {
      double const t = ld.dot(pts[i] - c);
      st += w[i] * t * t;
    }
  out.residual_px = std::sqrt(ss / sw);
  out.points = used;
  double const s2 = std::max(out.residual_px * out.residual_px, 0.01 * 0.01) * used / std::max(1, used - 2);
  // The residuals give the independent part of the error (s2 / n); a systematic error of
  // sigma_floor at each end of the line, common to its points (compression blocks, shading, the
  // jaws' outline), adds sigma_floor^2 / 2 to the offset and 2 sigma_floor^2 / L^2 to the angle,
  // L^2 = 12 var(t) the extent of the points.
  double const f2 = sigma_floor_px * sigma_floor_px, L2 = 12.0 * st / sw;
  out.covariance = geometry::lineCovariance(l, c, s2 / std::max(st, 1e-9) + 2.0 * f2 / std::max(L2, 1.0), s2 / used + 0.5 * f2);
  return out;
}


std::optional<RobustLine> fitLineLMedS(std::vector<Eigen::Vector2d> const& pts, int samples, std::uint64_t seed) {
  int const n = static_cast<int>(pts.size());
  if (n < 2) return std::nullopt;
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> pick(0, n - 1);
  std::vector<double> r(static_cast<std::size_t>(n));
  double best = std::numeric_limits<double>::infinity();
  Eigen::Vector3d bl = Eigen::Vector3d::Zero();
  int const k = n / 2;
  for (int s = 0; s < samples; ++s) {
    int const i = pick(rng), j = pick(rng);
    Eigen::Vector2d const d = pts[j] - pts[i];
    double const len = d.norm();
    if (len < 2.0) continue;
    Eigen::Vector2d const nrm(-d.y() / len, d.x() / len);
    double const c = -nrm.dot(pts[i]);
    int below = 0;  // residuals under the best median so far: at most k, and this line cannot beat it
    for (int m = 0; m < n; ++m) {
      double const e = nrm.dot(pts[m]) + c;
      r[m] = e * e;
      below += r[m] < best;
    }
    if (below <= k) continue;
    std::nth_element(r.begin(), r.begin() + k, r.end());
    if (r[k] < best) {
      best = r[k];
      bl = Eigen::Vector3d(nrm.x(), nrm.y(), c);
    }
  }
  if (!std::isfinite(best)) return std::nullopt;
  RobustLine out;
  out.sigma = 1.4826 * (1.0 + 5.0 / std::max(1, n - 2)) * std::sqrt(best);
  double const thr = std::max(2.5 * out.sigma, 1.0);
  std::vector<Eigen::Vector2d> in;
  for (int m = 0; m < n; ++m)
    if (std::abs(bl.head<2>().dot(pts[m]) + bl.z()) <= thr) {
      out.inliers.push_back(m);
      in.push_back(pts[m]);
    }
  auto const ls = in.size() >= 2 ? fitLineLS(in) : std::nullopt;
  out.line = ls ? *ls : bl;
  return out;
}

}  // namespace endo_guidance::perception
