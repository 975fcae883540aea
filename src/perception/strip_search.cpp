// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/strip_search.h"

#include "endo_guidance/perception/image_reduction.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <opencv2/core/hal/intrin.hpp>
#include <opencv2/imgproc.hpp>
#if defined(__GNUC__) && defined(__x86_64__)
#include <immintrin.h>
#endif


namespace endo_guidance::perception {

namespace {
void checkGradient(cv::Mat const& gx, cv::Mat const& gy, FieldOfView const& fov) {
  CV_Assert(gx.type() == CV_16S && gy.type() == CV_16S && gx.size() == gy.size() && fov.mask.type() == CV_8U &&
            fov.mask.size() == gx.size());
}
}  // namespace

void walkRay(StripRay& r, cv::Mat const& gx, cv::Mat const& gy, FieldOfView const& fov, StripSearchParams const& p) {
  checkGradient(gx, gy, fov);
  float const ox = static_cast<float>(r.out.x() / p.full_response), oy = static_cast<float>(r.out.y() / p.full_response);
  float const dx = static_cast<float>(r.dir.x()), dy = static_cast<float>(r.dir.y()), tau = static_cast<float>(p.min_response);
  float x = static_cast<float>(r.start.x()) + 0.5f, y = static_cast<float>(r.start.y()) + 0.5f;  // +0.5: truncation rounds
  float const W = static_cast<float>(gx.cols), H = static_cast<float>(gx.rows);
  float acc = 0.f, best = 0.f;
  int best_t = 0;
  int const tmax = gx.cols + gx.rows;
  for (int t = 1; t < tmax; ++t) {
    x += dx;
    y += dy;
    if (!(x >= 0.f && y >= 0.f && x < W && y < H)) break;
    int const xi = static_cast<int>(x), yi = static_cast<int>(y);
    if (t > 4 && fov.mask.ptr<std::uint8_t>(yi)[xi] == 0) break;
    float const g = gx.ptr<std::int16_t>(yi)[xi] * ox + gy.ptr<std::int16_t>(yi)[xi] * oy;
    acc += std::clamp(g, -1.f, 1.f) - tau;
    if (acc > best) {
      best = acc;
      best_t = t;
    } else if (acc < best - 8.f) {
      break;  // the edge has clearly ended
    }
  }
  r.score = best;
  r.length = best_t;
}

RayField packRayField(cv::Mat const& gx, cv::Mat const& gy, FieldOfView const& fov) {
  checkGradient(gx, gy, fov);
  RayField f;
  f.packed.create(gx.size(), CV_32S);
  int lo = 0, hi = 0;  // gy's range, checked after the one pass
  for (int y = 0; y < gx.rows; ++y) {
    std::int16_t const* a = gx.ptr<std::int16_t>(y);
    std::int16_t const* b = gy.ptr<std::int16_t>(y);
    std::uint8_t const* m = fov.mask.ptr<std::uint8_t>(y);
    std::uint32_t* o = f.packed.ptr<std::uint32_t>(y);
    for (int x = 0; x < gx.cols; ++x) {
      lo = std::min(lo, static_cast<int>(b[x]));
      hi = std::max(hi, static_cast<int>(b[x]));
      o[x] = (static_cast<std::uint32_t>(2 * b[x] + (m[x] != 0)) << 16) | static_cast<std::uint16_t>(a[x]);
    }
  }
  CV_Assert(lo > -16384 && hi < 16384);  // 2 gy + 1 in 16 bits
  return f;
}

namespace {

void checkField(RayField const& f) { CV_Assert(f.packed.type() == CV_32S && f.packed.isContinuous() && !f.packed.empty()); }

// Lanes of rays walked in lock step, a lane whose ray has ended taking the next one: the state
// of each lane, and how a lane starts its ray (or idles: a harmless ray inside the image, never
// reported). L lanes.
template <int L>
struct Lanes {
  alignas(32) float x[L], y[L], dx[L], dy[L], ox[L], oy[L], acc[L], best[L];
  alignas(32) int t[L], best_t[L], live[L];
  int ray[L];  // the lane's ray, -1: none left
  int next = 0;
  void start(int l, std::vector<StripRay> const& rays, StripSearchParams const& p) {
    if (next >= static_cast<int>(rays.size())) {
      ray[l] = -1;
      live[l] = 0;
      x[l] = y[l] = 0.5f;
      dx[l] = dy[l] = ox[l] = oy[l] = 0.f;
      t[l] = 0;
      acc[l] = best[l] = 0.f;
      best_t[l] = 0;
      return;
    }
    StripRay const& r = rays[static_cast<std::size_t>(next)];
    ray[l] = next++;
    live[l] = -1;
    ox[l] = static_cast<float>(r.out.x() / p.full_response);
    oy[l] = static_cast<float>(r.out.y() / p.full_response);
    dx[l] = static_cast<float>(r.dir.x());
    dy[l] = static_cast<float>(r.dir.y());
    x[l] = static_cast<float>(r.start.x()) + 0.5f;
    y[l] = static_cast<float>(r.start.y()) + 0.5f;
    t[l] = 0;
    acc[l] = best[l] = 0.f;
    best_t[l] = 0;
  }
  bool any() const {
    for (int l = 0; l < L; ++l)
      if (ray[l] >= 0) return true;
    return false;
  }
  // The rays of the lanes in mask `ended` are done: their results, and the lanes' next rays.
  void finish(int ended, std::vector<StripRay>& rays, StripSearchParams const& p) {
    for (int l = 0; l < L; ++l)
      if (ended >> l & 1) {
        StripRay& r = rays[static_cast<std::size_t>(ray[l])];
        r.score = best[l];
        r.length = best_t[l];
        start(l, rays, p);
      }
  }
};

// Four lanes (OpenCV's 128-bit universal intrinsics). Each ray gets exactly walkRay()'s result
// (the same float operations in the same order); the four independent sums run side by side
// instead of one after another (about 1.8x faster in a profile of the benchmark scene).
void walkRays4(std::vector<StripRay>& rays, RayField const& field, StripSearchParams const& p) {
  constexpr int L = 4;
  cv::Mat const& P = field.packed;
  int const tmax = P.cols + P.rows;
  std::int32_t const* const data = P.ptr<std::int32_t>();
  Lanes<L> s;
  for (int l = 0; l < L; ++l) s.start(l, rays, p);
  alignas(16) int xi[L], yi[L], inb[L];
  cv::v_float32x4 const zero = cv::v_setzero_f32(), W = cv::v_setall_f32(static_cast<float>(P.cols)),
                        H = cv::v_setall_f32(static_cast<float>(P.rows)), tau = cv::v_setall_f32(static_cast<float>(p.min_response)),
                        lo = cv::v_setall_f32(-1.f), hi = cv::v_setall_f32(1.f), eight = cv::v_setall_f32(8.f);
  cv::v_int32x4 const one = cv::v_setall_s32(1), four = cv::v_setall_s32(4), last = cv::v_setall_s32(tmax - 1);
  while (s.any()) {
    cv::v_float32x4 vx = cv::v_load_aligned(s.x), vy = cv::v_load_aligned(s.y), vacc = cv::v_load_aligned(s.acc),
                    vbest = cv::v_load_aligned(s.best);
    cv::v_int32x4 vt = cv::v_load_aligned(s.t), vbt = cv::v_load_aligned(s.best_t);
    cv::v_float32x4 const vlive = cv::v_reinterpret_as_f32(cv::v_load_aligned(s.live));
    cv::v_float32x4 const vdx = cv::v_load_aligned(s.dx), vdy = cv::v_load_aligned(s.dy), vox = cv::v_load_aligned(s.ox),
                          voy = cv::v_load_aligned(s.oy);
    for (;;) {
      vt = vt + one;
      vx = vx + vdx;
      vy = vy + vdy;
      cv::v_float32x4 const in = (vx >= zero) & (vy >= zero) & (vx < W) & (vy < H);
      cv::v_store_aligned(xi, cv::v_trunc(vx));
      cv::v_store_aligned(yi, cv::v_trunc(vy));
      cv::v_store_aligned(inb, cv::v_reinterpret_as_s32(in));
      int v[L];
      for (int l = 0; l < L; ++l) v[l] = data[inb[l] ? yi[l] * P.cols + xi[l] : 0];
      // (a vector built from registers: four scalar stores read back as one vector would stall)
      cv::v_int32x4 const vv(v[0], v[1], v[2], v[3]);
      cv::v_int32x4 const va = cv::v_shr<16>(cv::v_shl<16>(vv)), vh = cv::v_shr<16>(vv), vb = cv::v_shr<1>(vh);
      // The ray goes on here: inside the image and (after its first 4 px) the view.
      cv::v_float32x4 const ok = in & cv::v_reinterpret_as_f32((vt <= four) | ((vh & one) != cv::v_setzero_s32()));
      cv::v_float32x4 const g = cv::v_cvt_f32(va) * vox + cv::v_cvt_f32(vb) * voy;
      cv::v_float32x4 const nacc = vacc + (cv::v_min(cv::v_max(g, lo), hi) - tau);
      cv::v_float32x4 const up = ok & (nacc > vbest);
      vbt = cv::v_select(cv::v_reinterpret_as_s32(up), vt, vbt);
      cv::v_float32x4 const nbest = cv::v_max(vbest, nacc);
      vacc = cv::v_select(ok, nacc, vacc);
      vbest = cv::v_select(ok, nbest, vbest);
      // Ended: left the image or the view, the edge clearly ended, or at walkRay()'s last step.
      cv::v_float32x4 const ended = vlive & (~ok | (nacc < nbest - eight) | cv::v_reinterpret_as_f32(vt >= last));
      if (cv::v_check_any(ended)) {
        cv::v_store_aligned(s.x, vx);
        cv::v_store_aligned(s.y, vy);
        cv::v_store_aligned(s.acc, vacc);
        cv::v_store_aligned(s.best, vbest);
        cv::v_store_aligned(s.t, vt);
        cv::v_store_aligned(s.best_t, vbt);
        s.finish(cv::v_signmask(ended), rays, p);
        break;
      }
    }
  }
}

#if defined(__GNUC__) && defined(__x86_64__)
#define ENDO_GUIDANCE_AVX2_RAYS 1
// Eight lanes (AVX2, no FMA: the same roundings as walkRay()), the packed field gathered in one
// instruction. perf on the EndoVis robotic videos: the ray walks were a third of a frame's time
// with four lanes and three loads per lane and step.
__attribute__((target("avx2"))) void walkRays8(std::vector<StripRay>& rays, RayField const& field, StripSearchParams const& p) {
  constexpr int L = 8;
  cv::Mat const& P = field.packed;
  int const tmax = P.cols + P.rows;
  int const* const data = P.ptr<int>();
  Lanes<L> s;
  for (int l = 0; l < L; ++l) s.start(l, rays, p);
  __m256 const zero = _mm256_setzero_ps(), W = _mm256_set1_ps(static_cast<float>(P.cols)), H = _mm256_set1_ps(static_cast<float>(P.rows)),
               tau = _mm256_set1_ps(static_cast<float>(p.min_response)), lo = _mm256_set1_ps(-1.f), hi = _mm256_set1_ps(1.f),
               eight = _mm256_set1_ps(8.f);
  __m256i const one = _mm256_set1_epi32(1), four = _mm256_set1_epi32(4), last = _mm256_set1_epi32(tmax - 1),
                cols = _mm256_set1_epi32(P.cols);
  while (s.any()) {
    __m256 vx = _mm256_load_ps(s.x), vy = _mm256_load_ps(s.y), vacc = _mm256_load_ps(s.acc), vbest = _mm256_load_ps(s.best);
    __m256i vt = _mm256_load_si256(reinterpret_cast<__m256i const*>(s.t)), vbt = _mm256_load_si256(reinterpret_cast<__m256i const*>(s.best_t));
    __m256 const vlive = _mm256_castsi256_ps(_mm256_load_si256(reinterpret_cast<__m256i const*>(s.live)));
    __m256 const vdx = _mm256_load_ps(s.dx), vdy = _mm256_load_ps(s.dy), vox = _mm256_load_ps(s.ox), voy = _mm256_load_ps(s.oy);
    for (;;) {
      vt = _mm256_add_epi32(vt, one);
      vx = _mm256_add_ps(vx, vdx);
      vy = _mm256_add_ps(vy, vdy);
      __m256 const in = _mm256_and_ps(_mm256_and_ps(_mm256_cmp_ps(vx, zero, _CMP_GE_OQ), _mm256_cmp_ps(vy, zero, _CMP_GE_OQ)),
                                      _mm256_and_ps(_mm256_cmp_ps(vx, W, _CMP_LT_OQ), _mm256_cmp_ps(vy, H, _CMP_LT_OQ)));
      __m256i const idx = _mm256_and_si256(_mm256_add_epi32(_mm256_mullo_epi32(_mm256_cvttps_epi32(vy), cols), _mm256_cvttps_epi32(vx)),
                                           _mm256_castps_si256(in));  // outside the image: pixel 0 (not used)
      __m256i const vv = _mm256_i32gather_epi32(data, idx, 4);
      __m256i const va = _mm256_srai_epi32(_mm256_slli_epi32(vv, 16), 16), vh = _mm256_srai_epi32(vv, 16),
                    vb = _mm256_srai_epi32(vh, 1);
      __m256i const go = _mm256_or_si256(_mm256_cmpgt_epi32(_mm256_add_epi32(four, one), vt),  // t <= 4
                                         _mm256_cmpeq_epi32(_mm256_and_si256(vh, one), one));   // inside the view
      __m256 const ok = _mm256_and_ps(in, _mm256_castsi256_ps(go));
      __m256 const g = _mm256_add_ps(_mm256_mul_ps(_mm256_cvtepi32_ps(va), vox), _mm256_mul_ps(_mm256_cvtepi32_ps(vb), voy));
      __m256 const nacc = _mm256_add_ps(vacc, _mm256_sub_ps(_mm256_min_ps(_mm256_max_ps(g, lo), hi), tau));
      __m256 const up = _mm256_and_ps(ok, _mm256_cmp_ps(nacc, vbest, _CMP_GT_OQ));
      vbt = _mm256_blendv_epi8(vbt, vt, _mm256_castps_si256(up));
      __m256 const nbest = _mm256_max_ps(vbest, nacc);
      vacc = _mm256_blendv_ps(vacc, nacc, ok);
      vbest = _mm256_blendv_ps(vbest, nbest, ok);
      __m256 const stop = _mm256_or_ps(_mm256_or_ps(_mm256_xor_ps(ok, _mm256_castsi256_ps(_mm256_set1_epi32(-1))),
                                                    _mm256_cmp_ps(nacc, _mm256_sub_ps(nbest, eight), _CMP_LT_OQ)),
                                       _mm256_castsi256_ps(_mm256_cmpgt_epi32(vt, _mm256_sub_epi32(last, one))));  // t >= last
      int const ended = _mm256_movemask_ps(_mm256_and_ps(vlive, stop));
      if (ended) {
        _mm256_store_ps(s.x, vx);
        _mm256_store_ps(s.y, vy);
        _mm256_store_ps(s.acc, vacc);
        _mm256_store_ps(s.best, vbest);
        _mm256_store_si256(reinterpret_cast<__m256i*>(s.t), vt);
        _mm256_store_si256(reinterpret_cast<__m256i*>(s.best_t), vbt);
        s.finish(ended, rays, p);
        break;
      }
    }
  }
}
#endif

}  // namespace

void walkRays(std::vector<StripRay>& rays, RayField const& field, StripSearchParams const& p) {
  checkField(field);
#ifdef ENDO_GUIDANCE_AVX2_RAYS
  if (cv::checkHardwareSupport(CV_CPU_AVX2)) return walkRays8(rays, field, p);
#endif
  walkRays4(rays, field, p);
}

void walkRays(std::vector<StripRay>& rays, cv::Mat const& gx, cv::Mat const& gy, FieldOfView const& fov, StripSearchParams const& p) {
  walkRays(rays, packRayField(gx, gy, fov), p);
}

namespace {

// Median (upper) of a non-empty sample; reorders it.
template <typename T>
double median(std::vector<T>& v) {
  std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
  return static_cast<double>(v[v.size() / 2]);
}

Eigen::Vector2d rotate(Eigen::Vector2d const& v, double a) {
  double const c = std::cos(a), s = std::sin(a);
  return {c * v.x() - s * v.y(), s * v.x() + c * v.y()};
}

// The best rays of one side: starts at border points first+k_from..first+k_to (every k_step), a
// coarse angular sweep over [a_lo, a_hi] about the inward normal, then the best few distinct
// hypotheses (another start or another angle) refined to step / 3 and step / 12. `walked`: the
// coarse sweeps already walked from each start (same side, same angles), reused and added to.
using SweepCache = std::map<int, std::vector<StripRay>>;
std::vector<StripRay> searchSide(std::vector<cv::Point> const& border, int first, int k_from, int k_to, int k_step,
                            double a_lo, double a_hi, int candidates, Eigen::Vector2d const& inward, Eigen::Vector2d const& away,
                            RayField const& field, StripSearchParams const& p, SweepCache* walked = nullptr) {
  int const n = static_cast<int>(border.size());
  double const step = p.coarse_step_deg * M_PI / 180.0;
  auto make = [&](cv::Point const& s, double a, int pos) {  // (walked by walkRays())
    StripRay r;
    r.start = Eigen::Vector2d(s.x, s.y);
    r.dir = rotate(inward, a);
    r.out = Eigen::Vector2d(-r.dir.y(), r.dir.x());
    if (r.out.dot(away) < 0.0) r.out = -r.out;
    r.angle = a;
    r.pos = pos;
    return r;
  };
  // The coarse sweep from each start, walked once per search (`walked`: across its passes).
  SweepCache local;
  SweepCache& sweeps = walked ? *walked : local;
  std::vector<StripRay> coarse;
  for (int k = k_from; k <= k_to; k += k_step) {
    auto const [it, fresh] = sweeps.try_emplace(k);
    if (fresh) {
      cv::Point const s = border[((first + k) % n + n) % n];
      for (double a = a_lo; a <= a_hi + 1e-9; a += step) it->second.push_back(make(s, a, k));
      walkRays(it->second, field, p);
    }
    coarse.insert(coarse.end(), it->second.begin(), it->second.end());
  }
  // By score, best first (keys sorted, not the rays: the same permutation, a fifth of the moves).
  std::vector<std::pair<double, std::uint32_t>> order(coarse.size());
  for (std::size_t i = 0; i < coarse.size(); ++i) order[i] = {coarse[i].score, static_cast<std::uint32_t>(i)};
  std::sort(order.begin(), order.end(), [](auto const& a, auto const& b) { return a.first > b.first; });
  // The best few distinct hypotheses (another start or another angle).
  std::vector<StripRay> picked;
  for (auto const& [score, i] : order) {
    StripRay const& r = coarse[i];
    if (static_cast<int>(picked.size()) >= candidates || r.score <= 0.0) break;
    bool distinct = true;
    for (auto const& q : picked)
      distinct = distinct && (std::abs(q.angle - r.angle) > 1.5 * step || std::abs(q.pos - r.pos) > 2 * k_step);
    if (distinct) picked.push_back(r);
  }
  // Each refinement stage: the rays of every hypothesis walked together, then the first best in
  // order kept (a hypothesis's rays are rays[first_ray[i], first_ray[i + 1])).
  std::vector<StripRay> rays;
  std::vector<std::size_t> first_ray;
  auto keepBest = [&]() {
    first_ray.push_back(rays.size());
    walkRays(rays, field, p);
    for (std::size_t i = 0; i < picked.size(); ++i)
      for (std::size_t j = first_ray[i]; j < first_ray[i + 1]; ++j)
        if (rays[j].score > picked[i].score) picked[i] = rays[j];
    rays.clear();
    first_ray.clear();
  };
  for (auto const& r : picked) {
    first_ray.push_back(rays.size());
    for (int k = r.pos - k_step / 2; k <= r.pos + k_step / 2; ++k) {
      cv::Point const s = border[((first + k) % n + n) % n];
      for (double a = r.angle - step; a <= r.angle + step + 1e-9; a += step / 3.0) rays.push_back(make(s, a, k));
    }
  }
  keepBest();
  // Then finer, at the best start (a long side needs a fraction of a degree).
  for (auto const& best : picked) {
    first_ray.push_back(rays.size());
    cv::Point const s = border[((first + best.pos) % n + n) % n];
    for (double a = best.angle - step / 3.0; a <= best.angle + step / 3.0 + 1e-9; a += step / 12.0) rays.push_back(make(s, a, best.pos));
  }
  keepBest();
  return picked;
}

// The best pair of sides: near-parallel, not crossing, the strip between them shaft-like and
// darker than the tissue beside it. score 0: none.
struct Pair {
  StripRay a, b;
  double score = 0.0;
};
Pair pairSides(std::vector<StripRay> const& side0, std::vector<StripRay> const& side1, cv::Mat const& feature,
               FieldOfView const& fov, int level, StripSearchParams const& p, ContourLinesParams const& lp) {
  double const cos_max = std::cos(lp.max_angle_deg * M_PI / 180.0);
  Pair best;
  for (auto const& a : side0)
    for (auto const& b : side1) {
      if (b.pos - a.pos < p.min_width_px || a.length < p.min_side_px || b.length < p.min_side_px || a.dir.dot(b.dir) < cos_max)
        continue;
      if (a.score + b.score <= best.score) continue;
      if (std::min(a.length, b.length) < p.min_length_ratio * std::max(a.length, b.length)) continue;
      double const lmin = std::min(a.length, b.length);
      double const w0 = (b.start - a.start).dot(-a.out);
      double const w1 = (b.start + lmin * b.dir - a.start - lmin * a.dir).dot(-a.out);
      if (w0 < p.min_width_px || w1 < p.min_end_width * w0) continue;  // too thin, crossing or pinched
      if (lmin < w0) continue;  // a blob's rim, not a shaft (refineContour checks the elongation of the refined lines)
      // Both sides head into the view: a dark corner or rim has a side along the FOV edge.
      if (!fov.depth.empty()) {
        bool inward = true;
        for (StripRay const* r : {&a, &b}) {
          inward = inward && depthAt(fov, r->start + r->length * r->dir) >= lp.min_entry_sine * r->length;
        }
        if (!inward) continue;
      }
      // Inside: mostly shaft-like (at or below the level), and its median well below the tissue's
      // just outside each side (a side against the FOV edge has no outside samples: not tested).
      int low = 0, all = 0;
      std::vector<int> in, o0, o1;
      auto add = [&](Eigen::Vector2d const& q, std::vector<int>& v, bool interior) {
        int const x = static_cast<int>(std::lround(q.x())), y = static_cast<int>(std::lround(q.y()));
        if (x < 0 || y < 0 || x >= feature.cols || y >= feature.rows) return;
        int const f = feature.at<std::uint8_t>(y, x);
        if (interior) {
          ++all;
          low += f <= level;
        }
        if (fov.mask.at<std::uint8_t>(y, x)) v.push_back(f);
      };
      for (double t = 1.0; t <= lmin; t += 2.0) {
        Eigen::Vector2d const qa = a.start + t * a.dir, qb = b.start + t * b.dir;
        double const d = std::max(3.0, 0.3 * (qb - qa).norm());
        for (double f : {0.25, 0.5, 0.75}) add(qa + f * (qb - qa), in, true);
        add(qa + d * a.out, o0, false);
        add(qb + d * b.out, o1, false);
      }
      if (all == 0 || low < p.min_inside_low * all || in.empty()) continue;
      double const mi = median(in);
      bool contrast = true;
      for (auto* o : {&o0, &o1})
        if (o->size() >= 4) contrast = contrast && mi <= p.max_inside_outside_ratio * median(*o);
      if (!contrast) continue;
      best.score = a.score + b.score;
      best.a = a;
      best.b = b;
    }
  return best;
}

// A search window per side: border starts (relative to the run's beginning) and ray angles
// (about the inward normal).
struct SideWindows {
  std::array<int, 2> from{}, to{};
  std::array<double, 2> lo{}, hi{};
};

// The windows about the previous frame's strip, when both of its sides start within track_px of
// the run (each searched +-track_px / 2 about its start, +-2 coarse steps about its angle);
// nullopt otherwise.
std::optional<SideWindows> trackedWindows(std::vector<cv::Point> const& B, int ib, int len, StripCandidate const& previous,
                                          Eigen::Vector2d const& inward, StripSearchParams const& p) {
  int const n = static_cast<int>(B.size());
  double const amax = p.max_angle_deg * M_PI / 180.0, step = p.coarse_step_deg * M_PI / 180.0;
  int const ext = std::max(p.start_slack_px, p.extend_px);
  std::array<int, 2> const k_from{-ext, 0}, k_to{len - 1, len - 1 + ext};
  SideWindows w;
  for (int s = 0; s < 2; ++s) {
    double bd = 1e300;
    int kk = 0;
    for (int k = k_from[s]; k <= k_to[s]; ++k) {
      cv::Point const q = B[((ib + k) % n + n) % n];
      double const d = (Eigen::Vector2d(q.x, q.y) - previous.start[s]).squaredNorm();
      if (d < bd) {
        bd = d;
        kk = k;
      }
    }
    if (bd > p.track_px * p.track_px) return std::nullopt;
    Eigen::Vector2d const d = previous.dir[s];
    double const a = std::atan2(inward.x() * d.y() - inward.y() * d.x(), inward.dot(d));
    w.from[s] = kk - p.track_px / 2;
    w.to[s] = kk + p.track_px / 2;
    w.lo[s] = std::max(-amax, a - 2.0 * step);
    w.hi[s] = std::min(amax, a + 2.0 * step);
  }
  return w;
}

// The strip of a side pair: its sides (full-resolution points and lines, the shaft on their
// positive side) and the quadrilateral between the rays as its region.
StripCandidate stripOfPair(Pair const& pr, Seed const& seed, int level, int scale) {
  StripCandidate out;
  out.score = pr.score;
  auto toFull = [&](Eigen::Vector2d const& q) { return toFullRes(q, scale); };
  SideFit& sf = out.sides;
  StripRay const* rays[2] = {&pr.a, &pr.b};
  for (int s = 0; s < 2; ++s) {
    StripRay const& r = *rays[s];
    out.start[s] = r.start;
    out.dir[s] = r.dir;
    for (double t = 1.0; t <= r.length; t += 1.0) sf.points[s].push_back(toFull(r.start + t * r.dir));
    Eigen::Vector2d const nrm = -r.out;  // toward the shaft
    Eigen::Vector2d const p0 = toFull(r.start);
    sf.lines[s] = Eigen::Vector3d(nrm.x(), nrm.y(), -nrm.dot(p0));
    sf.inliers += static_cast<int>(sf.points[s].size());
  }
  sf.entry = toFull(Eigen::Vector2d(seed.position.x, seed.position.y));
  setFarEnd(sf);
  Region& rg = out.region;
  rg.seed = seed.position;
  rg.threshold = level;
  auto pt = [](Eigen::Vector2d const& q) { return cv::Point(static_cast<int>(std::lround(q.x())), static_cast<int>(std::lround(q.y()))); };
  StripRay const &ba = pr.a, &bb = pr.b;
  rg.boundary = {pt(ba.start), pt(ba.start + ba.length * ba.dir), pt(bb.start + bb.length * bb.dir), pt(bb.start)};
  rg.box = cv::boundingRect(rg.boundary);
  rg.area = static_cast<int>(std::lround(cv::contourArea(rg.boundary)));
  return out;
}

}  // namespace

std::optional<StripCandidate> searchStrip(cv::Mat const& feature, cv::Mat const& gx, cv::Mat const& gy,
                                          FieldOfView const& fov, Seed const& seed, int level, int scale,
                                          StripSearchParams const& p, ContourLinesParams const& lp,
                                          StripCandidate const* previous) {
  CV_Assert(feature.type() == CV_8U && gx.type() == CV_16S && gy.type() == CV_16S && gx.size() == feature.size() &&
            fov.mask.size() == feature.size());
  return searchStrip(feature, packRayField(gx, gy, fov), fov, seed, level, scale, p, lp, previous);
}

std::optional<StripCandidate> searchStrip(cv::Mat const& feature, RayField const& field, FieldOfView const& fov, Seed const& seed,
                                          int level, int scale, StripSearchParams const& p, ContourLinesParams const& lp,
                                          StripCandidate const* previous) {
  checkField(field);
  CV_Assert(feature.type() == CV_8U && field.packed.size() == feature.size() && fov.mask.size() == feature.size());
  auto const& B = fov.border;
  int const n = static_cast<int>(B.size());
  if (n < 8 || seed.width < 3) return std::nullopt;
  int const ib = seed.begin, ie = ((seed.end - 1) % n + n) % n;
  Eigen::Vector2d const pb(B[ib].x, B[ib].y), pe(B[ie].x, B[ie].y);
  if ((pb - pe).norm() < 2.0) return std::nullopt;
  // Inward normal at the seed: the gradient of the distance to the FOV edge, else toward the centre.
  Eigen::Vector2d inward = depthGradient(fov, seed.position);
  if (inward.norm() <= 1e-6) inward = Eigen::Vector2d(fov.centre.x - seed.position.x, fov.centre.y - seed.position.y);
  if (inward.norm() < 1e-9) return std::nullopt;
  inward.normalize();
  // Sides start on the run (plus the slack; a run can extend beyond the shaft along a dark rim):
  // side 0 has the shaft toward the run's end, side 1 toward its beginning. A run can also cover
  // only part of a wide shaft's crossing (metal mirrors the tissue): if no pair is found, each
  // side is searched again up to extend_px beyond the run's far end. With the strip of the
  // previous frame, each side is searched only about where it was.
  int const len = seed.width;
  double const amax = p.max_angle_deg * M_PI / 180.0;
  // (the full searches' sweeps, per side: the extended search walks again only the new starts)
  std::array<SweepCache, 2> walked;
  auto search = [&](std::array<int, 2> const& k_from, std::array<int, 2> const& k_to, int k_step,
                    std::array<double, 2> const& a_lo, std::array<double, 2> const& a_hi, int candidates, bool full) {
    std::vector<StripRay> const side0 = searchSide(B, ib, k_from[0], k_to[0], k_step, a_lo[0], a_hi[0], candidates, inward, pb - pe,
                                                   field, p, full ? &walked[0] : nullptr);
    std::vector<StripRay> const side1 = searchSide(B, ib, k_from[1], k_to[1], k_step, a_lo[1], a_hi[1], candidates, inward, pe - pb,
                                                   field, p, full ? &walked[1] : nullptr);
    return pairSides(side0, side1, feature, fov, level, p, lp);
  };
  std::array<double, 2> const full_lo{-amax, -amax}, full_hi{amax, amax};
  Pair pr;
  std::optional<SideWindows> const near = previous ? trackedWindows(B, ib, len, *previous, inward, p) : std::nullopt;
  if (near) {
    pr = search(near->from, near->to, 1, near->lo, near->hi, 2, false);
  } else {
    int const k_step = std::max(1, len / p.max_starts);
    pr = search({-p.start_slack_px, 0}, {len - 1, len - 1 + p.start_slack_px}, k_step, full_lo, full_hi,
                p.candidates_per_side, true);
    if (pr.score <= 0.0 && p.extend_px > p.start_slack_px) {
      int const ext = p.extend_px, k_step2 = std::max(1, (len + ext) / p.max_starts);
      pr = search({-ext, 0}, {len - 1, len - 1 + ext}, k_step2, full_lo, full_hi, p.candidates_per_side, true);
    }
  }
  if (pr.score <= 0.0) return std::nullopt;
  return stripOfPair(pr, seed, level, scale);
}

bool stripAgrees(StripCandidate const& strip, geometry::ApparentContour const& contour, int scale, StripSearchParams const& p) {
  double const tol = p.max_refine_shift * scale;
  for (int s = 0; s < 2; ++s) {
    auto const& pts = strip.sides.points[s];
    if (pts.empty()) return false;
    // The contour's lines are reordered (left/right): compare with the nearer one.
    double best = std::numeric_limits<double>::infinity();
    for (auto const& l : contour.lines) {
      double worst = 0.0;
      for (Eigen::Vector2d const& q : {pts.front(), pts.back()})
        worst = std::max(worst, std::abs(l.head<2>().dot(q) + l.z()));
      best = std::min(best, worst);
    }
    if (best > tol) return false;
  }
  return true;
}

ContourFit refineStrip(StripCandidate const& strip, FieldOfView const& fov, cv::Mat const& bgr, int scale,
                       StripSearchParams const& p, ContourLinesParams const& lines) {
  ContourFit f = refineContour(strip.sides, strip.region, fov, bgr, scale, lines);
  if (!f.contour || stripAgrees(strip, *f.contour, scale, p)) return f;
  // The wide pass took the steepest edge within +-coarse_halfwidth_px of the strip's side:
  // narrower windows leave a neighbouring edge out (only when the lines left the strip).
  if (p.retry_min_halfwidth_px > 0.0) {
    ContourLinesParams narrow = lines;
    for (double h = lines.coarse_halfwidth_px - 1.0; h >= p.retry_min_halfwidth_px; h -= 1.0) {
      narrow.coarse_halfwidth_px = h;
      ContourFit g = refineContour(strip.sides, strip.region, fov, bgr, scale, narrow);
      if (g.contour && stripAgrees(strip, *g.contour, scale, p)) return g;
    }
  }
  f.contour.reset();
  f.rejection = ContourRejection::kNotStraight;  // the sub-pixel lines left the strip
  return f;
}

bool stripContrastFullRes(cv::Mat const& bgr, geometry::ApparentContour const& c, StripSearchParams const& p) {
  return stripContrastFullRes(acrossContour(bgr, c), p);
}

bool stripContrastFullRes(AcrossSamples s, StripSearchParams const& p) {
  auto& in = s.inside;
  auto& out = s.outside;
  int const specular = s.glare;  // near-white samples inside: highlights
  if (in.empty()) return false;
  // A weakly contrasted strip is a shaft only if matte: a band of highlights on wet tissue is not.
  double const mi = median(in);
  bool const matte = specular < p.max_specular_fraction * static_cast<double>(in.size());
  double const max_ratio = matte ? p.max_full_res_ratio_matte : p.max_full_res_ratio;
  double const q = std::clamp(p.full_res_outside_quantile, 0.0, 1.0);
  for (auto& o : out) {
    if (o.size() < 4) continue;
    auto const k = std::min(o.size() - 1, static_cast<std::size_t>(q * static_cast<double>(o.size())));
    std::nth_element(o.begin(), o.begin() + static_cast<long>(k), o.end());
    if (mi > max_ratio * static_cast<double>(o[k])) return false;
  }
  return true;
}

}  // namespace endo_guidance::perception
