// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// Shared helpers of the core tests: random cylinder poses in front of a camera.
#pragma once

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "endo_guidance/geometry/plucker_line.h"

namespace endo_guidance::test {

inline Eigen::Matrix3d defaultK() {
  return (Eigen::Matrix3d() << 500, 0, 319.5, 0, 500, 239.5, 0, 0, 1).finished();
}

struct RandomCylinder {
  geometry::PluckerLine axis;
  double radius;
  Eigen::Vector3d visible_point;  ///< a point of the axis seen inside the 640x480 image
};

/// Axis through a point seen at a random pixel of a 640x480 image, 3-30 cm from the camera,
/// radius 2.5-5 mm, direction at least 20 degrees off the viewing ray.
inline RandomCylinder randomCylinder(std::mt19937_64& rng, Eigen::Matrix3d const& K = defaultK()) {
  std::uniform_real_distribution<double> U(0.0, 1.0);
  for (;;) {
    Eigen::Vector3d const px(40 + 560 * U(rng), 40 + 400 * U(rng), 1.0);
    Eigen::Vector3d const ray = K.inverse() * px;
    double const dist = 0.03 + 0.27 * U(rng);
    Eigen::Vector3d const P = ray.normalized() * dist;
    Eigen::Vector3d d(U(rng) - 0.5, U(rng) - 0.5, U(rng) - 0.5);
    if (d.norm() < 1e-3) continue;
    d.normalize();
    if (std::abs(d.dot(ray.normalized())) > std::cos(20.0 * M_PI / 180.0)) continue;
    double const r = 0.0025 + 0.0025 * U(rng);
    auto L = geometry::PluckerLine::fromPointDirection(P, d);
    if (!L || L->distanceToOrigin() < 3.0 * r) continue;
    return {*L, r, P};
  }
}

inline double percentile(std::vector<double> v, double p) {
  if (v.empty()) return 0.0;
  std::sort(v.begin(), v.end());
  std::size_t const i = std::min(v.size() - 1, static_cast<std::size_t>(p * (v.size() - 1) + 0.5));
  return v[i];
}

inline double angleDeg(Eigen::Vector3d const& a, Eigen::Vector3d const& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b)) * 180.0 / M_PI;
}

}  // namespace endo_guidance::test
