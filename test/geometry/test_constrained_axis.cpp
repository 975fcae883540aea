// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <cstdio>
#include <limits>
#include <numeric>
#include <random>
#include <vector>

#include "endo_guidance/geometry/constrained_axis.h"
#include "endo_guidance/sim/synthetic_scene.h"
#include "test_util.h"

using namespace endo_guidance::geometry;
using namespace endo_guidance::sim;
namespace test = endo_guidance::test;

namespace {
// NEES of the error e under a rank-deficient covariance (its support only).
double nees(Eigen::Matrix<double, 6, 1> const& e, Eigen::Matrix<double, 6, 6> const& cov) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> es(cov);
  double const top = es.eigenvalues().maxCoeff();
  double chi2 = 0.0;
  for (int i = 0; i < 6; ++i)
    if (es.eigenvalues()(i) > 1e-9 * top) chi2 += std::pow(es.eigenvectors().col(i).dot(e), 2) / es.eigenvalues()(i);
  return chi2;
}
Eigen::Matrix<double, 6, 1> lineError(PluckerLine const& est, PluckerLine const& truth) {
  Eigen::Matrix<double, 6, 1> e;
  e << est.direction() - truth.direction(), est.moment() - truth.moment();
  return e;
}
}  // namespace

// An axis measured exactly through the point is left as it is, whatever the weights; the
// orientation (entry -> tip) is kept.
TEST(ConstrainedAxis, AnAxisThroughThePointIsUnchanged) {
  std::mt19937_64 rng(3);
  for (int k = 0; k < 200; ++k) {
    auto const c = test::randomCylinder(rng);
    CylinderPose measured;
    measured.axis = k % 2 ? c.axis : c.axis.reversed();
    measured.distance = c.axis.distanceToOrigin();
    Eigen::Matrix<double, 6, 6> A = Eigen::Matrix<double, 6, 6>::Random();
    measured.covariance = 1e-6 * A * A.transpose();
    Eigen::Vector3d const trocar = c.axis.pointAt(-0.08);  // 8 cm back along the axis
    auto const f = constrainAxisToPoint(measured, trocar, 1e-6 * Eigen::Matrix3d::Identity(), 0.001);
    ASSERT_TRUE(f);
    EXPECT_LT((f->pose.axis.direction() - measured.axis.direction()).norm(), 1e-9);
    EXPECT_LT((f->pose.axis.moment() - measured.axis.moment()).norm(), 1e-11);
    EXPECT_LT((f->pivot - trocar).norm(), 1e-9);
    EXPECT_NEAR(f->pose.distance, measured.distance, 1e-11);
    EXPECT_LT(f->chi2, 1e-12);
  }
}

// Noisy contour lines of the rendered-free geometric scene (0.5 px per line end): each axis
// measured alone, then fused with its true trocar's estimate (1 mm off, covariance saying so)
// and the breathing (1 mm RMS). The fused axes are more accurate, most of all in direction, and
// their covariance is consistent with their errors (NEES about the rank, 4); a far-off point
// (a point the axis does not pass through) is a large chi2.
TEST(ConstrainedAxis, TheTrocarFixesTheDirectionOfNoisyAxes) {
  SyntheticSceneOptions so;
  so.line_noise_px = 0.5;
  so.seed = 21;
  so.breathing_amplitude = 0.0015;
  SyntheticScene scene(defaultInstruments(), so);
  std::mt19937_64 rng(5);
  std::normal_distribution<double> N(0.0, 0.001 / std::sqrt(3.0));  // 1 mm RMS, isotropic
  std::vector<Eigen::Vector3d> estimate(scene.size());
  for (std::size_t i = 0; i < scene.size(); ++i) estimate[i] = scene.meanTrocar(static_cast<int>(i)) + Eigen::Vector3d(N(rng), N(rng), N(rng));
  Eigen::Matrix3d const est_cov = (0.001 * 0.001 / 3.0) * Eigen::Matrix3d::Identity();
  std::vector<double> dir_raw, dir_fused, dist_raw, dist_fused, nees_fused, chi2_true, chi2_far;
  for (int k = 0; k < 600; ++k)
    for (auto const& v : scene.frame(k)) {
      auto const r = estimateCylinderPose(so.K, v.radius, v.measured);
      ASSERT_TRUE(r.ok()) << toString(r.status);
      auto const f = constrainAxisToPoint(r.pose, estimate[static_cast<std::size_t>(v.instrument)], est_cov, 0.001);
      ASSERT_TRUE(f);
      dir_raw.push_back(test::angleDeg(r.pose.axis.direction(), v.axis.direction()));
      dir_fused.push_back(test::angleDeg(f->pose.axis.direction(), v.axis.direction()));
      dist_raw.push_back(std::abs(r.pose.distance - v.axis.distanceToOrigin()) / v.axis.distanceToOrigin());
      dist_fused.push_back(std::abs(f->pose.distance - v.axis.distanceToOrigin()) / v.axis.distanceToOrigin());
      EXPECT_GT(f->pose.axis.direction().dot(r.pose.axis.direction()), 0.0);  // orientation kept
      nees_fused.push_back(nees(lineError(f->pose.axis, v.axis), f->pose.covariance));
      chi2_true.push_back(f->chi2);
      // A point 2 cm off the axis, with the same covariance: not this shaft's trocar.
      Eigen::Vector3d const off = v.axis.direction().unitOrthogonal();
      auto const g = constrainAxisToPoint(r.pose, estimate[static_cast<std::size_t>(v.instrument)] + 0.02 * off, est_cov, 0.001);
      ASSERT_TRUE(g);
      chi2_far.push_back(g->chi2);
    }
  double const mean_nees = std::accumulate(nees_fused.begin(), nees_fused.end(), 0.0) / nees_fused.size();
  std::printf("[ %zu axes ] direction median %.3f -> %.3f deg (p95 %.3f -> %.3f); distance median %.3f -> %.3f %%; "
              "fused NEES mean %.2f; chi2 median %.2f (through the trocar), %.0f (2 cm off)\n",
              dir_raw.size(), test::percentile(dir_raw, 0.5), test::percentile(dir_fused, 0.5), test::percentile(dir_raw, 0.95),
              test::percentile(dir_fused, 0.95), 100 * test::percentile(dist_raw, 0.5), 100 * test::percentile(dist_fused, 0.5),
              mean_nees, test::percentile(chi2_true, 0.5), test::percentile(chi2_far, 0.5));
  ASSERT_GT(dir_raw.size(), 1000u);
  EXPECT_LT(test::percentile(dir_fused, 0.5), 0.6 * test::percentile(dir_raw, 0.5));
  EXPECT_LT(test::percentile(dir_fused, 0.95), 0.6 * test::percentile(dir_raw, 0.95));
  EXPECT_LT(test::percentile(dist_fused, 0.5), test::percentile(dist_raw, 0.5));
  EXPECT_GT(mean_nees, 2.5);
  EXPECT_LT(mean_nees, 6.0);
  EXPECT_LT(test::percentile(chi2_true, 0.5), 3.0);
  EXPECT_GT(test::percentile(chi2_far, 0.5), 30.0);
}

// Nothing is guessed: no covariance, non-finite input, a point covariance that is not positive
// definite (and no motion to make it so).
TEST(ConstrainedAxis, BadInputIsRefused) {
  std::mt19937_64 rng(9);
  auto const c = test::randomCylinder(rng);
  CylinderPose measured;
  measured.axis = c.axis;
  measured.distance = c.axis.distanceToOrigin();
  Eigen::Vector3d const p = c.axis.pointAt(-0.08);
  Eigen::Matrix3d const S = 1e-6 * Eigen::Matrix3d::Identity();
  EXPECT_FALSE(constrainAxisToPoint(measured, p, S, 0.001)) << "zero axis covariance";
  measured.covariance = 1e-6 * Eigen::Matrix<double, 6, 6>::Identity();
  ASSERT_TRUE(constrainAxisToPoint(measured, p, S, 0.001));
  double const nan = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(constrainAxisToPoint(measured, Eigen::Vector3d(nan, 0, 0), S, 0.001));
  EXPECT_FALSE(constrainAxisToPoint(measured, p, S * nan, 0.001));
  EXPECT_FALSE(constrainAxisToPoint(measured, p, S, nan));
  EXPECT_FALSE(constrainAxisToPoint(measured, p, Eigen::Matrix3d::Zero(), 0.0)) << "a point covariance of rank 0";
  EXPECT_TRUE(constrainAxisToPoint(measured, p, Eigen::Matrix3d::Zero(), 0.001)) << "the motion alone";
  CylinderPose bad = measured;
  bad.covariance(0, 0) = nan;
  EXPECT_FALSE(constrainAxisToPoint(bad, p, S, 0.001));
}
