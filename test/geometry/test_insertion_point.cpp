// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <cstdio>
#include <limits>

#include "endo_guidance/geometry/cylinder_pose.h"
#include "endo_guidance/geometry/insertion_point.h"
#include "endo_guidance/geometry/insertion_point_image.h"
#include "endo_guidance/geometry/insertion_point_tracker.h"
#include "endo_guidance/sim/synthetic_scene.h"
#include "test_util.h"

using namespace endo_guidance::geometry;
using namespace endo_guidance::sim;
namespace test = endo_guidance::test;

namespace {

Eigen::Vector3d const kTrocar(0.09, -0.03, 0.02);

// Axes through `T` toward random points in front of the camera (spread of tens of degrees).
std::vector<PluckerLine> axesThrough(Eigen::Vector3d const& T, int n, std::mt19937_64& rng, double spread = 0.04) {
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  std::vector<PluckerLine> v;
  for (int i = 0; i < n; ++i) {
    Eigen::Vector3d const tip(spread * U(rng), spread * U(rng), 0.12 + 0.02 * U(rng));
    v.push_back(*PluckerLine::through(T, tip));
  }
  return v;
}

PluckerLine randomAxis(std::mt19937_64& rng) { return test::randomCylinder(rng).axis; }

// Axes measured the way the pipeline measures them: noisy contours -> cylinder pose.
std::vector<CylinderPose> measuredAxes(SyntheticScene& scene, int frames, int instrument) {
  std::vector<CylinderPose> v;
  for (int k = 0; k < frames; ++k)
    for (auto const& view : scene.frame(k)) {
      if (view.instrument != instrument) continue;
      auto const r = estimateCylinderPose(scene.options().K, view.radius, view.measured);
      if (r.ok()) v.push_back(r.pose);
    }
  return v;
}

// Axes through T, each shifted across itself by N(0, sigma) at T.
std::vector<PluckerLine> noisyAxesThrough(Eigen::Vector3d const& T, int n, std::mt19937_64& rng, double sigma) {
  std::normal_distribution<double> N(0.0, sigma);
  std::vector<PluckerLine> v;
  for (auto const& a : axesThrough(T, n, rng)) {
    Eigen::Vector3d const e1 = a.direction().unitOrthogonal(), e2 = a.direction().cross(e1);
    v.push_back(*PluckerLine::fromPointDirection(T + N(rng) * e1 + N(rng) * e2, a.direction()));
  }
  return v;
}

}  // namespace

TEST(InsertionPoint, TwoAndThreeExactAxes) {
  std::mt19937_64 rng(1);
  for (int n : {2, 3}) {
    auto const axes = axesThrough(kTrocar, n, rng);
    auto const e = intersectAxes(axes);
    ASSERT_TRUE(e.ok()) << toString(e.status);
    EXPECT_LT((e.position - kTrocar).norm(), 1e-12);
    EXPECT_LT(e.rms_distance, 1e-12);
    EXPECT_GT(e.homogeneous.z(), 0.0);  // sign convention I_z > 0
    EXPECT_NEAR(e.homogeneous.norm(), 1.0, 1e-12);
    EXPECT_EQ(e.views, static_cast<std::size_t>(n));
  }
}

TEST(InsertionPoint, FewOrParallelAxesAreFlagged) {
  std::mt19937_64 rng(2);
  EXPECT_EQ(intersectAxes({}).status, InsertionPointStatus::kTooFewAxes);
  EXPECT_EQ(intersectAxes(axesThrough(kTrocar, 1, rng)).status, InsertionPointStatus::kTooFewAxes);
  std::vector<PluckerLine> par;
  for (int i = 0; i < 5; ++i) par.push_back(*PluckerLine::fromPointDirection({0.01 * i, 0.002 * i * i, 0.1}, {0.3, 0.2, 1}));
  auto const e = intersectAxes(par);
  EXPECT_EQ(e.status, InsertionPointStatus::kAtInfinity);
  EXPECT_TRUE(e.homogeneous.allFinite());
  EXPECT_NEAR(e.conditioning, 0.0, 1e-9);
  EXPECT_EQ(intersectAxesRobust(par).status, InsertionPointStatus::kAtInfinity);
  // Weights of zero remove axes.
  auto axes = axesThrough(kTrocar, 3, rng);
  EXPECT_EQ(intersectAxes(axes, {1.0, 0.0, 0.0}).status, InsertionPointStatus::kTooFewAxes);
}

TEST(InsertionPoint, ConditioningIsAngularSpread) {
  // Axes in a plane at angles +-theta about the mean direction: spread = sin(theta) ~ theta.
  double const th = 3.0 * M_PI / 180.0;
  std::vector<PluckerLine> axes;
  for (double s : {-1.0, 1.0})
    axes.push_back(*PluckerLine::fromPointDirection(kTrocar, {std::sin(s * th), 0.0, std::cos(s * th)}));
  EXPECT_NEAR(axesAngularSpread(axes), std::sin(th), 1e-12);
  EXPECT_NEAR(intersectAxes(axes).conditioning, std::sin(th), 1e-12);
}

TEST(InsertionPoint, FiftyNoisyAxes) {
  std::mt19937_64 rng(4);
  for (double sigma : {0.0005, 0.002}) {
    auto const axes = noisyAxesThrough(kTrocar, 50, rng, sigma);
    auto const e = intersectAxes(axes);
    ASSERT_TRUE(e.ok());
    double const err = (e.position - kTrocar).norm();
    double const sd = std::sqrt(e.covariance.eigenvalues().real().maxCoeff());
    std::printf("[ 50 axes, %.1f mm across ] error %.3f mm, rms %.3f mm, spread %.1f deg, 1-sigma(max) %.3f mm\n",
                sigma * 1e3, err * 1e3, e.rms_distance * 1e3, std::asin(e.conditioning) * 180 / M_PI, sd * 1e3);
    EXPECT_NEAR(e.rms_distance, sigma * std::sqrt(2.0), 0.3 * sigma);
    EXPECT_LT(err, 4.0 * sd);  // the covariance covers the error
    EXPECT_LT(err, 2.0 * sigma);
  }
}

// Axes from noisy contours pivot about their visible part: their angular noise biases a plain
// least-squares point toward the image. Weighting each axis by its propagated covariance
// (the tracker) removes most of it.
TEST(InsertionPoint, CovarianceWeightingRemovesErrorsInVariablesBias) {
  SyntheticSceneOptions so;
  so.line_noise_px = 0.5;
  SyntheticScene scene(defaultInstruments(), so);
  for (int i = 0; i < 3; ++i) {
    auto const poses = measuredAxes(scene, 500, i);
    std::vector<PluckerLine> axes;
    InsertionPointTracker t;
    for (auto const& p : poses) {
      axes.push_back(p.axis);
      t.update(p.axis, p.covariance);
    }
    double const plain = (intersectAxes(axes).position - scene.meanTrocar(i)).norm();
    double const weighted = (t.estimate().position - scene.meanTrocar(i)).norm();
    std::printf("[ 0.5 px contours, %zu axes ] trocar %d: plain Eq. (3) %.2f mm, covariance-weighted %.2f mm\n",
                axes.size(), i, plain * 1e3, weighted * 1e3);
    EXPECT_GT(plain, 0.004);
    EXPECT_LT(weighted, 0.5 * plain);
    EXPECT_LT(weighted, 0.0025);
  }
}

TEST(InsertionPoint, RobustSurvivesHalfOutliers) {
  std::mt19937_64 rng(5);
  std::normal_distribution<double> N(0.0, 0.0003);
  auto axes = axesThrough(kTrocar, 50, rng);
  for (auto& a : axes) a = *PluckerLine::fromPointDirection(a.closestPointTo(kTrocar) + Eigen::Vector3d(N(rng), N(rng), N(rng)), a.direction());
  for (int i = 0; i < 50; ++i) axes.push_back(randomAxis(rng));  // 50 % wrong axes
  auto const plain = intersectAxes(axes);
  auto const robust = intersectAxesRobust(axes);
  ASSERT_TRUE(robust.ok());
  std::printf("[ 50 %% outliers ] plain LS error %.2f mm, robust error %.3f mm, inliers %zu\n",
              (plain.position - kTrocar).norm() * 1e3, (robust.position - kTrocar).norm() * 1e3, robust.inliers.size());
  EXPECT_GT((plain.position - kTrocar).norm(), 0.005);  // the test can fail: plain LS is off
  EXPECT_LT((robust.position - kTrocar).norm(), 0.0005);
  EXPECT_GE(robust.inliers.size(), 48u);
  EXPECT_LE(robust.inliers.size(), 55u);
}

TEST(InsertionPoint, IllConditionedEstimateIsElongatedAndSaysSo) {
  std::mt19937_64 rng(6);
  std::normal_distribution<double> N(0.0, 0.0002), A(0.0, 1.0 * M_PI / 180.0);  // 1 degree of spread
  Eigen::Vector3d const mean_dir = (Eigen::Vector3d(0, 0, 0.12) - kTrocar).normalized();
  Eigen::Vector3d const e1 = mean_dir.unitOrthogonal(), e2 = mean_dir.cross(e1);
  std::vector<PluckerLine> noisy;
  for (int i = 0; i < 40; ++i) {
    Eigen::Vector3d const d = (mean_dir + A(rng) * e1 + A(rng) * e2).normalized();
    noisy.push_back(*PluckerLine::fromPointDirection(kTrocar + Eigen::Vector3d(N(rng), N(rng), N(rng)), d));
  }
  auto const e = intersectAxes(noisy);
  ASSERT_TRUE(e.ok());
  InsertionPointTrackerOptions to;
  EXPECT_LT(e.conditioning, to.min_conditioning);
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(e.covariance);
  // Largest uncertainty along the mean axis direction, much larger than across.
  EXPECT_GT(std::abs(es.eigenvectors().col(2).dot(mean_dir)), 0.95);
  EXPECT_GT(es.eigenvalues()(2), 50.0 * es.eigenvalues()(1));
}

TEST(InsertionPointTracker, BreathingTrocarFollowsMean) {
  for (double noise : {0.1, 0.5}) {
    SyntheticSceneOptions so;
    so.line_noise_px = noise;
    so.breathing_amplitude = 0.002;
    SyntheticScene scene(defaultInstruments(), so);
    for (int i = 0; i < 3; ++i) {
      InsertionPointTracker t;
      auto const poses = measuredAxes(scene, 600, i);
      for (auto const& p : poses) t.update(p.axis, p.covariance);
      ASSERT_TRUE(t.initialized());
      ASSERT_GE(poses.size(), 100u);
      double const err = (t.estimate().position - scene.meanTrocar(i)).norm();
      std::printf("[ tracker, 2 mm breathing, %.1f px ] trocar %d: %zu axes, error to mean %.3f mm, rms %.3f mm, "
                  "spread %.1f deg, rejected %zu\n",
                  noise, i, poses.size(), err * 1e3, t.estimate().rms_distance * 1e3,
                  std::asin(t.estimate().conditioning) * 180 / M_PI, t.rejected());
      EXPECT_LT(err, noise < 0.3 ? 0.0015 : 0.0035);
      EXPECT_TRUE(t.wellConditioned());
    }
  }
}

TEST(InsertionPointTracker, OutlierStreamAndRelocation) {
  std::mt19937_64 rng(8);
  InsertionPointTracker t;
  auto const good = axesThrough(kTrocar, 200, rng);
  std::bernoulli_distribution coin(0.5);
  for (auto const& a : good) {
    t.update(a);
    if (coin(rng)) t.update(randomAxis(rng));  // ~1/3 of the stream is wrong, from the start
  }
  ASSERT_TRUE(t.estimate().ok());
  // Exact axes, but the few random axes that happen to pass within the gate are accepted too.
  EXPECT_LT((t.estimate().position - kTrocar).norm(), 1e-3);
  EXPECT_GT(t.rejected(), 30u);
  // The trocar is moved by 3 cm (re-porting): the tracker re-initialises on the new point.
  Eigen::Vector3d const moved = kTrocar + Eigen::Vector3d(0.0, 0.03, 0.0);
  for (auto const& a : axesThrough(moved, 120, rng)) t.update(a);
  EXPECT_LT((t.estimate().position - moved).norm(), 1e-3);
  // Freeze: no change.
  t.setFrozen(true);
  EXPECT_EQ(t.update(axesThrough(kTrocar, 1, rng)[0]), InsertionPointTracker::Update::kFrozen);
  EXPECT_LT((t.estimate().position - moved).norm(), 1e-3);
  t.reset();
  EXPECT_FALSE(t.initialized());
  EXPECT_TRUE(std::isinf(t.distanceTo(good[0])));
}

// Axes whose errors are shared by runs of consecutive axes (a shaft seen over several frames
// keeps its compression and shading errors): the covariance must still cover the estimate's
// error. Taking the axes as independent, it is about sqrt(10) too small here.
TEST(InsertionPointTracker, CovarianceCoversErrorsSharedByConsecutiveAxes) {
  auto mahalanobis2 = [](std::size_t correlation_views, int trial) {
    std::mt19937_64 rng(100 + trial);
    std::normal_distribution<double> N(0.0, 1.0);
    InsertionPointTrackerOptions o;
    o.correlation_views = correlation_views;
    InsertionPointTracker t(o);
    auto const axes = axesThrough(kTrocar, 300, rng);
    Eigen::Vector3d shared = Eigen::Vector3d::Zero();
    for (std::size_t k = 0; k < axes.size(); ++k) {
      if (k % 10 == 0) shared = 0.001 * Eigen::Vector3d(N(rng), N(rng), N(rng));  // 1 mm, per run of 10 axes
      Eigen::Vector3d const own = 0.0001 * Eigen::Vector3d(N(rng), N(rng), N(rng));
      t.update(*PluckerLine::fromPointDirection(kTrocar + shared + own, axes[k].direction()));
    }
    EXPECT_TRUE(t.estimate().ok());
    Eigen::Vector3d const e = t.estimate().position - kTrocar;
    return e.dot(t.estimate().covariance.ldlt().solve(e));
  };
  int const trials = 60;
  int covered = 0, covered_model = 0;
  for (int i = 0; i < trials; ++i) {
    covered += mahalanobis2(10, i) < 7.81;      // chi^2 (3 dof) 95 % point
    covered_model += mahalanobis2(0, i) < 7.81;
  }
  std::printf("[ errors shared by 10 consecutive axes ] within the 95 %% ellipsoid: %d / %d (model covariance alone: %d)\n",
              covered, trials, covered_model);
  EXPECT_GE(covered, static_cast<int>(0.85 * trials));
  EXPECT_LT(covered_model, static_cast<int>(0.6 * trials));  // the case is one the model alone fails
}

// A point seen over a narrow fan of axes is well conditioned (its image and the attachment hold)
// before its position along the axes is known: it is located (a frame to pivot about) only once
// its covariance's longest axis is under max_sigma.
TEST(InsertionPointTracker, LocatedOnlyOnceThePositionIsKnown) {
  std::mt19937_64 rng(21);
  std::normal_distribution<double> N(0.0, 0.003);
  auto feed = [&](InsertionPointTracker& t, int n, double spread) {
    for (auto const& a : axesThrough(kTrocar, n, rng, spread)) {
      Eigen::Vector3d const e1 = a.direction().unitOrthogonal(), e2 = a.direction().cross(e1);
      t.update(*PluckerLine::fromPointDirection(kTrocar + N(rng) * e1 + N(rng) * e2, a.direction()));
    }
  };
  InsertionPointTracker t;
  InsertionPointTrackerOptions unlimited;
  unlimited.max_sigma = 0.0;
  InsertionPointTracker u(unlimited);
  feed(t, 20, 0.004);
  rng.seed(21);
  feed(u, 20, 0.004);
  auto sigmaMax = [](InsertionPointTracker const& x) {
    return std::sqrt(Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(x.estimate().covariance).eigenvalues()(2));
  };
  std::printf("[ narrow fan, 3 mm noise ] spread %.1f deg, longest sigma %.1f mm, error %.1f mm\n",
              std::asin(t.estimate().conditioning) * 180 / M_PI, 1e3 * sigmaMax(t), 1e3 * (t.estimate().position - kTrocar).norm());
  ASSERT_TRUE(t.wellConditioned());
  EXPECT_GT(sigmaMax(t), t.options().max_sigma);
  EXPECT_FALSE(t.located());
  EXPECT_TRUE(u.located());  // max_sigma 0: located once well conditioned
  feed(t, 300, 0.05);  // the instrument sweeps wider
  std::printf("[ then a wide fan ] spread %.1f deg, longest sigma %.1f mm, error %.1f mm\n",
              std::asin(t.estimate().conditioning) * 180 / M_PI, 1e3 * sigmaMax(t), 1e3 * (t.estimate().position - kTrocar).norm());
  EXPECT_TRUE(t.located());
  EXPECT_LT((t.estimate().position - kTrocar).norm(), t.options().max_sigma);
}

// An instrument held still after its trocar was located: thousands of copies of one noisy axis
// (eight memory constants, 67 s at 60 Hz) would forget the diverse views that fixed the point,
// its spread would shrink and it would stop being located, and a servo pivoting about it would
// stop for good. Each still axis passes through the point, so it is held where it was; moving
// the instrument again goes on accumulating; a trocar that moves is still found again.
TEST(InsertionPointTracker, AStillInstrumentKeepsItsTrocarLocated) {
  std::mt19937_64 rng(33);
  std::normal_distribution<double> N(0.0, 0.0005);
  InsertionPointTracker t;
  for (auto const& a : axesThrough(kTrocar, 400, rng, 0.06)) t.update(a);
  ASSERT_TRUE(t.located());
  Eigen::Vector3d const before = t.estimate().position;
  PluckerLine const still = axesThrough(kTrocar, 1, rng, 0.06)[0];
  Eigen::Vector3d const e1 = still.direction().unitOrthogonal(), e2 = still.direction().cross(e1);
  int held = 0;
  for (int k = 0; k < 4000; ++k) {
    auto const a = *PluckerLine::fromPointDirection(kTrocar + N(rng) * e1 + N(rng) * e2, still.direction());
    held += t.update(a) == InsertionPointTracker::Update::kHeld;
  }
  std::printf("[ still instrument ] %d of 4000 axes held; spread %.1f deg; moved %.3f mm\n", held,
              std::asin(t.estimate().conditioning) * 180 / M_PI, 1e3 * (t.estimate().position - before).norm());
  EXPECT_TRUE(t.located());
  EXPECT_TRUE(t.held());
  EXPECT_GT(held, 500);
  EXPECT_LT((t.estimate().position - kTrocar).norm(), 1e-3);
  // The same stream on a point never located is not held: an ill-conditioned point stays so.
  InsertionPointTracker u;
  for (int k = 0; k < 300; ++k) u.update(*PluckerLine::fromPointDirection(kTrocar + N(rng) * e1 + N(rng) * e2, still.direction()));
  EXPECT_FALSE(u.located());
  EXPECT_FALSE(u.held());
  // Moving again: accumulated, not held.
  for (auto const& a : axesThrough(kTrocar, 200, rng, 0.06)) t.update(a);
  EXPECT_TRUE(t.located());
  EXPECT_FALSE(t.held());
  // The trocar re-ported 3 cm away: the axes leave the gate and the point is found there.
  Eigen::Vector3d const moved = kTrocar + Eigen::Vector3d(0.0, 0.03, 0.0);
  for (auto const& a : axesThrough(moved, 400, rng, 0.06)) t.update(a);
  EXPECT_LT((t.estimate().position - moved).norm(), 1e-3);
}

// Precise axes of a breathing trocar (2 mm, a 4 s cycle) seen over a fan that widens slowly: the
// trocar's motion across the axes is shared by every axis of a breathing cycle, and moves the
// point along the narrow fan by that motion over the fan's spread. A point must not be located
// (published for the servo to pivot about) that far off: with blocks of 10 axes taken as
// independent, it was, 18.5 mm off at 4.8 mm claimed (rendered hard scene without JPEG). Every
// located estimate lies within 3 of its claimed longest sigmas of the true mean. The cycles are
// counted in time: the same axes stamped at 12.5 Hz span twice the cycles and are located sooner.
TEST(InsertionPointTracker, ABreathingTrocarIsNotLocatedBeforeItsMotionAverages) {
  SyntheticSceneOptions so;
  so.line_noise_px = 0.02;
  so.breathing_amplitude = 0.002;
  struct Run {
    int first = -1;           // first frame located
    double worst_mm = 0.0;    // largest error while located
    double worst_ratio = 0.0; // ... in claimed longest sigmas
  };
  auto run = [&](double breathing_period, double rate_hz, int instrument) {
    SyntheticScene scene(defaultInstruments(), so);
    InsertionPointTrackerOptions o;
    o.breathing_period = breathing_period;
    InsertionPointTracker t(o);
    Run r;
    for (int k = 0; k < 300; ++k)
      for (auto const& view : scene.frame(k)) {
        if (view.instrument != instrument) continue;
        auto const p = estimateCylinderPose(so.K, view.radius, view.measured);
        if (!p.ok()) continue;
        t.update(p.pose.axis, p.pose.covariance, rate_hz > 0.0 ? k / rate_hz : std::numeric_limits<double>::quiet_NaN());
        if (!t.located()) continue;
        if (r.first < 0) r.first = k;
        double const e = (t.estimate().position - scene.meanTrocar(instrument)).norm();
        r.worst_mm = std::max(r.worst_mm, 1e3 * e);
        r.worst_ratio = std::max(r.worst_ratio, e / t.estimate().longestSigma());
      }
    return r;
  };
  double const period = InsertionPointTrackerOptions{}.breathing_period;
  double worst_without = 0.0;
  int sooner = 0;
  for (int i = 0; i < 3; ++i) {
    Run const at25 = run(period, 25.0, i), unstamped = run(period, 0.0, i), at12 = run(period, 12.5, i), off = run(0.0, 25.0, i);
    std::printf("[ breathing trocar %d, precise axes ] located from frame %d, at most %.2f mm / %.1f claimed sigmas off; "
                "stamped at 12.5 Hz from frame %d; without the breathing term from frame %d, %.2f mm / %.1f sigmas\n",
                i, at25.first, at25.worst_mm, at25.worst_ratio, at12.first, off.first, off.worst_mm, off.worst_ratio);
    EXPECT_GE(at25.first, 0) << "trocar " << i << " never located in 300 frames";
    EXPECT_LT(at25.worst_ratio, 3.0) << "trocar " << i;
    EXPECT_EQ(unstamped.first, at25.first) << "unstamped axes are taken at 25 Hz";
    EXPECT_LE(at12.first, at25.first);
    sooner += at12.first < at25.first;
    worst_without = std::max(worst_without, off.worst_ratio);
  }
  EXPECT_GT(sooner, 0);              // the stamps count
  EXPECT_GT(worst_without, 3.0);     // the case is one the blocks of 10 axes alone fail
}

TEST(InsertionPointTracker, AnUncertainAxisDoesNotWidenTheGate) {
  // Exact axes through the point: its spread is nil, and the gate is the default one. An axis
  // whose own covariance is wide at the point (a short shaft) does not widen it to gate_max: a
  // mis-segmented short shaft (lines along its open jaws, 7-11 deg off) was attached that way.
  std::mt19937_64 rng(9);
  InsertionPointTracker t;
  for (auto const& a : axesThrough(kTrocar, 60, rng)) t.update(a);
  ASSERT_TRUE(t.estimate().ok());
  InsertionPointTrackerOptions const o;
  PluckerLine const probe = axesThrough(kTrocar, 1, rng)[0];
  AxisCovariance const precise = AxisCovariance::Identity() * 1e-12;
  AxisCovariance const wide = AxisCovariance::Identity() * 1e-2;  // 0.1 rad, 0.1 m: 1 cm and more at the point
  EXPECT_NEAR(t.gate(probe, precise), o.gate_distance, 1e-6);
  EXPECT_LT(t.gate(probe, wide), 1.05 * o.gate_distance);
  EXPECT_LT(t.gate(probe, wide), 0.5 * o.gate_max);
}

TEST(InsertionPointSet, DiscoversThreeTrocarsAndAttaches) {
  SyntheticSceneOptions so;
  so.line_noise_px = 0.2;
  so.breathing_amplitude = 0.002;
  SyntheticScene scene(defaultInstruments(), so);
  InsertionPointSet set;
  std::size_t attached = 0, wrong = 0, total = 0;
  std::mt19937_64 rng(9);
  for (int k = 0; k < 600; ++k)
    for (auto const& v : scene.frame(k)) {
      auto const r = estimateCylinderPose(so.K, v.radius, v.measured);
      ASSERT_TRUE(r.ok());
      int const id = set.update(r.pose.axis, r.pose.covariance);
      if (k % 7 == 0) set.update(randomAxis(rng));  // stray axes (gauze, wrong regions)
      if (k < 300) continue;
      ++total;
      if (id < 0) continue;
      ++attached;
      wrong += (set.find(id)->estimate().position - scene.meanTrocar(v.instrument)).norm() > 0.005;
    }
  ASSERT_EQ(set.points().size(), 3u);
  for (int i = 0; i < 3; ++i) {
    double best = 1e9;
    for (auto const& p : set.points()) best = std::min(best, (p.tracker.estimate().position - scene.meanTrocar(i)).norm());
    std::printf("[ set, 0.2 px, 2 mm breathing, stray axes ] trocar %d: error %.3f mm\n", i, best * 1e3);
    EXPECT_LT(best, 0.002) << "trocar " << i;
  }
  EXPECT_GT(attached, 0.97 * total);
  EXPECT_EQ(wrong, 0u);
}

TEST(InsertionPointImage, LeastSquaresMatchesProjectionOfTheTrocar) {
  std::mt19937_64 rng(10);
  Eigen::Matrix3d const K = test::defaultK();
  for (Eigen::Vector3d T : {kTrocar, Eigen::Vector3d(0.09, -0.03, 0.0), Eigen::Vector3d(0.02, 0.01, 0.08)}) {
    std::vector<ImageLine> lines;
    for (auto const& a : axesThrough(T, 10, rng)) lines.push_back(*imageOfAxis(K, a));
    auto const e = intersectImageLines(lines, {319.5, 239.5}, 400.0);
    ASSERT_TRUE(e.ok);
    Eigen::Vector3d const truth = projectPointHomogeneous(K, T);
    EXPECT_LT(std::min((e.point - truth).norm(), (e.point + truth).norm()), 1e-9);
    if (T.z() == 0.0) {
      EXPECT_TRUE(e.atInfinity());  // a trocar in the camera's plane images at infinity
    } else {
      EXPECT_LT(e.rms_px, 1e-6);
    }
  }
}

TEST(InsertionPointImage, RobustWithOutliers) {
  std::mt19937_64 rng(11);
  Eigen::Matrix3d const K = test::defaultK();
  std::vector<ImageLine> lines;
  for (auto const& a : axesThrough(kTrocar, 20, rng)) lines.push_back(*imageOfAxis(K, a));
  for (int i = 0; i < 18; ++i) lines.push_back(*imageOfAxis(K, randomAxis(rng)));
  Eigen::Vector2d const truth = (projectPointHomogeneous(K, kTrocar).head<2>() / projectPointHomogeneous(K, kTrocar).z());
  auto const plain = intersectImageLines(lines, {319.5, 239.5}, 400.0);
  auto const rob = intersectImageLinesRobust(lines, {319.5, 239.5}, 400.0);
  ASSERT_TRUE(rob.ok && !rob.atInfinity());
  EXPECT_LT((rob.pixel() - truth).norm(), 1e-6);
  EXPECT_GE(rob.inliers.size(), 20u);
  EXPECT_GT(plain.atInfinity() ? 1e9 : (plain.pixel() - truth).norm(), 5.0);
}
