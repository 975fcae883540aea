// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/edge_profile.h"

#include <opencv2/core/hal/intrin.hpp>
#include <cstring>
#if defined(__GNUC__) && defined(__x86_64__)
#include <immintrin.h>
#define ENDO_GUIDANCE_AVX2 1
#endif

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

namespace endo_guidance::perception {

namespace {

// edgeChannel() of the bilinear colour at (x, y); false outside.
bool edgeAt(cv::Mat const& bgr, double x, double y, float* out) {
  if (x < 0.0 || y < 0.0 || x >= bgr.cols - 1 || y >= bgr.rows - 1) return false;
  float c[3];
  bilinearAt(bgr, x, y, c);
  *out = edgeChannel(c[0], c[1], c[2]);
  return true;
}

#ifdef ENDO_GUIDANCE_AVX2
inline std::int32_t load4(std::uint8_t const* q) {
  std::int32_t v;
  std::memcpy(&v, q, 4);
  return v;
}
// The 4 bytes at base + off[k] in lane k (B, G, R, -): eight loads and inserts (AVX2's gather
// instruction made the sampler slower here).
__attribute__((target("avx2"))) inline __m256i cornerLanes(char const* base, int const* off) {
  auto const q = [base](int o) { return load4(reinterpret_cast<std::uint8_t const*>(base + o)); };
  return _mm256_setr_epi32(q(off[0]), q(off[1]), q(off[2]), q(off[3]), q(off[4]), q(off[5]), q(off[6]), q(off[7]));
}
// Channel ch (0 B, 1 G, 2 R) of each lane of cornerLanes() as a float.
__attribute__((target("avx2"))) inline __m256 channel(__m256i q, int ch, __m256i mask) {
  return _mm256_cvtepi32_ps(_mm256_and_si256(_mm256_srli_epi32(q, 8 * ch), mask));
}
// sampleEdgeChannel() eight samples per step, one per lane, the channels in separate vectors: each
// corner is 4 bytes per sample (B, G, R, -). Positions in double as edgeAt() computes them
// (a + i d: multiply, then add; no FMA is enabled here, so none is contracted), the bilinear
// interpolation with edgeAt()'s operations in its order: identical results. A step with a
// sample whose loads would pass the end of its row (the last two columns) takes edgeAt(), as
// does a profile shorter than 8 samples. The last step overlaps the one before.
__attribute__((target("avx2"))) void sampleEdgeChannelAvx2(cv::Mat const& bgr, Eigen::Vector2d const& a, Eigen::Vector2d const& d,
                                                      int count, float* out) {
  if (count < 8) {
    for (int i = 0; i < count; ++i) edgeAt(bgr, a.x() + i * d.x(), a.y() + i * d.y(), &out[i]);
    return;
  }
  int const stride = static_cast<int>(bgr.step[0]);
  char const* const base = reinterpret_cast<char const*>(bgr.data);
  __m256i const x_last = _mm256_set1_epi32(bgr.cols - 3), mask = _mm256_set1_epi32(0xff), vstride = _mm256_set1_epi32(stride),
                three = _mm256_set1_epi32(3);
  __m256 const one = _mm256_set1_ps(1.f);
  __m256d const ax = _mm256_set1_pd(a.x()), ay = _mm256_set1_pd(a.y()), dx = _mm256_set1_pd(d.x()), dy = _mm256_set1_pd(d.y());
  for (int i0 = 0; i0 < count; i0 += 8) {
    int const i = std::min(i0, count - 8);
    __m256d const k0 = _mm256_setr_pd(i, i + 1, i + 2, i + 3), k1 = _mm256_setr_pd(i + 4, i + 5, i + 6, i + 7);
    __m256d const x_lo = _mm256_add_pd(ax, _mm256_mul_pd(k0, dx)), x_hi = _mm256_add_pd(ax, _mm256_mul_pd(k1, dx));
    __m256d const y_lo = _mm256_add_pd(ay, _mm256_mul_pd(k0, dy)), y_hi = _mm256_add_pd(ay, _mm256_mul_pd(k1, dy));
    __m128i const xi_lo = _mm256_cvttpd_epi32(x_lo), xi_hi = _mm256_cvttpd_epi32(x_hi);
    __m128i const yi_lo = _mm256_cvttpd_epi32(y_lo), yi_hi = _mm256_cvttpd_epi32(y_hi);
    __m256i const x0 = _mm256_set_m128i(xi_hi, xi_lo), y0 = _mm256_set_m128i(yi_hi, yi_lo);
    if (!_mm256_testz_si256(_mm256_cmpgt_epi32(x0, x_last), _mm256_cmpgt_epi32(x0, x_last))) {
      for (int k = i; k < i + 8; ++k) edgeAt(bgr, a.x() + k * d.x(), a.y() + k * d.y(), &out[k]);
      continue;
    }
    __m256 const fx = _mm256_set_m128(_mm256_cvtpd_ps(_mm256_sub_pd(x_hi, _mm256_cvtepi32_pd(xi_hi))),
                                      _mm256_cvtpd_ps(_mm256_sub_pd(x_lo, _mm256_cvtepi32_pd(xi_lo))));
    __m256 const fy = _mm256_set_m128(_mm256_cvtpd_ps(_mm256_sub_pd(y_hi, _mm256_cvtepi32_pd(yi_hi))),
                                      _mm256_cvtpd_ps(_mm256_sub_pd(y_lo, _mm256_cvtepi32_pd(yi_lo))));
    __m256i const off = _mm256_add_epi32(_mm256_mullo_epi32(y0, vstride), _mm256_mullo_epi32(x0, three));
    alignas(32) int offs[8];
    _mm256_store_si256(reinterpret_cast<__m256i*>(offs), off);
    __m256i const q00 = cornerLanes(base, offs), q01 = cornerLanes(base + 3, offs), q10 = cornerLanes(base + stride, offs),
                  q11 = cornerLanes(base + stride + 3, offs);
    __m256 const ofx = _mm256_sub_ps(one, fx), ofy = _mm256_sub_ps(one, fy);
    __m256 mx, mn;
    for (int ch = 0; ch < 3; ++ch) {
      __m256 const v = _mm256_add_ps(
          _mm256_mul_ps(ofy, _mm256_add_ps(_mm256_mul_ps(ofx, channel(q00, ch, mask)), _mm256_mul_ps(fx, channel(q01, ch, mask)))),
          _mm256_mul_ps(fy, _mm256_add_ps(_mm256_mul_ps(ofx, channel(q10, ch, mask)), _mm256_mul_ps(fx, channel(q11, ch, mask)))));
      mx = ch == 0 ? v : _mm256_max_ps(mx, v);
      mn = ch == 0 ? v : _mm256_min_ps(mn, v);
    }
    _mm256_storeu_ps(out + i, _mm256_sub_ps(mx, mn));  // edgeChannel()
  }
}
#endif

}  // namespace

// The edge channel at a + i d, i = 0..count-1, bilinear, all inside the image (edgeAt() without the
// bounds test: the inner loop of the sub-pixel refinement). One sample per
// SIMD step with the channels in the lanes: each corner is one 4-byte load (B, G, R and the next
// pixel's B, unused), interpolated with the same operations, in the same order, as edgeAt(), so
// the results are identical. A sample whose 4-byte load would pass the end of its row (the last
// two columns) takes edgeAt(). On a CPU with AVX2 (and OpenCV's optimisations on:
// cv::setUseOptimized()), eight samples per step (sampleEdgeChannelAvx2()), the same results. perf on
// a 640x480 frame: the sampler's share 14 % with two samples per step, 11 % with eight.
void sampleEdgeChannel(cv::Mat const& bgr, Eigen::Vector2d const& a, Eigen::Vector2d const& d, int count, float* out,
                       bool reference) {
  if (reference) {
    for (int i = 0; i < count; ++i) edgeAt(bgr, a.x() + i * d.x(), a.y() + i * d.y(), &out[i]);
    return;
  }
#ifdef ENDO_GUIDANCE_AVX2
  if (cv::checkHardwareSupport(CV_CPU_AVX2)) return sampleEdgeChannelAvx2(bgr, a, d, count, out);
#endif
  std::size_t const stride = bgr.step[0];
  std::uint8_t const* const data = bgr.data;
  int const x_last = bgr.cols - 3;  // x0 + 1 + 1 must stay in the row
  cv::v_float32x4 const one = cv::v_setall_f32(1.f);
  auto corner = [](std::uint8_t const* q) {
    alignas(4) std::uint8_t b[4];  // (v_load_expand_q reads an int: q is not 4-byte aligned; one movd all the same)
    std::memcpy(b, q, 4);
    return cv::v_cvt_f32(cv::v_reinterpret_as_s32(cv::v_load_expand_q(b)));
  };
  for (int i = 0; i < count; ++i) {
    double const x = a.x() + i * d.x(), y = a.y() + i * d.y();
    int const x0 = static_cast<int>(x), y0 = static_cast<int>(y);
    if (x0 > x_last) {
      edgeAt(bgr, x, y, &out[i]);
      continue;
    }
    cv::v_float32x4 const fx = cv::v_setall_f32(static_cast<float>(x - x0)), fy = cv::v_setall_f32(static_cast<float>(y - y0));
    std::uint8_t const* p0 = data + y0 * stride + 3 * x0;
    std::uint8_t const* p1 = p0 + stride;
    cv::v_float32x4 const c = (one - fy) * ((one - fx) * corner(p0) + fx * corner(p0 + 3)) +
                              fy * ((one - fx) * corner(p1) + fx * corner(p1 + 3));  // B, G, R, -
    cv::v_float32x4 const c1 = cv::v_rotate_right<1>(c), c2 = cv::v_rotate_right<2>(c);  // G, R, ... and R, ...
    out[i] = (cv::v_max(c, cv::v_max(c1, c2)) - cv::v_min(c, cv::v_min(c1, c2))).get0();  // edgeChannel()
  }
}

namespace {

// Sub-pixel position (in samples) of the steepest descent of a profile (tissue at index 0, shaft
// at the end): the centroid of the slope about its peak, within +-2.5 px -- exact for a
// box-filtered (anti-aliased) step under bilinear sampling and unbiased for any symmetric blur,
// whereas a parabola on the peak, or weights cut at a fraction of it, is biased by up to 0.15 px
// on sharp edges (the slope of such a step is a two-level staircase). `lobe_floor` >= 0: only the
// contiguous lobe of the peak whose slope stays above lobe_floor times the peak counts (whole
// samples, uncut), not the slope of textured tissue further in the window, which counts only
// where it descends (ascents weigh nothing) and so pulls the edge outward (test
// SubpixelEdgeIsNotPulledByTheTissueTexture); < 0:
// every descending sample of the window. nullopt: no descent steeper than min_slope (per sample
// pair), or the window would be cut by the profile's end (the centroid would be biased).
std::optional<double> steepestDescent(std::vector<float> const& prof, double ds, double min_slope, double lobe_floor) {
  int const ns = static_cast<int>(prof.size());
  int bi = -1;
  float bg = -static_cast<float>(min_slope);
  for (int i = 1; i + 1 < ns; ++i) {
    float const g = prof[i + 1] - prof[i - 1];
    bi = g < bg ? i : bi;  // (branch-free: where the minimum falls is not predictable)
    bg = std::min(bg, g);
  }
  int const wr = static_cast<int>(std::lround(2.5 / ds));
  if (bi < 0 || bi - wr < 1 || bi + wr > ns - 2) return std::nullopt;
  auto slope = [&](int i) { return prof[i - 1] - prof[i + 1]; };  // descending: positive
  int lo = bi - wr, hi = bi + wr;
  if (lobe_floor >= 0.0) {
    float const floor = static_cast<float>(lobe_floor) * -bg;
    for (lo = bi; lo > bi - wr && slope(lo - 1) > floor;) --lo;
    for (hi = bi; hi < bi + wr && slope(hi + 1) > floor;) ++hi;
  }
  double sw = 0.0, swx = 0.0;
  for (int i = lo; i <= hi; ++i) {
    double const g = slope(i);
    if (g <= 0.0) continue;
    sw += g;
    swx += g * i;
  }
  if (!(sw > 0.0)) return std::nullopt;
  return swx / sw;
}


}  // namespace

namespace {

// Sub-pixel edge points on profiles across a line, one at a time (the buffers of a profile are
// reused).
class EdgeProfiler {
 public:
  EdgeProfiler(cv::Mat const& bgr, ContourLinesParams const& p, ColourDirection const* direction)
      : bgr_(bgr), p_(p), direction_(direction), h_(p.refine_halfwidth_px), ds_(p.profile_step_px),
        ns_(static_cast<int>(std::lround(2.0 * h_ / ds_)) + 1), prof_(static_cast<std::size_t>(ns_)) {}

  // The edge on the profile across `line` at t along its direction (-b, a); nullopt when the
  // profile leaves the image or has no edge steeper than min_edge_contrast.
  std::optional<Eigen::Vector2d> at(geometry::ImageLine const& line, double t) {
    Eigen::Vector2d const n = line.head<2>();   // toward the shaft
    Eigen::Vector2d const dir(-n.y(), n.x());
    Eigen::Vector2d const o = -line.z() * n;    // foot of the origin
    double const xmax = bgr_.cols - 1, ymax = bgr_.rows - 1;
    Eigen::Vector2d const base = o + t * dir;
    // The profile lies inside the image if both its ends do (edgeAt's bounds).
    Eigen::Vector2d const a = base - h_ * n, b = base + (-h_ + (ns_ - 1) * ds_) * n;
    if (!(std::min(a.x(), b.x()) >= 0.0 && std::min(a.y(), b.y()) >= 0.0 && std::max(a.x(), b.x()) < xmax &&
          std::max(a.y(), b.y()) < ymax))
      return std::nullopt;
    if (direction_) sampleProjection(a, ds_ * n);
    else sampleEdgeChannel(bgr_, a, ds_ * n, ns_, prof_.data());
    // The edge is located in the edge channel, where the shaded rim of a grey shaft does not bias
    // it (metal mirrors tissue colours, so it is the steepest descent, not the first seen from inside).
    auto const at = steepestDescent(prof_, ds_, p_.min_edge_contrast * 2.0 * ds_, p_.edge_lobe_floor);
    if (!at) return std::nullopt;
    return Eigen::Vector2d(base + (-h_ + *at * ds_) * n);
  }

 private:
  // The colour along direction_ at a + i d, bilinear as edgeAt() (every sample inside the image).
  void sampleProjection(Eigen::Vector2d const& a, Eigen::Vector2d const& d) {
    for (int i = 0; i < ns_; ++i) {
      float c[3];
      bilinearAt(bgr_, a.x() + i * d.x(), a.y() + i * d.y(), c);
      prof_[static_cast<std::size_t>(i)] = (*direction_)[0] * c[0] + (*direction_)[1] * c[1] + (*direction_)[2] * c[2];
    }
  }

  cv::Mat const& bgr_;
  ContourLinesParams const& p_;
  ColourDirection const* direction_;
  double const h_, ds_;
  int const ns_;
  std::vector<float> prof_;
};

// The sub-pixel edge points of refineLineSubpixel(): one per profile with an edge steeper than
// min_edge_contrast, at t = t0 + j refine_step_px up to t1. `reuse`: profiles taken with the same
// parameters at t0 + i step (step a multiple of refine_step_px), used where the line and t0 are
// exactly the same; `record`: where to keep every profile's edge.
std::vector<Eigen::Vector2d> subpixelEdgePoints(cv::Mat const& bgr, geometry::ImageLine const& line, double t0, double t1,
                                               ContourLinesParams const& p, ColourDirection const* direction,
                                               ProfileEdges const* reuse = nullptr, ProfileEdges* record = nullptr) {
  CV_Assert(!(direction && reuse));  // (the profiles reused are edgeChannel()'s)
  EdgeProfiler profiler(bgr, p, direction);
  std::vector<Eigen::Vector2d> pts;
  double const step = p.refine_step_px;
  // Every m-th profile is one of `reuse`'s: the same t exactly (integer multiples of the steps).
  int m = 0;
  if (reuse && reuse->line == line && reuse->t0 == t0 && step > 0.0 && reuse->step >= step) {
    double const r = reuse->step / step;
    if (r == std::round(r)) m = static_cast<int>(r);
  }
  if (record) {
    record->line = line;
    record->t0 = t0;
    record->step = step;
    record->edges.clear();
  }
  for (int j = 0;; ++j) {
    double const t = t0 + j * step;  // (not accumulated: the reused profiles' t are the same)
    if (!(t <= t1)) break;
    std::optional<Eigen::Vector2d> q;
    if (m > 0 && j % m == 0 && static_cast<std::size_t>(j / m) < reuse->edges.size()) q = reuse->edges[static_cast<std::size_t>(j / m)];
    else q = profiler.at(line, t);
    if (record) record->edges.push_back(q);
    if (q) pts.push_back(*q);
  }
  return pts;
}

}  // namespace

ContourLinesParams widePass(ContourLinesParams const& p) {
  ContourLinesParams wide = p;
  wide.refine_halfwidth_px = p.coarse_halfwidth_px;
  wide.profile_step_px = 2.0 * p.profile_step_px;
  wide.edge_lobe_floor = -1.0;  // it recentres and scores: the whole window (the lobe alone loses weak shafts)
  return wide;
}

namespace {

// The robust line through sub-pixel edge points, oriented like `line` (shaft on the positive
// side), with its covariance: Tukey biweight (scale from the MAD, three passes) from a
// least-squares start. A few points beyond one end of the others (a jaw past a gap) tilt that
// start by their leverage, and the biweight then keeps them; so it is also run from the LMedS
// line ([Rousseeuw87]), and that fit is kept when all it leaves out lies beyond one end of what
// it keeps and its biweight loss is the lower at the smaller of the two fits' scales.
// `lmeds_start` false: the least-squares start only (a line that only steers a search).
std::optional<RefinedLine> robustEdgeLine(std::vector<Eigen::Vector2d> const& pts, geometry::ImageLine const& line, ContourLinesParams const& p,
                                          bool lmeds_start = true) {
  Eigen::Vector2d const n = line.head<2>();
  if (static_cast<int>(pts.size()) < p.min_edge_points) return std::nullopt;
  struct Fit {
    Eigen::Vector3d l;
    std::vector<double> w;
    double scale;
  };
  std::vector<double> r(pts.size()), rr(pts.size());
  auto residuals = [&](Eigen::Vector3d const& l) {
    for (std::size_t i = 0; i < pts.size(); ++i) r[i] = std::abs(l.head<2>().dot(pts[i]) + l.z());
  };
  auto reweight = [&](Fit& f) {
    residuals(f.l);
    std::copy(r.begin(), r.end(), rr.begin());
    std::nth_element(rr.begin(), rr.begin() + rr.size() / 2, rr.end());
    f.scale = std::max(1.4826 * rr[rr.size() / 2], 0.05);
    for (std::size_t i = 0; i < pts.size(); ++i) {
      double const u = r[i] / (4.685 * f.scale);
      f.w[i] = u < 1.0 ? (1 - u * u) * (1 - u * u) : 0.0;
    }
  };
  auto biweight = [&](Fit f, int passes) -> std::optional<Fit> {
    for (int it = 0; it < passes; ++it) {
      auto const l = fitLineLS(pts, &f.w);
      if (!l) return std::nullopt;
      f.l = *l;
      reweight(f);
    }
    return f;
  };
  // Tukey's biweight rho at scale s, summed: the loss the reweighting descends.
  auto loss = [&](Eigen::Vector3d const& l, double s) {
    residuals(l);
    double sum = 0.0;
    for (double const e : r) {
      double const u = std::min(e / (4.685 * s), 1.0), v = 1.0 - u * u;
      sum += 1.0 - v * v * v;
    }
    return sum;
  };
  // Only points beyond one end of the others have leverage on the least-squares start (and a
  // fit that leaves out points inside its own span is a shorter, straighter piece of a crooked
  // edge, such as a tissue fold's): the run left out lies past one end, and enough remain.
  auto const leverageOnly = [&](Fit const& f) {
    Eigen::Vector2d const d(-f.l.y(), f.l.x());
    double kept_lo = std::numeric_limits<double>::infinity(), kept_hi = -kept_lo, out_lo = kept_lo, out_hi = kept_hi;
    int kept = 0;
    for (std::size_t i = 0; i < pts.size(); ++i) {
      double const t = d.dot(pts[i]);
      if (f.w[i] > 0.0) ++kept, kept_lo = std::min(kept_lo, t), kept_hi = std::max(kept_hi, t);
      else out_lo = std::min(out_lo, t), out_hi = std::max(out_hi, t);
    }
    return kept >= p.min_edge_points && out_lo <= out_hi && (out_lo > kept_hi || out_hi < kept_lo);
  };
  auto best = biweight(Fit{line, std::vector<double>(pts.size(), 1.0), 0.0}, 3);  // (the first pass unweighted)
  if (!best) return std::nullopt;
  if (auto const start = lmeds_start ? fitLineLMedS(pts, p.lmeds_samples, p.seed + pts.size()) : std::nullopt) {
    Fit f{start->line, std::vector<double>(pts.size()), 0.0};
    reweight(f);
    auto const g = biweight(std::move(f), 3);
    if (g && leverageOnly(*g)) {
      double const sc = std::min(g->scale, best->scale);
      if (loss(g->l, sc) < loss(best->l, sc)) best = g;
    }
  }
  Eigen::Vector3d l = best->l;
  std::vector<double> const& w = best->w;
  if (l.head<2>().dot(n) < 0.0) l = -l;  // keep the shaft on the positive side
  return summarizeLine(l, pts, w, p.min_edge_points, p.line_sigma_floor_px);
}

}  // namespace

std::optional<RefinedLine> refineLineSubpixel(cv::Mat const& bgr, geometry::ImageLine const& line, double t0, double t1,
                                              ContourLinesParams const& p, ColourDirection const* direction) {
  return robustEdgeLine(subpixelEdgePoints(bgr, line, t0, t1, p, direction), line, p);
}

std::optional<RefinedLine> refineLineProfiles(cv::Mat const& bgr, geometry::ImageLine const& line, double t0, double t1, ContourLinesParams const& p,
                                              ProfileEdges const* reuse, ProfileEdges* record, ColourDirection const* direction) {
  return robustEdgeLine(subpixelEdgePoints(bgr, line, t0, t1, p, direction, reuse, record), line, p);
}

std::optional<ColourDirection> sideColourDirection(cv::Mat const& bgr, geometry::ImageLine const& line, double t0, double t1,
                                                   double inside_px, double outside_px) {
  CV_Assert(bgr.type() == CV_8UC3);
  Eigen::Vector2d const n = line.head<2>(), d(-n.y(), n.x()), o = -line.z() * n;
  std::array<std::vector<float>, 3> in, out;
  for (double t = t0; t <= t1; t += 2.0)
    for (double const depth : {inside_px, -outside_px}) {
      Eigen::Vector2d const x = o + t * d + depth * n;
      int const xi = static_cast<int>(std::lround(x.x())), yi = static_cast<int>(std::lround(x.y()));
      if (xi < 0 || yi < 0 || xi >= bgr.cols || yi >= bgr.rows) continue;
      cv::Vec3b const c = bgr.at<cv::Vec3b>(yi, xi);
      for (int k = 0; k < 3; ++k) (depth > 0.0 ? in : out)[k].push_back(c[k]);
    }
  if (in[0].size() < 3 || out[0].size() < 3) return std::nullopt;
  auto median = [](std::vector<float>& v) {
    std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  ColourDirection w;
  for (int k = 0; k < 3; ++k) w[k] = median(out[k]) - median(in[k]);
  if (!(w.norm() >= 1.0)) return std::nullopt;  // (a grey level: no direction)
  return ColourDirection(w.normalized());
}

std::optional<RefinedLine> extendLineSubpixel(cv::Mat const& bgr, RefinedLine const& refined, double t0, double t1,
                                              double t_lo, double t_hi, ContourLinesParams const& p,
                                              ColourDirection const* direction) {
  if (p.extend_max_misses <= 0 || refined.inliers.empty()) return std::nullopt;
  geometry::ImageLine l = refined.line;
  std::vector<Eigen::Vector2d> pts = refined.inliers;
  // An edge point continues the line within 3 of its residuals (at least gate_min px).
  double const gate = std::max(3.0 * refined.residual_px, p.extend_gate_px);
  std::size_t const before = pts.size();
  EdgeProfiler profiler(bgr, p, direction);
  for (int dir : {1, -1}) {
    double t = dir > 0 ? t1 : t0;
    int misses = 0, added = 0;
    // After a gap of more than a few profiles (an instrument or a blob across the edge), the
    // edge found again is kept only once it holds over kConfirm profiles in a row: a lone edge
    // point on the line beyond a gap is as likely another edge (tissue, the jaws) as this one.
    int const kFreeGap = 3, kConfirm = 4;
    std::vector<Eigen::Vector2d> pending;
    bool after_gap = false;
    while (true) {
      t += dir * p.refine_step_px;
      if (dir > 0 ? t > t_hi : t < t_lo) break;
      auto const q = profiler.at(l, t);
      if (q && std::abs(l.head<2>().dot(*q) + l.z()) <= gate) {
        if (misses > kFreeGap) after_gap = true;
        misses = 0;
        pending.push_back(*q);
        if (after_gap && static_cast<int>(pending.size()) < kConfirm) continue;
        after_gap = false;
        for (auto const& e : pending) {
          pts.push_back(e);
          // Follow the line as it gets longer (its direction improves with the baseline); it only
          // steers the gate, and the final fit below has both starts.
          if (++added % 16 == 0)
            if (auto const f = robustEdgeLine(pts, l, p, false)) l = f->line;
        }
        pending.clear();
      } else {
        if (after_gap) {  // not confirmed: the gap goes on
          misses += static_cast<int>(pending.size());
          pending.clear();
        }
        if (++misses >= p.extend_max_misses) break;
      }
    }
  }
  if (pts.size() == before) return std::nullopt;
  auto const out = robustEdgeLine(pts, refined.line, p);
  // The extension must continue the same edge: not a noisier one (jaws, a touching blob).
  if (!out || out->residual_px > 1.25 * refined.residual_px + 0.05) return std::nullopt;
  return out;
}

}  // namespace endo_guidance::perception
