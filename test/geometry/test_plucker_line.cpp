// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include "endo_guidance/geometry/plucker_line.h"
#include "test_util.h"

using namespace endo_guidance::geometry;
namespace test = endo_guidance::test;

TEST(PluckerLine, InvariantsFromAnyInput) {
  auto L = PluckerLine::fromDirectionMoment({0, 0, 2}, {1, 1, 5});
  ASSERT_TRUE(L);
  EXPECT_NEAR(L->direction().norm(), 1.0, 1e-15);
  EXPECT_NEAR(L->direction().dot(L->moment()), 0.0, 1e-15);
  EXPECT_FALSE(PluckerLine::fromDirectionMoment({0, 0, 0}, {1, 0, 0}));
  EXPECT_FALSE(PluckerLine::fromPointDirection({NAN, 0, 0}, {1, 0, 0}));
  EXPECT_FALSE(PluckerLine::through({1, 2, 3}, {1, 2, 3}));
}

TEST(PluckerLine, ThroughTwoPointsContainsBoth) {
  Eigen::Vector3d const p(0.1, -0.2, 0.3), q(-0.05, 0.07, 0.12);
  auto L = PluckerLine::through(p, q);
  ASSERT_TRUE(L);
  EXPECT_NEAR(L->distanceTo(p), 0.0, 1e-15);
  EXPECT_NEAR(L->distanceTo(q), 0.0, 1e-15);
  EXPECT_NEAR(L->direction().dot((q - p).normalized()), 1.0, 1e-15);
  // Distance of the closest point to the origin equals |m| and is perpendicular to d.
  EXPECT_NEAR(L->closestPointToOrigin().norm(), L->distanceToOrigin(), 1e-15);
  EXPECT_NEAR(L->closestPointToOrigin().dot(L->direction()), 0.0, 1e-15);
  // A point off the line at a known distance.
  Eigen::Vector3d const n = L->direction().unitOrthogonal();
  EXPECT_NEAR(L->distanceTo(p + 0.013 * n), 0.013, 1e-15);
  EXPECT_TRUE(L->closestPointTo(p + 0.013 * n).isApprox(p, 1e-12));
}

TEST(PluckerLine, TransformMatchesTransformedPoints) {
  std::mt19937_64 rng(3);
  for (int k = 0; k < 200; ++k) {
    auto const c = test::randomCylinder(rng);
    Eigen::Isometry3d aMb = Eigen::Isometry3d::Identity();
    aMb.linear() = Eigen::Quaterniond::UnitRandom().toRotationMatrix();
    aMb.translation() = Eigen::Vector3d::Random() * 0.2;
    PluckerLine const La = c.axis.transformed(aMb);
    auto const ref = PluckerLine::through(aMb * c.axis.pointAt(0.0), aMb * c.axis.pointAt(0.1));
    ASSERT_TRUE(ref);
    EXPECT_LT((La.direction() - ref->direction()).norm(), 1e-12);
    EXPECT_LT((La.moment() - ref->moment()).norm(), 1e-12);
    EXPECT_NEAR(La.direction().dot(La.moment()), 0.0, 1e-14);
  }
}

TEST(PluckerLine, DualMatrixAnnihilatesPointsAndGivesDistance) {
  std::mt19937_64 rng(4);
  for (int k = 0; k < 100; ++k) {
    auto const c = test::randomCylinder(rng);
    Eigen::Matrix4d const L = c.axis.dualMatrix();
    EXPECT_LT((L + L.transpose()).norm(), 1e-15);  // skew
    Eigen::Vector4d X;
    X << c.axis.pointAt(0.05), 1.0;
    EXPECT_LT((L * X).norm(), 1e-14);
    Eigen::Vector3d const off = c.axis.pointAt(0.0) + 0.02 * c.axis.direction().unitOrthogonal();
    X << off, 1.0;
    EXPECT_NEAR((L * X).head<3>().norm(), 0.02, 1e-14);
    Eigen::FullPivLU<Eigen::Matrix4d> lu(L);
    EXPECT_EQ(lu.rank(), 2);
  }
}

TEST(PluckerLine, ProjectionContainsProjectedPoints) {
  std::mt19937_64 rng(5);
  Eigen::Matrix3d const K = test::defaultK();
  for (int k = 0; k < 200; ++k) {
    auto const c = test::randomCylinder(rng);
    auto const l = c.axis.project(K);
    ASSERT_TRUE(l);
    EXPECT_NEAR(l->head<2>().norm(), 1.0, 1e-15);
    for (double t : {-0.02, 0.0, 0.03}) {
      Eigen::Vector3d const X = c.visible_point + t * c.axis.direction();
      if (X.z() <= 0) continue;
      Eigen::Vector3d const x = K * X / X.z();
      EXPECT_NEAR(l->dot(x), 0.0, 1e-9);  // pixels
    }
  }
  // A line through the optical centre has no image line.
  EXPECT_FALSE(PluckerLine::through({0, 0, 0}, {0, 0, 1})->project(K));
}

TEST(PluckerLine, LineToLineDistance) {
  auto a = PluckerLine::fromPointDirection({0, 0, 0}, {1, 0, 0});
  auto b = PluckerLine::fromPointDirection({0, 0.05, 1}, {0, 0, 1});
  auto c = PluckerLine::fromPointDirection({0, 0.03, 0}, {-2, 0, 0});
  EXPECT_NEAR(a->distanceTo(*b), 0.05, 1e-15);
  EXPECT_NEAR(a->distanceTo(*c), 0.03, 1e-15);  // parallel
  EXPECT_NEAR(a->distanceTo(a->reversed()), 0.0, 1e-15);
  EXPECT_TRUE(a->reversed().direction().isApprox(-a->direction()));
}
