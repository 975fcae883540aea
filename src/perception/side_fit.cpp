// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/side_fit.h"

#include <opencv2/core.hpp>
#if defined(__GNUC__) && defined(__x86_64__)
#include <immintrin.h>
#define ENDO_GUIDANCE_AVX2 1
#endif

#include <algorithm>
#include <cmath>
#include <iterator>
#include <limits>
#include <random>

#include "endo_guidance/perception/image_reduction.h"
#include "endo_guidance/perception/line_fit.h"

namespace endo_guidance::perception {

namespace {

// A straight side followed from the entry: LMedS on the first part of the chain, then extended
// point by point while the chain stays on the line (gaps of a few points allowed), so that the
// side ends where the shaft ends (tip, jaws, or the junction with a touching instrument).
struct FollowedSide {
  Eigen::Vector3d line = Eigen::Vector3d::Zero();
  std::vector<Eigen::Vector2d> points;
  int traversed = 0;  ///< chain points up to the last kept one
};

std::optional<FollowedSide> followSide(std::vector<Eigen::Vector2d> const& chain, FieldOfView const& fov,
                                       ContourLinesParams const& p, std::uint64_t seed) {
  int const n = static_cast<int>(chain.size());
  if (n < p.min_side_points) return std::nullopt;
  int const m = std::clamp(n / 3, p.min_side_points, 80);
  auto const rl = fitLineLMedS(std::vector<Eigen::Vector2d>(chain.begin(), chain.begin() + m), p.lmeds_samples, seed);
  if (!rl || rl->inliers.size() < p.min_inlier_fraction * m) return std::nullopt;
  Eigen::Vector3d l = rl->line;
  double tol = std::max(2.5 * rl->sigma, 1.0);
  bool cut = false;  // the side was cut at a bend of the head
  // The side starts at the entry. A head that spans a short shaft and its longer jaw (at another
  // angle) holds two edges: the median picks the jaw's, or a line between the two (a wide
  // residual scale), and the side found would not be the shaft's. The head is split at the
  // break that best explains it by two lines (least squares, O(m) by prefix sums); the first
  // line is the side if it is much straighter than the median's (a third of its residual scale)
  // and heads into the view at 30 deg or more to the border (not a side's stretch along the
  // border before it turns inward). That side is followed without refits (they would lean onto
  // the jaw).
  if (!fov.depth.empty() && m >= 2 * p.min_side_points) {
    std::array<Eigen::Matrix<double, 5, 1>, 81> acc;  // m <= 80
    acc[0].setZero();
    for (int i = 0; i < m; ++i) {
      Eigen::Vector2d const& q = chain[i];
      acc[i + 1] = acc[i];
      acc[i + 1] += (Eigen::Matrix<double, 5, 1>() << q.x(), q.y(), q.x() * q.x(), q.x() * q.y(), q.y() * q.y()).finished();
    }
    // Sum of squared orthogonal residuals of the LS line through chain[a..b).
    auto sse = [&](int a, int b) {
      Eigen::Matrix<double, 5, 1> const v = acc[b] - acc[a];
      double const k = b - a, mx = v[0] / k, my = v[1] / k;
      double const cxx = v[2] - k * mx * mx, cxy = v[3] - k * mx * my, cyy = v[4] - k * my * my;
      return std::max(0.0, 0.5 * (cxx + cyy) - std::sqrt(0.25 * (cxx - cyy) * (cxx - cyy) + cxy * cxy));
    };
    int best_b = -1;
    double best = std::numeric_limits<double>::infinity();
    for (int b = p.min_side_points; b + p.min_side_points <= m; ++b)
      if (double const e = sse(0, b) + sse(b, m); e < best) {
        best = e;
        best_b = b;
      }
    if (best_b > 0 && std::sqrt(sse(0, best_b) / best_b) < 0.35 * rl->sigma) {
      std::vector<Eigen::Vector2d> const first(chain.begin(), chain.begin() + best_b);
      auto const l1 = fitLineLS(first);
      if (l1 && depthAt(fov, first.back()) - depthAt(fov, first.front()) >= 0.5 * (first.back() - first.front()).norm()) {
        l = *l1;
        tol = std::max(2.5 * std::sqrt(sse(0, best_b) / best_b), 1.0);
        cut = true;
      }
    }
  }
  FollowedSide f;
  int misses = 0, last = -1;
  for (int i = 0; i < n; ++i) {
    if (std::abs(l.head<2>().dot(chain[i]) + l.z()) <= tol) {
      f.points.push_back(chain[i]);
      misses = 0;
      last = i;
      if (!cut && f.points.size() % 32 == 0)
        if (auto const ls = fitLineLS(f.points)) l = *ls;  // follow the line as it gets longer
    } else if (++misses > p.max_gap_points && !f.points.empty()) {
      break;
    }
  }
  if (static_cast<int>(f.points.size()) < p.min_side_points ||
      f.points.size() < p.min_inlier_fraction * (last + 1))
    return std::nullopt;
  auto const ls = fitLineLS(f.points);
  if (!ls) return std::nullopt;
  f.line = *ls;
  f.traversed = last + 1;
  return f;
}

// The extent [lo, hi] of points along direction d.
std::pair<double, double> extentAlong(Eigen::Vector2d const& d, std::vector<Eigen::Vector2d> const& v) {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (auto const& q : v) {
    lo = std::min(lo, d.dot(q));
    hi = std::max(hi, d.dot(q));
  }
  return {lo, hi};
}

// The straight run of a boundary sequence: the line through a random pair of its points (not
// `used`; with `along`, within the angle whose cosine is cos_max of that direction) with the most
// points within 1 px, and the longest run of points on it along the sequence (gaps of
// max_gap_points allowed). nullopt: fewer than min_side_points on the best line.
struct StraightRun {
  Eigen::Vector3d line = Eigen::Vector3d::Zero();
  int begin = -1, end = -1;  ///< sequence indices of the run's first and last point
  std::vector<Eigen::Vector2d> points;  ///< the run's points on the line
};
// The points of a sequence, coordinates apart (x then y), the ones not free as NaN (never within
// 1 px of a line: every comparison with NaN is false), for countNearLine().
struct PointColumns {
  std::vector<double> x, y;
};
PointColumns pointColumns(std::vector<Eigen::Vector2d> const& seq, std::vector<unsigned char> const* used) {
  PointColumns c;
  c.x.resize(seq.size());
  c.y.resize(seq.size());
  for (std::size_t i = 0; i < seq.size(); ++i) {
    bool const gone = used && (*used)[i];
    c.x[i] = gone ? std::numeric_limits<double>::quiet_NaN() : seq[i].x();
    c.y[i] = gone ? std::numeric_limits<double>::quiet_NaN() : seq[i].y();
  }
  return c;
}

// The points within 1 px of the line n.q + c = 0: |(nx x + ny y) + c| <= 1, in that order of
// operations (as Eigen's 2-vector dot product, then + c; no fused multiply-add), so that the
// count is the same in every path. A NaN point is never counted.
int countNearLineScalar(PointColumns const& pc, double nx, double ny, double c) {
  int count = 0;
  std::size_t const n = pc.x.size();
  for (std::size_t q = 0; q < n; ++q) count += std::abs((nx * pc.x[q] + ny * pc.y[q]) + c) <= 1.0;
  return count;
}
#ifdef ENDO_GUIDANCE_AVX2
// Four points per step (AVX2 without FMA: the same roundings as the scalar loop): straightRun()
// counts over boundaries of thousands of points for each of hundreds of lines.
__attribute__((target("avx2"))) int countNearLineAvx2(PointColumns const& pc, double nx, double ny, double c) {
  std::size_t const n = pc.x.size();
  __m256d const vnx = _mm256_set1_pd(nx), vny = _mm256_set1_pd(ny), vc = _mm256_set1_pd(c), one = _mm256_set1_pd(1.0),
                abs_mask = _mm256_castsi256_pd(_mm256_set1_epi64x(0x7fffffffffffffffLL));
  __m256i acc = _mm256_setzero_si256();
  std::size_t q = 0;
  for (; q + 4 <= n; q += 4) {
    __m256d const v = _mm256_add_pd(_mm256_add_pd(_mm256_mul_pd(vnx, _mm256_loadu_pd(&pc.x[q])), _mm256_mul_pd(vny, _mm256_loadu_pd(&pc.y[q]))), vc);
    __m256d const near = _mm256_cmp_pd(_mm256_and_pd(v, abs_mask), one, _CMP_LE_OQ);  // (nan: false)
    acc = _mm256_sub_epi64(acc, _mm256_castpd_si256(near));                          // all ones: -1
  }
  alignas(32) long long lanes[4];
  _mm256_store_si256(reinterpret_cast<__m256i*>(lanes), acc);
  int count = static_cast<int>(lanes[0] + lanes[1] + lanes[2] + lanes[3]);
  for (; q < n; ++q) count += std::abs((nx * pc.x[q] + ny * pc.y[q]) + c) <= 1.0;
  return count;
}
#endif
int countNearLine(PointColumns const& pc, double nx, double ny, double c) {
#ifdef ENDO_GUIDANCE_AVX2
  if (cv::checkHardwareSupport(CV_CPU_AVX2)) return countNearLineAvx2(pc, nx, ny, c);
#endif
  return countNearLineScalar(pc, nx, ny, c);
}

std::optional<StraightRun> straightRun(std::vector<Eigen::Vector2d> const& seq, std::vector<unsigned char> const* used, int samples,
                                       std::mt19937_64& rng, ContourLinesParams const& p, Eigen::Vector2d const* along = nullptr,
                                       double cos_max = 0.0) {
  int const n = static_cast<int>(seq.size());
  if (n < 2) return std::nullopt;
  auto const free = [&](int i) { return !used || !(*used)[static_cast<std::size_t>(i)]; };
  std::uniform_int_distribution<int> pick(0, n - 1);
  Eigen::Vector3d best = Eigen::Vector3d::Zero();
  int best_count = 0;
  PointColumns const pc = pointColumns(seq, used);
  for (int s = 0; s < samples; ++s) {
    int const i = pick(rng), j = pick(rng);
    if (!free(i) || !free(j)) continue;
    Eigen::Vector2d const d = seq[j] - seq[i];
    double const len = d.norm();
    if (len < 4.0 || (along && std::abs(along->dot(d / len)) < cos_max)) continue;
    Eigen::Vector2d const nrm(-d.y() / len, d.x() / len);
    double const c = -nrm.dot(seq[i]);
    int const count = countNearLine(pc, nrm.x(), nrm.y(), c);
    if (count > best_count) {
      best_count = count;
      best = Eigen::Vector3d(nrm.x(), nrm.y(), c);
    }
  }
  if (best_count < p.min_side_points) return std::nullopt;
  StraightRun run;
  run.line = best;
  int cur_start = -1, last = -1, best_len = 0;
  for (int i = 0; i < n; ++i) {
    if (!free(i) || std::abs(best.head<2>().dot(seq[i]) + best.z()) > 1.0) continue;
    if (cur_start < 0 || i - last > p.max_gap_points + 1) cur_start = i;
    last = i;
    if (i - cur_start + 1 > best_len) {
      best_len = i - cur_start + 1;
      run.begin = cur_start;
      run.end = i;
    }
  }
  for (int i = run.begin; i >= 0 && i <= run.end; ++i)
    if (free(i) && std::abs(best.head<2>().dot(seq[i]) + best.z()) <= 1.0) run.points.push_back(seq[i]);
  return run;
}

// The side of a region whose boundary, from the entry, is not a straight line (a grey blob
// merged with the shaft near the entry: gauze): the straight stretch of `head` (the boundary
// from the entry to the point farthest from the seed), beside the other side (within its extent
// along it), that is near-parallel to the other side's line `other` (the contours of a cylinder
// meet at most max_angle_deg apart) and has the most points within 1 px; its longest run along
// the boundary (gaps of max_gap_points allowed).
std::optional<FollowedSide> parallelSide(std::vector<Eigen::Vector2d> const& head, FollowedSide const& other_side,
                                         ContourLinesParams const& p, std::uint64_t seed) {
  Eigen::Vector3d const& other = other_side.line;
  double const cos_max = std::cos(p.max_angle_deg * M_PI / 180.0);
  Eigen::Vector2d const od(-other.y(), other.x());
  auto const [a0, a1] = extentAlong(od, other_side.points);
  // Only the stretch beside the other side: where the region also holds a touching instrument
  // beyond the tip, that instrument's edges (near-parallel too, and longer) are not this side.
  std::vector<Eigen::Vector2d> chain;
  for (auto const& q : head)
    if (double const t = od.dot(q); t >= a0 && t <= a1) chain.push_back(q);
  if (static_cast<int>(chain.size()) < p.min_side_points) return std::nullopt;
  std::mt19937_64 rng(seed);
  auto run = straightRun(chain, nullptr, 4 * p.lmeds_samples, rng, p, &od, cos_max);
  if (!run) return std::nullopt;
  FollowedSide f;
  f.points = std::move(run->points);
  if (static_cast<int>(f.points.size()) < p.min_side_points) return std::nullopt;
  // A side of the same shaft: at least half as long as the other, and beside it for most of its
  // length (not a short straight stretch of the blob's outline).
  auto const [b0, b1] = extentAlong(od, f.points);
  double const overlap = std::min(a1, b1) - std::max(a0, b0);
  if (b1 - b0 < p.min_parallel_side_ratio * (a1 - a0) || overlap < p.min_parallel_side_ratio * (b1 - b0)) return std::nullopt;
  auto const ls = fitLineLS(f.points);
  if (!ls) return std::nullopt;
  f.line = *ls;
  f.traversed = run->end + 1;
  return f;
}

// The straight stretches of a boundary sequence, longest first (straightRun(), each run taken out
// of the sequence), up to `count` of min_side_points or more.
std::vector<FollowedSide> straightStretches(std::vector<Eigen::Vector2d> const& seq, int count, ContourLinesParams const& p,
                                            std::uint64_t seed) {
  std::vector<FollowedSide> out;
  if (static_cast<int>(seq.size()) < p.min_side_points) return out;
  std::vector<unsigned char> used(seq.size(), 0);
  std::mt19937_64 rng(seed);
  for (int k = 0; k < count; ++k) {
    auto run = straightRun(seq, &used, 8 * p.lmeds_samples, rng, p);
    if (!run) break;
    for (int i = run->begin; i >= 0 && i <= run->end; ++i) used[static_cast<std::size_t>(i)] = 1;
    if (static_cast<int>(run->points.size()) < p.min_side_points) continue;
    auto const ls = fitLineLS(run->points);
    if (!ls) continue;
    FollowedSide f;
    f.points = std::move(run->points);
    f.line = *ls;
    out.push_back(std::move(f));
  }
  return out;
}

// The two sides of a shaft whose boundary is straight from the entry on neither side (a blob
// merged on both sides near the entry, or one that also reaches the border): among the straight
// stretches of the whole boundary (straightStretches()), the pair that is near-parallel, lies
// beside each other over min_parallel_side_ratio of the shorter, at least 2 px apart, with the
// seed between them (the strip they bound reaches the entry); the most points.
std::optional<std::array<FollowedSide, 2>> stretchPair(std::vector<std::vector<Eigen::Vector2d>> const& pieces,
                                                       Eigen::Vector2d const& seed_pt, ContourLinesParams const& p, std::uint64_t seed) {
  std::vector<FollowedSide> st;
  for (std::size_t k = 0; k < pieces.size(); ++k) {
    auto s = straightStretches(pieces[k], 4, p, seed + k);
    std::move(s.begin(), s.end(), std::back_inserter(st));
  }
  double const cos_max = std::cos(p.max_angle_deg * M_PI / 180.0);
  std::optional<std::array<FollowedSide, 2>> best;
  std::size_t best_n = 0;
  for (std::size_t a = 0; a < st.size(); ++a)
    for (std::size_t b = a + 1; b < st.size(); ++b) {
      Eigen::Vector3d la = st[a].line, lb = st[b].line;
      if (std::abs(la.head<2>().dot(lb.head<2>())) < cos_max) continue;
      if (la.head<2>().dot(lb.head<2>()) < 0.0) lb = -lb;
      Eigen::Vector2d const d(-la.y(), la.x());
      auto const [a0, a1] = extentAlong(d, st[a].points);
      auto const [b0, b1] = extentAlong(d, st[b].points);
      double const overlap = std::min(a1, b1) - std::max(a0, b0);
      if (overlap < p.min_parallel_side_ratio * std::min(a1 - a0, b1 - b0)) continue;
      // Apart, on opposite sides of the strip, the seed between them (within 2 px).
      Eigen::Vector2d mb = Eigen::Vector2d::Zero(), ma = Eigen::Vector2d::Zero();
      for (auto const& q : st[b].points) mb += q / static_cast<double>(st[b].points.size());
      for (auto const& q : st[a].points) ma += q / static_cast<double>(st[a].points.size());
      double const sep = la.head<2>().dot(mb) + la.z();
      if (std::abs(sep) < 2.0) continue;
      double const sa = (la.head<2>().dot(seed_pt) + la.z()) * (sep > 0 ? 1.0 : -1.0);
      double const sb = (lb.head<2>().dot(seed_pt) + lb.z()) * ((lb.head<2>().dot(ma) + lb.z()) > 0 ? 1.0 : -1.0);
      if (sa < -2.0 || sb < -2.0) continue;
      std::size_t const n = st[a].points.size() + st[b].points.size();
      if (n > best_n) {
        best_n = n;
        best = std::array<FollowedSide, 2>{st[a], st[b]};
      }
    }
  return best;
}

}  // namespace

void setFarEnd(SideFit& fit) {
  double fd = -1.0;
  for (int s = 0; s < 2; ++s)
    for (auto const& q : fit.points[s])
      if ((q - fit.entry).norm() > fd) {
        fd = (q - fit.entry).norm();
        fit.far = q;
      }
}

// What every side search of a region shares (fitSides()): which boundary points lie on the
// view's border, whether the region meets it more than once, the two chains that leave the
// entry and each side followed from the entry.
struct SideChains {
  std::vector<unsigned char> border;
  bool merged = false;
  std::vector<Eigen::Vector2d> chain[2];
  std::optional<FollowedSide> fwd[2];
};

namespace {

SideChains sideChains(Region const& region, FieldOfView const& fov, ContourLinesParams const& p) {
  SideChains sc;
  auto const& B = region.boundary;
  int const n = static_cast<int>(B.size());
  auto& border = sc.border;
  auto& chain = sc.chain;
  // Boundary points on (near) the FOV edge belong to the entry, not to a contour line.
  border.resize(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) border[i] = nearViewEdge(fov, B[i], p.border_margin);
  // A region that meets the border in several places has merged with another instrument.
  int runs = 0;
  for (int i = 0; i < n; ++i) runs += border[i] && !border[(i + n - 1) % n];
  sc.merged = runs >= 2;
  // The two classes ([Doignon07] Sec. 3) are the two boundary chains that leave the entry (the
  // seed's border run), one along each side; for a lone shaft they meet at the boundary point
  // farthest from the seed, the paper's split point. Following each side from the entry (rather
  // than fitting the whole class) keeps the split right when the region also holds the jaws or
  // a touching instrument beyond the tip.
  int s0 = 0;
  double sd = 1e300;
  for (int i = 0; i < n; ++i) {
    double const d = cv::norm(B[i] - region.seed) - (border[i] ? 0.5 : 0.0);
    if (d < sd) {
      sd = d;
      s0 = i;
    }
  }
  for (int dirn = 0; dirn < 2; ++dirn) {
    int const step = dirn == 0 ? 1 : -1;
    int k = 0;
    while (k < n && border[((s0 + step * k) % n + n) % n]) ++k;  // leave the entry run
    for (; k < n; ++k) {
      int const i = ((s0 + step * k) % n + n) % n;
      if (border[i]) break;
      chain[dirn].emplace_back(B[i].x, B[i].y);
    }
  }
  for (int s = 0; s < 2; ++s) sc.fwd[s] = followSide(chain[s], fov, p, p.seed + s);
  return sc;
}

// The pair's lines (full resolution) into `fit` if they are parallel enough; else why not.
ContourRejection pairUp(SideFit& fit, FollowedSide const& a, FollowedSide const& b, int scale, ContourLinesParams const& p) {
  double const cos_max = std::cos(p.max_angle_deg * M_PI / 180.0);
  std::array<std::vector<Eigen::Vector2d>, 2> pts;
  std::array<Eigen::Vector3d, 2> lines;
  FollowedSide const* sides[2] = {&a, &b};
  for (int s = 0; s < 2; ++s) {
    for (auto const& q : sides[s]->points) pts[s].push_back(toFullRes(q, scale));
    auto const l = fitLineLS(pts[s]);
    if (!l) return ContourRejection::kNotStraight;
    lines[s] = *l;
  }
  if (std::abs(lines[0].head<2>().dot(lines[1].head<2>())) < cos_max) return ContourRejection::kNotParallel;
  for (int s = 0; s < 2; ++s) {
    fit.points[s] = std::move(pts[s]);
    fit.lines[s] = lines[s];
    fit.inliers += static_cast<int>(sides[s]->points.size());
  }
  return ContourRejection::kNone;
}

// The whole boundary in its pieces between its stretches on the FOV border: where the region
// meets the border more than once, the shaft's far side can lie on a piece that leaves the view
// at neither end of the entry run (between a blob's and another instrument's border runs).
std::vector<std::vector<Eigen::Vector2d>> boundaryPieces(Region const& region, std::vector<unsigned char> const& border) {
  auto const& B = region.boundary;
  int const n = static_cast<int>(B.size());
  std::vector<std::vector<Eigen::Vector2d>> pieces;
  int start = 0;
  while (start < n && !border[start]) ++start;  // a border point to start from (one exists: the entry)
  for (int k = 1; k <= n; ++k) {
    int const i = (start + k) % n;
    if (border[i]) {
      if (!pieces.empty() && !pieces.back().empty()) pieces.emplace_back();
      continue;
    }
    if (pieces.empty()) pieces.emplace_back();
    pieces.back().emplace_back(B[i].x, B[i].y);
  }
  if (start == n) {  // (no point on the border: one closed piece)
    pieces.assign(1, {});
    for (auto const& q : B) pieces[0].emplace_back(q.x, q.y);
  }
  return pieces;
}

// One side sought as the straight stretch of its chain, up to the point farthest from the seed,
// parallel beside the other side followed from the entry (parallelSide()); `only` >= 0: that side
// only. True when a pair was found (into `fit`).
bool pairWithParallelSide(SideFit& fit, SideChains const& sc, Region const& region, int only, bool resought, int scale,
                          ContourLinesParams const& p) {
  auto const& chain = sc.chain;
  auto const& fwd = sc.fwd;
  Eigen::Vector2d const sp(region.seed.x, region.seed.y);
  for (int s = 0; s < 2; ++s) {
    if (!fwd[1 - s] || (only >= 0 && s != only)) continue;
    auto const far = std::max_element(chain[s].begin(), chain[s].end(), [&](Eigen::Vector2d const& a, Eigen::Vector2d const& b) {
      return (a - sp).squaredNorm() < (b - sp).squaredNorm();
    });
    if (far == chain[s].end()) continue;
    std::vector<Eigen::Vector2d> head(chain[s].begin(), far + 1);
    FollowedSide other = *fwd[1 - s];
    if (resought && fit.merged) {
      // A region that meets the border again (the blob reaches it): this side's chain ends there,
      // and the shaft's side beyond the blob is on the other chain, after the other side's end
      // (around the tip and back): walked from the border, off the other side's line. The other
      // side's points beyond the gap where following it stopped are added to it.
      Eigen::Vector3d const o = other.line;
      for (int i = static_cast<int>(chain[1 - s].size()) - 1; i >= fwd[1 - s]->traversed; --i) {
        double const d = std::abs(o.head<2>().dot(chain[1 - s][i]) + o.z());
        if (d > 1.5) head.push_back(chain[1 - s][i]);
        else if (d <= 1.0) other.points.push_back(chain[1 - s][i]);
      }
      if (auto const l = fitLineLS(other.points)) other.line = *l;
    }
    auto const side = parallelSide(head, other, p, p.seed + 2 + s);
    if (side && pairUp(fit, s == 0 ? *side : other, s == 0 ? other : *side, scale, p) == ContourRejection::kNone) return true;
  }
  return false;
}

// One search of fitSides() over the shared part. Each side followed from the entry ([Doignon07]'s
// two classes); a region merged with a grey blob near the entry (gauze) has one side that is not
// straight from there, sought then as the stretch parallel to the other (the pair is `parallel`).
SideFit fitSidesFrom(SideChains const& sc, Region const& region, int scale, ContourLinesParams const& p, SideSearch search) {
  SideFit fit;
  fit.merged = sc.merged;
  ContourRejection why = ContourRejection::kNone;
  for (int s = 0; s < 2 && why == ContourRejection::kNone; ++s)
    if (!sc.fwd[s])
      why = static_cast<int>(sc.chain[s].size()) < p.min_side_points ? ContourRejection::kTooFewPoints : ContourRejection::kNotStraight;
  // Re-sought: the pair from the entry (if any) had no edges; the sides are sought again below.
  bool const resought = search != SideSearch::kFromEntry;
  if (resought) why = ContourRejection::kNotStraight;
  if (why == ContourRejection::kNone) why = pairUp(fit, *sc.fwd[0], *sc.fwd[1], scale, p);
  if (search == SideSearch::kStretchPair) {
    auto const pair = stretchPair(boundaryPieces(region, sc.border), Eigen::Vector2d(region.seed.x, region.seed.y), p, p.seed + 5);
    if (pair && pairUp(fit, (*pair)[0], (*pair)[1], scale, p) == ContourRejection::kNone) {
      fit.parallel = true;
      why = ContourRejection::kNone;
    }
  }
  int const only = search == SideSearch::kParallelFirst ? 0 : search == SideSearch::kParallelSecond ? 1 : -1;
  if (why != ContourRejection::kNone && p.min_parallel_side_ratio > 0.0 && search != SideSearch::kStretchPair &&
      pairWithParallelSide(fit, sc, region, only, resought, scale, p)) {
    fit.parallel = true;
    why = ContourRejection::kNone;
  }
  if (why != ContourRejection::kNone) {
    fit.rejection = why;
    return fit;
  }
  fit.entry = toFullRes(Eigen::Vector2d(region.seed.x, region.seed.y), scale);
  setFarEnd(fit);
  // Orient each line with the shaft on its positive side: the mean of both sides' points.
  Eigen::Vector2d inside = Eigen::Vector2d::Zero();
  for (int s = 0; s < 2; ++s) {
    Eigen::Vector2d m = Eigen::Vector2d::Zero();
    for (auto const& q : fit.points[s]) m += q;
    inside += 0.5 * m / static_cast<double>(fit.points[s].size());
  }
  for (int s = 0; s < 2; ++s)
    if (fit.lines[s].head<2>().dot(inside) + fit.lines[s].z() < 0.0) fit.lines[s] = -fit.lines[s];
  return fit;
}

// A boundary too short for two sides: refused before anything is computed.
std::optional<SideFit> tooShortForSides(Region const& region, ContourLinesParams const& p) {
  if (static_cast<int>(region.boundary.size()) >= 2 * p.min_side_points) return std::nullopt;
  SideFit f;
  f.rejection = ContourRejection::kTooFewPoints;
  return f;
}

}  // namespace

SideFit fitSides(Region const& region, FieldOfView const& fov, int scale, ContourLinesParams const& p, SideSearch search) {
  if (auto f = tooShortForSides(region, p)) return *f;
  auto sc = std::make_shared<SideChains const>(sideChains(region, fov, p));
  SideFit fit = fitSidesFrom(*sc, region, scale, p, search);
  fit.chains = std::move(sc);
  return fit;
}

std::vector<SideFit> fitSidesEach(Region const& region, FieldOfView const& fov, int scale, ContourLinesParams const& p,
                                  std::vector<SideSearch> const& searches, SideFit const* fitted) {
  if (auto f = tooShortForSides(region, p)) return std::vector<SideFit>(searches.size(), *f);
  std::shared_ptr<SideChains const> sc = fitted ? fitted->chains : nullptr;
  if (!sc) sc = std::make_shared<SideChains const>(sideChains(region, fov, p));
  std::vector<SideFit> out;
  for (SideSearch const s : searches) {
    out.push_back(fitSidesFrom(*sc, region, scale, p, s));
    out.back().chains = sc;
  }
  return out;
}

}  // namespace endo_guidance::perception
