// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/seed_search.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace endo_guidance::perception {

namespace {
// Unit directions, seen from the FOV centre c, of the trocar images (zero: none).
std::vector<Eigen::Vector2d> trocarDirections(cv::Point2f const& c, std::vector<Eigen::Vector3d> const& t) {
  std::vector<Eigen::Vector2d> dirs;
  for (auto const& tj : t) {
    Eigen::Vector2d dir;
    if (std::abs(tj.z()) > 1e-12) dir = tj.head<2>() / tj.z() - Eigen::Vector2d(c.x, c.y);
    else dir = tj.head<2>();  // at infinity: its direction
    dirs.push_back(dir.norm() < 1e-9 ? Eigen::Vector2d::Zero() : Eigen::Vector2d(dir.normalized()));
  }
  return dirs;
}

// Index of the trocar image whose direction from the FOV centre is within the arc of p, or -1.
int facingTrocar(cv::Point const& p, cv::Point2f const& c, std::vector<Eigen::Vector2d> const& dirs, double cos_max) {
  Eigen::Vector2d v(p.x - c.x, p.y - c.y);
  double const vn = v.norm();
  if (vn < 1e-9) return -1;
  v /= vn;
  int best = -1;
  double bc = cos_max;
  for (std::size_t j = 0; j < dirs.size(); ++j) {
    if (dirs[j].isZero()) continue;
    double const cs = v.dot(dirs[j]);
    if (cs > bc) {
      bc = cs;
      best = static_cast<int>(j);
    }
  }
  return best;
}

// The 75th percentile of every other point of the closed profile `sm` within +-half: a wide shaft
// crossing the border must not pull the tissue level down. Taken every 4th point, then held (the
// background varies slowly), from a sorted window slid along the border (4 points per step: two
// samples leave and two enter) instead of a selection per point.
std::vector<float> borderBackground(std::vector<float> const& sm, int half) {
  int const n = static_cast<int>(sm.size());
  std::vector<float> background(static_cast<std::size_t>(n));
  auto at = [&](int k) { return sm[static_cast<std::size_t>(((k % n) + n) % n)]; };
  std::vector<float> win;
  for (int j = -half; j <= half; j += 2) win.push_back(at(j));
  std::sort(win.begin(), win.end());
  std::size_t const q = win.size() * 3 / 4;
  for (int i = 0; i < n; i += 4) {
    if (i > 0)
      for (int j : {i - 4 - half, i - 2 - half}) {
        win.erase(std::lower_bound(win.begin(), win.end(), at(j)));
        float const in = at(j + 2 * half + 2);  // the window is {i - half + 2m, m = 0..half}
        win.insert(std::upper_bound(win.begin(), win.end(), in), in);
      }
    for (int k = i; k < std::min(n, i + 4); ++k) background[k] = win[q];
  }
  return background;
}

// The feature along the field of view's border and what each point of it is.
struct BorderProfile {
  std::vector<float> v, sm;  // the feature, and 3-tap smoothed
  std::vector<float> background;  // the local tissue level (borderBackground())
  std::vector<int> facing;        // the trocar image it faces, or -1
  // low: in a run (up to the floor where the relative threshold is lower); strict: under the
  // relative threshold alone.
  std::vector<unsigned char> low, strict;
};

// Per-point thresholds, relaxed near trocar arcs and relative to the local background where the
// border is dark (vignetted tissue near the border is low in absolute terms; the shaft is lower still).
BorderProfile borderProfile(cv::Mat const& feature, FieldOfView const& fov, SeedSearchParams const& p,
                            std::vector<Eigen::Vector3d> const& trocars) {
  int const n = static_cast<int>(fov.border.size());
  auto const un = static_cast<std::size_t>(n);
  double const cos_max = std::cos(p.near_angle_deg * M_PI / 180.0);
  std::vector<Eigen::Vector2d> const dirs = trocarDirections(fov.centre, trocars);
  BorderProfile b{std::vector<float>(un), std::vector<float>(un), {}, std::vector<int>(un, -1),
                  std::vector<unsigned char>(un), std::vector<unsigned char>(un)};
  auto const& v = b.v;
  for (int i = 0; i < n; ++i) b.v[i] = feature.at<std::uint8_t>(fov.border[i]);
  for (int i = 0; i < n; ++i) b.sm[i] = (v[(i + n - 1) % n] + 2.f * v[i] + v[(i + 1) % n]) * 0.25f;
  b.background = borderBackground(b.sm, std::max(8, static_cast<int>(p.background_window * n / 2)));
  for (int i = 0; i < n; ++i) {
    if (!dirs.empty()) b.facing[i] = facingTrocar(fov.border[i], fov.centre, dirs, cos_max);
    float const abs_t = b.facing[i] >= 0 ? p.near_threshold : p.threshold;
    float thr = abs_t, run_thr = abs_t;
    if (p.relative_threshold > 0.0 && b.background[i] < p.dark_border_level) {
      thr = std::min(abs_t, std::max(static_cast<float>(p.relative_threshold) * b.background[i], static_cast<float>(p.min_threshold)));
      run_thr = std::min(abs_t, std::max(thr, static_cast<float>(p.run_floor)));
    }
    b.strict[i] = b.sm[i] <= thr;
    b.low[i] = b.sm[i] <= run_thr;
  }
  return b;
}

// The seed of the low run of `len` points from border point i; placed at the middle of its
// lowest stretch under the relative threshold alone, if one is a seed's width: the shaft beside
// a blob of about its level (gauze), one run whose middle lies on the blob.
Seed runSeed(BorderProfile const& b, FieldOfView const& fov, int i, int len, float sum, int min_width) {
  int const n = static_cast<int>(b.v.size());
  Seed s;
  s.begin = i;
  s.end = (i + len) % n;
  s.width = len;
  int mid = (i + len / 2) % n;
  s.mean_value = sum / len;
  float lowest = std::numeric_limits<float>::infinity();
  for (int a = 0; a < len;) {
    if (!b.strict[(i + a) % n]) {
      ++a;
      continue;
    }
    int e = a;
    float sub = 0.f;
    for (; e < len && b.strict[(i + e) % n]; ++e) sub += b.v[(i + e) % n];
    if (e - a >= min_width && sub / (e - a) < lowest) {
      lowest = sub / (e - a);
      mid = (i + (a + e) / 2) % n;
    }
    a = e;
  }
  s.mean_value = std::min(s.mean_value, lowest);
  s.position = fov.border[mid];
  s.background = b.background[mid];
  s.insertion_point = b.facing[mid];
  return s;
}
}  // namespace

std::vector<Seed> findSeeds(cv::Mat const& feature, FieldOfView const& fov, SeedSearchParams const& p,
                            std::vector<Eigen::Vector3d> const& trocars) {
  std::vector<Seed> seeds;
  int const n = static_cast<int>(fov.border.size());
  if (n < 8) return seeds;
  BorderProfile const b = borderProfile(feature, fov, p, trocars);
  // Runs of low values on the closed path: start scanning just after a high value.
  int start = 0;
  while (start < n && b.low[start]) ++start;
  if (start == n) return seeds;  // the whole border is low: no usable contrast
  int const max_width = static_cast<int>(p.max_width_fraction * n);
  for (int k = 0; k < n;) {
    int const i = (start + k) % n;
    if (!b.low[i]) {
      ++k;
      continue;
    }
    int len = 0;
    float sum = 0.f;
    while (k + len < n && b.low[(start + k + len) % n]) {
      sum += b.v[(start + k + len) % n];
      ++len;
    }
    if (len >= p.min_width && len <= max_width) seeds.push_back(runSeed(b, fov, i, len, sum, p.min_width));
    k += len;
  }
  // Trocar-facing seeds first, then by contrast.
  std::stable_sort(seeds.begin(), seeds.end(), [](Seed const& a, Seed const& b) {
    if ((a.insertion_point >= 0) != (b.insertion_point >= 0)) return a.insertion_point >= 0;
    return a.mean_value < b.mean_value;
  });
  return seeds;
}

}  // namespace endo_guidance::perception
