// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/geometry/insertion_point.h"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <random>

namespace endo_guidance::geometry {

char const* toString(InsertionPointStatus s) {
  switch (s) {
    case InsertionPointStatus::kOk: return "ok";
    case InsertionPointStatus::kTooFewAxes: return "fewer than two usable axes";
    case InsertionPointStatus::kAtInfinity: return "axes (nearly) parallel: common point at infinity";
    case InsertionPointStatus::kNoConsensus: return "no subset of axes agrees on a common point";
  }
  return "unknown";
}

namespace {

double weightOf(std::vector<double> const& w, std::size_t i) { return w.empty() ? 1.0 : w[i]; }

// Fills the residual-dependent fields (rms, covariance, conditioning) for a known position.
void finishEstimate(std::vector<PluckerLine> const& axes, std::vector<double> const& w, InsertionPointEstimate* e) {
  Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
  double sw = 0.0, ss = 0.0;
  std::size_t n = 0;
  for (std::size_t i = 0; i < axes.size(); ++i) {
    double const wi = weightOf(w, i);
    if (!(wi > 0.0)) continue;
    Eigen::Vector3d const& d = axes[i].direction();
    S += wi * (Eigen::Matrix3d::Identity() - d * d.transpose());
    double const r = axes[i].distanceTo(e->position);
    ss += wi * r * r;
    sw += wi;
    ++n;
  }
  e->views = n;
  e->rms_distance = sw > 0.0 ? std::sqrt(ss / sw) : 0.0;
  e->conditioning = axesAngularSpread(axes, w);
  // Each axis gives 2 equations, 3 unknowns: sigma^2 = sum w r^2 / (2n - 3) per unit weight.
  double const dof = 2.0 * static_cast<double>(n) - 3.0;
  double const sigma2 = dof > 0.0 ? ss / sw * static_cast<double>(n) / dof : 0.0;
  Eigen::FullPivLU<Eigen::Matrix3d> lu(S * (static_cast<double>(n) / std::max(sw, 1e-300)));
  if (lu.isInvertible()) e->covariance = sigma2 * lu.inverse();
  else e->covariance = Eigen::Matrix3d::Identity() * std::numeric_limits<double>::max();
}

}  // namespace

double InsertionPointEstimate::longestSigma() const {
  if (!covariance.allFinite()) return std::numeric_limits<double>::infinity();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(covariance, Eigen::EigenvaluesOnly);
  return std::sqrt(std::max(0.0, es.eigenvalues()(2)));
}

double axesAngularSpread(std::vector<PluckerLine> const& axes, std::vector<double> const& w) {
  if (axes.size() < 2) return 0.0;
  Eigen::Matrix3d S = Eigen::Matrix3d::Zero();
  double sw = 0.0;
  for (std::size_t i = 0; i < axes.size(); ++i) {
    double const wi = weightOf(w, i);
    if (!(wi > 0.0)) continue;
    Eigen::Vector3d const& d = axes[i].direction();
    S += wi * (Eigen::Matrix3d::Identity() - d * d.transpose());
    sw += wi;
  }
  if (!(sw > 0.0)) return 0.0;
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(S / sw, Eigen::EigenvaluesOnly);
  return std::sqrt(std::max(0.0, es.eigenvalues()(0)));
}

InsertionPointEstimate intersectAxes(std::vector<PluckerLine> const& axes, std::vector<double> const& w) {
  InsertionPointEstimate e;
  std::size_t n = 0;
  for (std::size_t i = 0; i < axes.size(); ++i) n += weightOf(w, i) > 0.0 ? 1 : 0;
  if (n < 2) return e;

  // Normalisation: translate the closest points' centroid to the origin, scale to unit RMS.
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  double sw = 0.0;
  for (std::size_t i = 0; i < axes.size(); ++i) {
    double const wi = weightOf(w, i);
    if (!(wi > 0.0)) continue;
    c += wi * axes[i].closestPointToOrigin();
    sw += wi;
  }
  c /= sw;
  double rms = 0.0;
  for (std::size_t i = 0; i < axes.size(); ++i) {
    if (!(weightOf(w, i) > 0.0)) continue;
    rms += (axes[i].closestPointToOrigin() - c).squaredNorm();
  }
  double const scale = std::max(std::sqrt(rms / static_cast<double>(n)), 1e-6);

  // Eq. (3): stacked dual Plücker matrices (accumulated as the 4x4 normal matrix A^T A).
  Eigen::Matrix4d AtA = Eigen::Matrix4d::Zero();
  for (std::size_t i = 0; i < axes.size(); ++i) {
    double const wi = weightOf(w, i);
    if (!(wi > 0.0)) continue;
    // Line in normalised coordinates x' = (x - c) / scale: m' = (m - c x d) / scale.
    Eigen::Vector3d const& d = axes[i].direction();
    Eigen::Vector3d const m = (axes[i].moment() - c.cross(d)) / scale;
    Eigen::Matrix4d L = Eigen::Matrix4d::Zero();
    L.topLeftCorner<3, 3>() = skew(d);  // Eq. (2)
    L.topRightCorner<3, 1>() = m;
    L.bottomLeftCorner<1, 3>() = -m.transpose();
    AtA.noalias() += wi * L.transpose() * L;
  }
  // The smallest right singular vector of A is the smallest eigenvector of A^T A.
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix4d> es(AtA);
  Eigen::Vector4d I = es.eigenvectors().col(0);
  // Back to metric coordinates: x = scale x' + c.
  Eigen::Vector4d Im;
  Im.head<3>() = scale * I.head<3>() + c * I(3);
  Im(3) = I(3);
  Im.normalize();
  if (Im(2) < 0.0) Im = -Im;  // sign convention I_z > 0
  e.homogeneous = Im;
  // At infinity when the point is farther than 1e6 x the scene extent.
  if (std::abs(I(3)) < 1e-6 * I.head<3>().norm()) {
    e.status = InsertionPointStatus::kAtInfinity;
    e.views = n;
    e.conditioning = axesAngularSpread(axes, w);
    return e;
  }
  e.position = Im.head<3>() / Im(3);
  e.status = InsertionPointStatus::kOk;
  finishEstimate(axes, w, &e);
  // Axes beyond double range (moments ~1e300): no usable point, flagged rather than returned.
  if (!AtA.allFinite() || !e.position.allFinite() || !e.covariance.allFinite()) {
    e.status = InsertionPointStatus::kAtInfinity;
    e.position.setZero(), e.covariance.setZero();
  }
  return e;
}

InsertionPointEstimate intersectAxesRobust(std::vector<PluckerLine> const& axes, RobustIntersectOptions const& o) {
  InsertionPointEstimate e;
  int const n = static_cast<int>(axes.size());
  if (n < 2) return e;
  if (n == 2) {
    e = intersectAxes(axes);
    e.inliers = {0, 1};
    return e;
  }
  // Candidate points: the midpoints of the common perpendicular of pairs of axes.
  std::vector<std::pair<int, int>> pairs;
  long const all = static_cast<long>(n) * (n - 1) / 2;
  if (all <= o.max_samples) {
    for (int i = 0; i < n; ++i)
      for (int j = i + 1; j < n; ++j) pairs.emplace_back(i, j);
  } else {
    std::mt19937_64 rng(o.seed);
    std::uniform_int_distribution<int> pick(0, n - 1);
    while (static_cast<int>(pairs.size()) < o.max_samples) {
      int i = pick(rng), j = pick(rng);
      if (i != j) pairs.emplace_back(std::min(i, j), std::max(i, j));
    }
  }
  int const k = std::clamp(static_cast<int>(std::ceil(o.inlier_fraction * n)) - 1, 0, n - 1);
  std::vector<double> r2(static_cast<std::size_t>(n));
  double best = std::numeric_limits<double>::infinity();
  Eigen::Vector3d best_x = Eigen::Vector3d::Zero();
  for (auto const& [i, j] : pairs) {
    Eigen::Vector3d const& d1 = axes[i].direction();
    Eigen::Vector3d const& d2 = axes[j].direction();
    Eigen::Vector3d const p1 = axes[i].closestPointToOrigin(), p2 = axes[j].closestPointToOrigin();
    double const b = d1.dot(d2), den = 1.0 - b * b;
    if (den < o.min_pair_sine * o.min_pair_sine) continue;
    Eigen::Vector3d const w0 = p1 - p2;
    double const t1 = (b * d2.dot(w0) - d1.dot(w0)) / den;
    double const t2 = (d2.dot(w0) - b * d1.dot(w0)) / den;
    Eigen::Vector3d const x = 0.5 * ((p1 + t1 * d1) + (p2 + t2 * d2));
    int below = 0;  // residuals under the best order statistic so far
    for (int m = 0; m < n; ++m) {
      double const r = axes[m].distanceTo(x);
      r2[m] = r * r;
      below += r2[m] < best;
    }
    if (below <= k) continue;  // its k-th smallest is not below the best: no need to find it
    std::nth_element(r2.begin(), r2.begin() + k, r2.end());
    if (r2[k] < best) {
      best = r2[k];
      best_x = x;
    }
  }
  if (!std::isfinite(best)) {
    e.status = InsertionPointStatus::kAtInfinity;
    return e;
  }
  // Robust scale (Rousseeuw & Leroy) and inliers, then Eq. (3) on the inliers.
  double const sigma = 1.4826 * (1.0 + 5.0 / std::max(1, n - 3)) * std::sqrt(best);
  double const thr = std::clamp(o.inlier_sigmas * sigma, o.min_inlier_threshold, std::max(o.min_inlier_threshold, o.max_inlier_threshold));
  std::vector<double> w(static_cast<std::size_t>(n), 0.0);
  int count = 0;
  for (int m = 0; m < n; ++m)
    if (axes[m].distanceTo(best_x) < thr) {
      w[m] = 1.0;
      ++count;
    }
  if (count < 2) {
    e.status = InsertionPointStatus::kNoConsensus;
    return e;
  }
  e = intersectAxes(axes, w);
  for (int m = 0; m < n; ++m)
    if (w[m] > 0.0) e.inliers.push_back(m);
  return e;
}

}  // namespace endo_guidance::geometry
