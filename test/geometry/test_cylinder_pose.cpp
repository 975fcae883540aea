// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <cstdio>
#include <numeric>
#include <visp3/core/vpCylinder.h>
#include <visp3/core/vpHomogeneousMatrix.h>

#include "endo_guidance/geometry/cylinder_pose.h"
#include "cylinder_pose_conic.h"
#include "endo_guidance/sim/synthetic_scene.h"
#include "test_util.h"

using namespace endo_guidance::geometry;
using namespace endo_guidance::sim;
namespace test = endo_guidance::test;
using test::defaultK;
using test::estimateCylinderPoseConic;

namespace {
double relErr(PluckerLine const& e, PluckerLine const& t) {
  return std::max((e.direction() - t.direction()).norm(), (e.moment() - t.moment()).norm() / t.moment().norm());
}
}  // namespace

// Exact round trip: forward model -> both closed forms, thousands of random poses.
TEST(CylinderPose, RoundTripExactBothForms) {
  std::mt19937_64 rng(11);
  Eigen::Matrix3d const K = defaultK();
  double worst_geo = 0.0, worst_conic = 0.0;
  for (int k = 0; k < 5000; ++k) {
    auto const c = test::randomCylinder(rng);
    auto const lines = projectCylinder(K, c.axis, c.radius);
    ASSERT_TRUE(lines);
    auto const g = estimateCylinderPose(K, c.radius, (*lines)[0], (*lines)[1]);
    auto const a = estimateCylinderPoseConic(K, c.radius, (*lines)[0], (*lines)[1]);
    ASSERT_TRUE(g.ok()) << toString(g.status);
    ASSERT_TRUE(a.ok()) << toString(a.status);
    worst_geo = std::max(worst_geo, relErr(g.pose.axis, c.axis));
    worst_conic = std::max(worst_conic, relErr(a.pose.axis, c.axis));
    EXPECT_NEAR(g.pose.distance, c.axis.distanceToOrigin(), 1e-9 * c.axis.distanceToOrigin());
  }
  RecordProperty("worst_relative_error_geometric", std::to_string(worst_geo));
  RecordProperty("worst_relative_error_conic", std::to_string(worst_conic));
  EXPECT_LT(worst_geo, 1e-9);
  EXPECT_LT(worst_conic, 1e-9);
}

// The forward model against ViSP's vpCylinder (independent implementation): same two lines.
TEST(CylinderPose, ForwardModelMatchesViSPCylinder) {
  std::mt19937_64 rng(12);
  Eigen::Matrix3d const I = Eigen::Matrix3d::Identity();  // normalised coordinates, as ViSP
  for (int k = 0; k < 1000; ++k) {
    auto const c = test::randomCylinder(rng);
    Eigen::Vector3d const d = c.axis.direction(), p = c.visible_point;
    vpCylinder cyl(d.x(), d.y(), d.z(), p.x(), p.y(), p.z(), c.radius);
    cyl.track(vpHomogeneousMatrix());  // camera = object frame
    auto const lines = projectCylinder(I, c.axis, c.radius);
    ASSERT_TRUE(lines);
    // ViSP: x cos(theta) + y sin(theta) - rho = 0 ; ours: a x + b y + c = 0 with a^2+b^2 = 1.
    Eigen::Vector3d const v1(std::cos(cyl.getTheta1()), std::sin(cyl.getTheta1()), -cyl.getRho1());
    Eigen::Vector3d const v2(std::cos(cyl.getTheta2()), std::sin(cyl.getTheta2()), -cyl.getRho2());
    auto match = [](Eigen::Vector3d const& a, Eigen::Vector3d const& b) {
      return std::min((a - b).norm(), (a + b).norm());
    };
    double const straight = std::max(match((*lines)[0], v1), match((*lines)[1], v2));
    double const swapped = std::max(match((*lines)[0], v2), match((*lines)[1], v1));
    EXPECT_LT(std::min(straight, swapped), 1e-9) << "pose " << k;
    // And the pose recovered from ViSP's lines (oriented with a point of the shaft) is the truth.
    Eigen::Vector3d l0 = v1, l1 = v2;
    Eigen::Vector3d const x = p / p.z();
    if (l0.dot(x) < 0) l0 = -l0;
    if (l1.dot(x) < 0) l1 = -l1;
    auto const r = estimateCylinderPose(I, c.radius, l0, l1);
    ASSERT_TRUE(r.ok());
    PluckerLine axis = r.pose.axis;
    if (axis.direction().dot(d) < 0) axis = axis.reversed();  // ViSP lines carry no order
    EXPECT_LT(relErr(axis, c.axis), 1e-9);
  }
}

// Ordering convention: lines[0] on the left walking entry -> tip; direction entry -> tip.
TEST(CylinderPose, OrderConventionGivesEntryToTipDirection) {
  SyntheticScene scene(defaultInstruments());
  int checked = 0;
  for (int k = 0; k < 200; ++k) {
    for (auto const& v : scene.frame(k)) {
      Eigen::Vector2d const t = (v.truth.tip_px - v.truth.entry_px).normalized();
      Eigen::Vector2d const left(t.y(), -t.x());  // v points down
      EXPECT_LT(v.truth.lines[0].head<2>().dot(left), 0.0);  // shaft is to its right
      EXPECT_GT(v.truth.lines[1].head<2>().dot(left), 0.0);
      auto const r = estimateCylinderPose(scene.options().K, v.radius, v.truth);
      ASSERT_TRUE(r.ok());
      EXPECT_GT(r.pose.axis.direction().dot(v.axis.direction()), 0.999999);
      // Swapping the lines reverses the orientation (same line).
      auto const s = estimateCylinderPose(scene.options().K, v.radius, v.truth.lines[1], v.truth.lines[0]);
      ASSERT_TRUE(s.ok());
      EXPECT_LT(s.pose.axis.direction().dot(v.axis.direction()), -0.999999);
      EXPECT_LT(s.pose.axis.distanceTo(v.axis), 1e-9);
      ++checked;
    }
  }
  EXPECT_GT(checked, 300);
}

// An axis parallel to the image plane images as two parallel lines: a valid pose.
TEST(CylinderPose, ParallelImageLinesAreValid) {
  Eigen::Matrix3d const K = defaultK();
  auto const axis = PluckerLine::fromPointDirection({0.01, -0.02, 0.1}, {1, 0.3, 0});
  auto const lines = projectCylinder(K, *axis, 0.004);
  ASSERT_TRUE(lines);
  EXPECT_NEAR(std::abs((*lines)[0].head<2>().dot((*lines)[1].head<2>())), 1.0, 1e-12);
  auto const r = estimateCylinderPose(K, 0.004, (*lines)[0], (*lines)[1]);
  ASSERT_TRUE(r.ok());
  EXPECT_LT(relErr(r.pose.axis, *axis), 1e-9);
  auto const a = estimateCylinderPoseConic(K, 0.004, (*lines)[0], (*lines)[1]);
  ASSERT_TRUE(a.ok());
  EXPECT_LT(relErr(a.pose.axis, *axis), 1e-9);
}

TEST(CylinderPose, TipBackProjection) {
  SyntheticScene scene(defaultInstruments());
  for (auto const& v : scene.frame(10)) {
    auto const tip = backProjectOntoAxis(scene.options().K, v.axis, v.truth.tip_px);
    ASSERT_TRUE(tip);
    EXPECT_LT((*tip - v.tip_c).norm(), 1e-9);
    // The same from the viewing ray alone (any point on it, here 3x the tip): the servo's use.
    auto const again = backProjectOntoAxis(v.axis, 3.0 * v.tip_c);
    ASSERT_TRUE(again);
    EXPECT_LT((*again - v.tip_c).norm(), 1e-9);
    // A ray along the axis meets it nowhere in particular; no ray at all is refused.
    EXPECT_FALSE(backProjectOntoAxis(v.axis, v.axis.direction()));
    EXPECT_FALSE(backProjectOntoAxis(v.axis, Eigen::Vector3d::Zero()));
    EXPECT_FALSE(backProjectOntoAxis(v.axis, Eigen::Vector3d(std::nan(""), 0.0, 1.0)));
  }
}

// Degenerate input is flagged, never guessed, and no NaN escapes.
TEST(CylinderPose, DegenerateInputIsFlagged) {
  Eigen::Matrix3d const K = defaultK();
  auto const axis = PluckerLine::fromPointDirection({0.0, 0.0, 0.1}, {1, 0.2, 0.3});
  auto const lines = projectCylinder(K, *axis, 0.004);
  ASSERT_TRUE(lines);
  Eigen::Vector3d const l0 = (*lines)[0], l1 = (*lines)[1];
  auto status = [&](Eigen::Vector3d const& a, Eigen::Vector3d const& b, double r = 0.004,
                    CylinderPoseOptions const& o = {}, std::optional<Eigen::Vector2d> in = std::nullopt,
                    Eigen::Matrix3d const& KK = defaultK()) {
    auto const g = estimateCylinderPose(KK, r, a, b, o, in);
    EXPECT_TRUE(g.pose.axis.direction().allFinite() && g.pose.axis.moment().allFinite());
    return g.status;
  };
  EXPECT_EQ(status(l0, l0), CylinderPoseStatus::kIdenticalPlanes);
  EXPECT_EQ(status(l0, -l0), CylinderPoseStatus::kIdenticalPlanes);
  EXPECT_EQ(status(l0, 3.0 * l0), CylinderPoseStatus::kIdenticalPlanes);
  EXPECT_EQ(estimateCylinderPoseConic(K, 0.004, l0, l0).status, CylinderPoseStatus::kIdenticalPlanes);
  EXPECT_EQ(status(l0, Eigen::Vector3d(0, 0, 1)), CylinderPoseStatus::kInvalidInput);
  EXPECT_EQ(status(l0, Eigen::Vector3d(NAN, 0, 1)), CylinderPoseStatus::kInvalidInput);
  EXPECT_EQ(status(l0, l1, 0.0), CylinderPoseStatus::kInvalidInput);
  EXPECT_EQ(status(l0, l1, -1.0), CylinderPoseStatus::kInvalidInput);
  EXPECT_EQ(status(l0, l1, 0.004, {}, std::nullopt, Eigen::Matrix3d::Zero()), CylinderPoseStatus::kInvalidInput);
  CylinderPoseOptions near;
  near.min_distance = 0.2;
  EXPECT_EQ(status(l0, l1, 0.004, near), CylinderPoseStatus::kTooClose);
  CylinderPoseOptions far;
  far.max_distance = 0.05;
  EXPECT_EQ(status(l0, l1, 0.004, far), CylinderPoseStatus::kTooFar);
  // Lines on the wrong side: one line flipped, checked with a pixel of the shaft.
  Eigen::Vector3d const P = K * axis->closestPointToOrigin();
  Eigen::Vector2d const shaft_px = P.head<2>() / P.z();
  EXPECT_EQ(status(l0, l1, 0.004, {}, shaft_px), CylinderPoseStatus::kOk);
  EXPECT_EQ(status(l0, -l1, 0.004, {}, shaft_px), CylinderPoseStatus::kWrongSide);
  EXPECT_EQ(status(-l0, -l1, 0.004, {}, shaft_px), CylinderPoseStatus::kWrongSide);
  // Without that pixel, a flipped line selects the other wedge: a different, far-off cylinder.
  auto const other = estimateCylinderPose(K, 0.004, l0, -l1);
  if (other.ok()) {
    EXPECT_GT(other.pose.axis.distanceTo(*axis), 0.001);
  }
  // The forward model refuses a camera inside or on the cylinder.
  EXPECT_FALSE(projectCylinder(K, *axis, axis->distanceToOrigin()));
  EXPECT_FALSE(projectCylinder(K, *axis, 2.0 * axis->distanceToOrigin()));
}

// With 0.5 px line noise: errors reported and bounded, and the propagated covariance is
// consistent with them (mean NEES close to the rank, 4).
TEST(CylinderPose, NoisyLinesErrorAndCovariance) {
  SyntheticSceneOptions so;
  so.line_noise_px = 0.5;
  so.seed = 7;
  SyntheticScene scene(defaultInstruments(), so);
  std::vector<double> dir_deg, dist_rel, nees;
  for (int k = 0; k < 1500; ++k) {
    for (auto const& v : scene.frame(k)) {
      auto const r = estimateCylinderPose(so.K, v.radius, v.measured);
      ASSERT_TRUE(r.ok()) << toString(r.status);
      dir_deg.push_back(test::angleDeg(r.pose.axis.direction(), v.axis.direction()));
      dist_rel.push_back(std::abs(r.pose.distance - v.axis.distanceToOrigin()) / v.axis.distanceToOrigin());
      Eigen::Matrix<double, 6, 1> e;
      e << r.pose.axis.direction() - v.axis.direction(), r.pose.axis.moment() - v.axis.moment();
      Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> es(r.pose.covariance);
      double chi2 = 0.0;
      double const top = es.eigenvalues().maxCoeff();
      ASSERT_GT(top, 0.0);
      for (int i = 0; i < 6; ++i)
        if (es.eigenvalues()(i) > 1e-9 * top) chi2 += std::pow(es.eigenvectors().col(i).dot(e), 2) / es.eigenvalues()(i);
      nees.push_back(chi2);
    }
  }
  double const mean_nees = std::accumulate(nees.begin(), nees.end(), 0.0) / nees.size();
  std::printf("[ noise 0.5 px, %zu poses ] direction median %.3f deg p95 %.3f deg; distance median %.3f %% p95 %.3f %%; "
              "mean NEES %.2f (rank 4)\n",
              dir_deg.size(), test::percentile(dir_deg, 0.5), test::percentile(dir_deg, 0.95),
              100 * test::percentile(dist_rel, 0.5), 100 * test::percentile(dist_rel, 0.95), mean_nees);
  EXPECT_GT(dir_deg.size(), 2000u);
  // 0.5 px on the endpoints of 20-40 px wide shafts: ~2 % of the apparent width.
  EXPECT_LT(test::percentile(dir_deg, 0.5), 2.5);
  EXPECT_LT(test::percentile(dist_rel, 0.5), 0.025);
  EXPECT_GT(mean_nees, 3.0);
  EXPECT_LT(mean_nees, 5.5);
}
