// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/contour_lines.h"
#include "endo_guidance/perception/image_reduction.h"

#include <opencv2/core/hal/intrin.hpp>
#include <cstring>
#include <limits>
#if defined(__GNUC__) && defined(__x86_64__)
#include <immintrin.h>
#endif

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <numeric>
#include <opencv2/imgproc.hpp>
#include <random>

#include "endo_guidance/perception/colour_feature.h"

namespace endo_guidance::perception {

char const* toString(ContourRejection r) {
  switch (r) {
    case ContourRejection::kNone: return "accepted";
    case ContourRejection::kTooFewPoints: return "too few boundary points on a side";
    case ContourRejection::kNotStraight: return "a side is not a straight line";
    case ContourRejection::kNotParallel: return "the two sides are not near-parallel";
    case ContourRejection::kTooShort: return "shaft too short";
    case ContourRejection::kTooThin: return "shaft too thin";
    case ContourRejection::kCrossing: return "the sides cross or do not enclose the region";
    case ContourRejection::kWeakEdges: return "too few sub-pixel edge points";
    case ContourRejection::kResidual: return "sub-pixel edge residual too large";
    case ContourRejection::kNotElongated: return "not elongated";
    case ContourRejection::kNotFilled: return "region does not fill the strip between its lines";
    case ContourRejection::kAlongBorder: return "runs along the field-of-view border instead of into the view";
    case ContourRejection::kLowContrast: return "not less chromatic than the tissue beside it (full resolution)";
    case ContourRejection::kWidthJump: return "tracked shaft's width changed too much since the last frame";
    case ContourRejection::kDuplicate: return "a shaft already found";
    case ContourRejection::kWidens: return "widens toward the tip more than a shaft can";
    case ContourRejection::kGlare: return "mostly glare between its lines (near white, achromatic)";
    case ContourRejection::kTipOnBorder: return "its tip is on the field-of-view border (a band across the view, not a shaft entering it)";
    case ContourRejection::kNotContinued: return "found beyond another shaft, but not continued on its other side (not a crossing shaft)";
  }
  return "unknown";
}

namespace {

// Total least squares line through weighted points.
std::optional<Eigen::Vector3d> fitLineLS(std::vector<Eigen::Vector2d> const& pts, std::vector<double> const* w = nullptr) {
  double sw = 0.0;
  Eigen::Vector2d c = Eigen::Vector2d::Zero();
  for (std::size_t i = 0; i < pts.size(); ++i) {
    double const wi = w ? (*w)[i] : 1.0;
    c += wi * pts[i];
    sw += wi;
  }
  if (sw <= 0.0) return std::nullopt;
  c /= sw;
  Eigen::Matrix2d S = Eigen::Matrix2d::Zero();
  for (std::size_t i = 0; i < pts.size(); ++i) {
    double const wi = w ? (*w)[i] : 1.0;
    Eigen::Vector2d const d = pts[i] - c;
    S += wi * d * d.transpose();
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d> es(S);
  Eigen::Vector2d const n = es.eigenvectors().col(0);  // normal: smallest scatter
  return Eigen::Vector3d(n.x(), n.y(), -n.dot(c));
}

// Residual, inliers and covariance of the line l fitted to weighted points (weight 0 = outlier).
std::optional<RefinedLine> summarizeLine(Eigen::Vector3d const& l, std::vector<Eigen::Vector2d> const& pts,
                                         std::vector<double> const& w, int min_points, double sigma_floor_px) {
  RefinedLine out;
  out.line = l;
  double sw = 0.0, ss = 0.0, st = 0.0;
  Eigen::Vector2d c = Eigen::Vector2d::Zero();
  int used = 0;
  for (std::size_t i = 0; i < pts.size(); ++i) {
    if (w[i] <= 0.0) continue;
    double const e = l.head<2>().dot(pts[i]) + l.z();
    ss += w[i] * e * e;
    sw += w[i];
    c += w[i] * pts[i];
    out.inliers.push_back(pts[i]);
    ++used;
  }
  if (used < min_points || sw <= 0.0) return std::nullopt;
  c /= sw;
  Eigen::Vector2d const ld(-l.y(), l.x());
  for (std::size_t i = 0; i < pts.size(); ++i)
    if (w[i] > 0.0) {
      double const t = ld.dot(pts[i] - c);
      st += w[i] * t * t;
    }
  out.residual_px = std::sqrt(ss / sw);
  out.points = used;
  double const s2 = std::max(out.residual_px * out.residual_px, 0.01 * 0.01) * used / std::max(1, used - 2);
  // The residuals give the independent part of the error (s2 / n); a systematic error of
  // sigma_floor at each end of the line, common to its points (compression blocks, shading, the
  // jaws' outline), adds sigma_floor^2 / 2 to the offset and 2 sigma_floor^2 / L^2 to the angle,
  // L^2 = 12 var(t) the extent of the points.
  double const f2 = sigma_floor_px * sigma_floor_px, L2 = 12.0 * st / sw;
  out.covariance = geometry::lineCovariance(l, c, s2 / std::max(st, 1e-9) + 2.0 * f2 / std::max(L2, 1.0), s2 / used + 0.5 * f2);
  return out;
}

// Bilinear sample of the edge channel (edgeChannel(), red-green weight w) of a BGR image at
// (x, y); false outside.
bool edgeAt(cv::Mat const& bgr, double x, double y, float w, float* out, float* value = nullptr) {
  if (x < 0.0 || y < 0.0 || x >= bgr.cols - 1 || y >= bgr.rows - 1) return false;
  int const x0 = static_cast<int>(x), y0 = static_cast<int>(y);
  float const fx = static_cast<float>(x - x0), fy = static_cast<float>(y - y0);
  std::uint8_t const* p0 = bgr.ptr<std::uint8_t>(y0) + 3 * x0;
  std::uint8_t const* p1 = bgr.ptr<std::uint8_t>(y0 + 1) + 3 * x0;
  float c[3];
  for (int k = 0; k < 3; ++k)
    c[k] = (1 - fy) * ((1 - fx) * p0[k] + fx * p0[k + 3]) + fy * ((1 - fx) * p1[k] + fx * p1[k + 3]);
  *out = edgeChannel(c[0], c[1], c[2], w);
  if (value) *value = std::max(c[0], std::max(c[1], c[2]));
  return true;
}

#if defined(__GNUC__) && defined(__x86_64__)
#define ENDO_GUIDANCE_AVX2_SAMPLER 1
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
                                                      int count, float w, float* out) {
  if (count < 8) {
    for (int i = 0; i < count; ++i) edgeAt(bgr, a.x() + i * d.x(), a.y() + i * d.y(), w, &out[i]);
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
      for (int k = i; k < i + 8; ++k) edgeAt(bgr, a.x() + k * d.x(), a.y() + k * d.y(), w, &out[k]);
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
    __m256 mx, mn, c[3];
    for (int ch = 0; ch < 3; ++ch) {
      __m256 const v = _mm256_add_ps(
          _mm256_mul_ps(ofy, _mm256_add_ps(_mm256_mul_ps(ofx, channel(q00, ch, mask)), _mm256_mul_ps(fx, channel(q01, ch, mask)))),
          _mm256_mul_ps(fy, _mm256_add_ps(_mm256_mul_ps(ofx, channel(q10, ch, mask)), _mm256_mul_ps(fx, channel(q11, ch, mask)))));
      c[ch] = v;
      mx = ch == 0 ? v : _mm256_max_ps(mx, v);
      mn = ch == 0 ? v : _mm256_min_ps(mn, v);
    }
    // edgeChannel(), its operations in its order.
    __m256 const e = _mm256_add_ps(_mm256_mul_ps(_mm256_set1_ps(1.f - w), _mm256_sub_ps(mx, mn)),
                                   _mm256_mul_ps(_mm256_set1_ps(w * kRedGreenScale), _mm256_sub_ps(c[2], c[1])));
    _mm256_storeu_ps(out + i, e);
  }
}
#endif

// The edge channel at a + i d, i = 0..count-1, bilinear, all inside the image (edgeAt() without the
// bounds test and the brightness: the inner loop of the sub-pixel refinement). One sample per
// SIMD step with the channels in the lanes: each corner is one 4-byte load (B, G, R and the next
// pixel's B, unused), interpolated with the same operations, in the same order, as edgeAt(), so
// the results are identical. A sample whose 4-byte load would pass the end of its row (the last
// two columns) takes edgeAt(). On a CPU with AVX2 (and OpenCV's optimisations on:
// cv::setUseOptimized()), eight samples per step (sampleEdgeChannelAvx2()), the same results. perf on
// a 640x480 frame: the sampler's share 14 % with two samples per step, 11 % with eight.
void sampleEdgeChannel(cv::Mat const& bgr, Eigen::Vector2d const& a, Eigen::Vector2d const& d, int count, float w, float* out) {
#ifdef ENDO_GUIDANCE_AVX2_SAMPLER
  if (cv::checkHardwareSupport(CV_CPU_AVX2)) return sampleEdgeChannelAvx2(bgr, a, d, count, w, out);
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
      edgeAt(bgr, x, y, w, &out[i]);
      continue;
    }
    cv::v_float32x4 const fx = cv::v_setall_f32(static_cast<float>(x - x0)), fy = cv::v_setall_f32(static_cast<float>(y - y0));
    std::uint8_t const* p0 = data + y0 * stride + 3 * x0;
    std::uint8_t const* p1 = p0 + stride;
    cv::v_float32x4 const c = (one - fy) * ((one - fx) * corner(p0) + fx * corner(p0 + 3)) +
                              fy * ((one - fx) * corner(p1) + fx * corner(p1 + 3));  // B, G, R, -
    cv::v_float32x4 const c1 = cv::v_rotate_right<1>(c), c2 = cv::v_rotate_right<2>(c);  // G, R, ... and R, ...
    float const chroma = (cv::v_max(c, cv::v_max(c1, c2)) - cv::v_min(c, cv::v_min(c1, c2))).get0();
    out[i] = (1.f - w) * chroma + (w * kRedGreenScale) * (c2.get0() - c1.get0());  // edgeChannel()
  }
}

// Sub-pixel position (in samples) of the steepest descent of a profile (tissue at index 0, shaft
// at the end): the centroid of the slope about its peak, within +-2.5 px -- exact for a
// box-filtered (anti-aliased) step under bilinear sampling and unbiased for any symmetric blur,
// whereas a parabola on the peak, or weights cut at a fraction of it, is biased by up to 0.15 px
// on sharp edges (the slope of such a step is a two-level staircase). `lobe_floor` >= 0: only the
// contiguous lobe of the peak whose slope stays above lobe_floor times the peak counts (whole
// samples, uncut), not the slope of textured tissue further in the window, which counts only
// where it descends (ascents weigh nothing) and so pulls the edge outward (test
// SubpixelEdgeIsNotPulledByTheTissueTexture; rendered clean scene 0.013 -> 0.007 px); < 0:
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

std::optional<RobustLine> fitLineLMedS(std::vector<Eigen::Vector2d> const& pts, int samples, std::uint64_t seed) {
  int const n = static_cast<int>(pts.size());
  if (n < 2) return std::nullopt;
  std::mt19937_64 rng(seed);
  std::uniform_int_distribution<int> pick(0, n - 1);
  std::vector<double> r(static_cast<std::size_t>(n));
  double best = std::numeric_limits<double>::infinity();
  Eigen::Vector3d bl = Eigen::Vector3d::Zero();
  int const k = n / 2;
  for (int s = 0; s < samples; ++s) {
    int const i = pick(rng), j = pick(rng);
    Eigen::Vector2d const d = pts[j] - pts[i];
    double const len = d.norm();
    if (len < 2.0) continue;
    Eigen::Vector2d const nrm(-d.y() / len, d.x() / len);
    double const c = -nrm.dot(pts[i]);
    int below = 0;  // residuals under the best median so far: at most k, and this line cannot beat it
    for (int m = 0; m < n; ++m) {
      double const e = nrm.dot(pts[m]) + c;
      r[m] = e * e;
      below += r[m] < best;
    }
    if (below <= k) continue;
    std::nth_element(r.begin(), r.begin() + k, r.end());
    if (r[k] < best) {
      best = r[k];
      bl = Eigen::Vector3d(nrm.x(), nrm.y(), c);
    }
  }
  if (!std::isfinite(best)) return std::nullopt;
  RobustLine out;
  out.sigma = 1.4826 * (1.0 + 5.0 / std::max(1, n - 2)) * std::sqrt(best);
  double const thr = std::max(2.5 * out.sigma, 1.0);
  std::vector<Eigen::Vector2d> in;
  for (int m = 0; m < n; ++m)
    if (std::abs(bl.head<2>().dot(pts[m]) + bl.z()) <= thr) {
      out.inliers.push_back(m);
      in.push_back(pts[m]);
    }
  auto const ls = in.size() >= 2 ? fitLineLS(in) : std::nullopt;
  out.line = ls ? *ls : bl;
  return out;
}

namespace {

// Sub-pixel edge points on profiles across a line, one at a time (the buffers of a profile are
// reused).
class EdgeProfiler {
 public:
  EdgeProfiler(cv::Mat const& bgr, ContourLinesParams const& p)
      : bgr_(bgr), p_(p), h_(p.refine_halfwidth_px), ds_(p.profile_step_px),
        ns_(static_cast<int>(std::lround(2.0 * h_ / ds_)) + 1), prof_(static_cast<std::size_t>(ns_)),
        val_(static_cast<std::size_t>(ns_)), need_value_(p.brightness_fallback_contrast > 0.0),
        w_(static_cast<float>(p.edge_red_green_weight)) {}

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
    if (need_value_) {
      for (int i = 0; i < ns_; ++i) {
        Eigen::Vector2d const q = base + (-h_ + i * ds_) * n;
        edgeAt(bgr_, q.x(), q.y(), w_, &prof_[i], &val_[i]);
      }
    } else {
      sampleEdgeChannel(bgr_, a, ds_ * n, ns_, w_, prof_.data());
    }
    // The edge is located in the edge channel (chroma, with the red-green term if set), where
    // the shaded rim of a grey shaft does not bias it (metal mirrors tissue colours, so it is the
    // steepest descent, not the first seen from inside --
    // the latter doubled the in-vivo line error). A black shaft against pale tissue may have too
    // little chroma contrast: then its drop in brightness is used.
    auto at = steepestDescent(prof_, ds_, p_.min_edge_contrast * 2.0 * ds_, p_.edge_lobe_floor);
    if (!at && need_value_) at = steepestDescent(val_, ds_, p_.brightness_fallback_contrast * 2.0 * ds_, p_.edge_lobe_floor);
    if (!at) return std::nullopt;
    return Eigen::Vector2d(base + (-h_ + *at * ds_) * n);
  }

 private:
  cv::Mat const& bgr_;
  ContourLinesParams const& p_;
  double const h_, ds_;
  int const ns_;
  std::vector<float> prof_, val_;
  bool const need_value_;
  float const w_;  // edgeChannel()'s red-green weight
};

// The sub-pixel edge points of refineLineSubpixel(): one per profile with an edge steeper than
// min_edge_contrast, at t = t0 + j refine_step_px up to t1. `reuse`: profiles taken with the same
// parameters at t0 + i step (step a multiple of refine_step_px), used where the line and t0 are
// exactly the same; `record`: where to keep every profile's edge.
std::vector<Eigen::Vector2d> subpixelEdgePoints(cv::Mat const& bgr, geometry::ImageLine const& line, double t0, double t1,
                                               ContourLinesParams const& p, ProfileEdges const* reuse = nullptr,
                                               ProfileEdges* record = nullptr) {
  EdgeProfiler profiler(bgr, p);
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
  wide.edge_lobe_floor = -1.0;  // it recentres and scores: the whole window (the lobe alone there: robotic Dataset 1 -4 shafts)
  return wide;
}

namespace {

// The robust line through sub-pixel edge points (Tukey biweight, scale from the MAD, three
// passes), oriented like `line` (shaft on the positive side), with its covariance.
std::optional<RefinedLine> robustEdgeLine(std::vector<Eigen::Vector2d> const& pts, geometry::ImageLine const& line, ContourLinesParams const& p) {
  Eigen::Vector2d const n = line.head<2>();
  if (static_cast<int>(pts.size()) < p.min_edge_points) return std::nullopt;
  // Robust LS: Tukey biweight, scale from the MAD, three passes.
  std::vector<double> w(pts.size(), 1.0), r(pts.size()), rr(pts.size());
  Eigen::Vector3d l = line;
  for (int it = 0; it < 3; ++it) {
    auto const f = fitLineLS(pts, &w);
    if (!f) return std::nullopt;
    l = *f;
    for (std::size_t i = 0; i < pts.size(); ++i) r[i] = std::abs(l.head<2>().dot(pts[i]) + l.z());
    std::copy(r.begin(), r.end(), rr.begin());
    std::nth_element(rr.begin(), rr.begin() + rr.size() / 2, rr.end());
    double const sc = std::max(1.4826 * rr[rr.size() / 2], 0.05);
    for (std::size_t i = 0; i < pts.size(); ++i) {
      double const u = r[i] / (4.685 * sc);
      w[i] = u < 1.0 ? (1 - u * u) * (1 - u * u) : 0.0;
    }
  }
  if (l.head<2>().dot(n) < 0.0) l = -l;  // keep the shaft on the positive side
  return summarizeLine(l, pts, w, p.min_edge_points, p.line_sigma_floor_px);
}

}  // namespace

std::optional<RefinedLine> refineLineSubpixel(cv::Mat const& bgr, geometry::ImageLine const& line, double t0, double t1,
                                              ContourLinesParams const& p) {
  return robustEdgeLine(subpixelEdgePoints(bgr, line, t0, t1, p), line, p);
}

namespace {
// refineLineSubpixel() reusing or recording profiles (subpixelEdgePoints()).
std::optional<RefinedLine> refineLineProfiles(cv::Mat const& bgr, geometry::ImageLine const& line, double t0, double t1, ContourLinesParams const& p,
                                              ProfileEdges const* reuse, ProfileEdges* record) {
  return robustEdgeLine(subpixelEdgePoints(bgr, line, t0, t1, p, reuse, record), line, p);
}
}  // namespace

std::optional<RefinedLine> extendLineSubpixel(cv::Mat const& bgr, RefinedLine const& refined, double t0, double t1,
                                              double t_lo, double t_hi, ContourLinesParams const& p) {
  if (p.extend_max_misses <= 0 || refined.inliers.empty()) return std::nullopt;
  geometry::ImageLine l = refined.line;
  std::vector<Eigen::Vector2d> pts = refined.inliers;
  // An edge point continues the line within 3 of its residuals (at least gate_min px).
  double const gate = std::max(3.0 * refined.residual_px, p.extend_gate_px);
  std::size_t const before = pts.size();
  EdgeProfiler profiler(bgr, p);
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
          // Follow the line as it gets longer (its direction improves with the baseline).
          if (++added % 16 == 0)
            if (auto const f = robustEdgeLine(pts, l, p)) l = f->line;
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
#ifdef ENDO_GUIDANCE_AVX2_SAMPLER
// Four points per step (AVX2 without FMA: the same roundings as the scalar loop). perf on the
// EndoVis robotic videos: this count was 16 % of a frame's samples (re-sought sides of regions
// that leaked: straightRun() over boundaries of thousands of points, 120-240 lines each).
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
#ifdef ENDO_GUIDANCE_AVX2_SAMPLER
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

SideFit fitSidesFrom(SideChains const& sc, Region const& region, FieldOfView const& fov, int scale, ContourLinesParams const& p,
                     SideSearch search) {
  SideFit fit;
  auto const& B = region.boundary;
  int const n = static_cast<int>(B.size());
  auto const& border = sc.border;
  auto const& chain = sc.chain;
  auto const& fwd = sc.fwd;
  fit.merged = sc.merged;
  auto reject = [&](ContourRejection r) {
    fit.rejection = r;
    return fit;
  };
  // Each side followed from the entry ([Doignon07]'s two classes). A region merged with a grey
  // blob near the entry (gauze) has one side that is not a straight line from there: that side
  // is then the straight stretch of its chain, up to the point farthest from the seed, that
  // runs parallel beside the other side (parallelSide()); the pair is marked `parallel`.
  auto toFull = [&](Eigen::Vector2d const& q) { return toFullRes(q, scale); };
  double const cos_max = std::cos(p.max_angle_deg * M_PI / 180.0);
  // The pair's lines (full resolution) if parallel enough; else the reason.
  auto pairUp = [&](FollowedSide const& a, FollowedSide const& b) -> ContourRejection {
    std::array<std::vector<Eigen::Vector2d>, 2> pts;
    std::array<Eigen::Vector3d, 2> lines;
    FollowedSide const* sides[2] = {&a, &b};
    for (int s = 0; s < 2; ++s) {
      for (auto const& q : sides[s]->points) pts[s].push_back(toFull(q));
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
  };
  ContourRejection why = ContourRejection::kNone;
  for (int s = 0; s < 2 && why == ContourRejection::kNone; ++s)
    if (!fwd[s])
      why = static_cast<int>(chain[s].size()) < p.min_side_points ? ContourRejection::kTooFewPoints : ContourRejection::kNotStraight;
  // Re-sought: the pair from the entry (if any) had no edges; the sides are sought again below.
  bool const resought = search != SideSearch::kFromEntry;
  if (resought) why = ContourRejection::kNotStraight;
  if (why == ContourRejection::kNone) why = pairUp(*fwd[0], *fwd[1]);
  if (search == SideSearch::kStretchPair) {
    // The whole boundary, in its pieces between the stretches on the FOV border: where the
    // region meets the border more than once, the shaft's far side can lie on a piece that
    // leaves the view at neither end of the entry run (between a blob's and another
    // instrument's border runs).
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
    auto const pair = stretchPair(pieces, Eigen::Vector2d(region.seed.x, region.seed.y), p, p.seed + 5);
    if (pair && pairUp((*pair)[0], (*pair)[1]) == ContourRejection::kNone) {
      fit.parallel = true;
      why = ContourRejection::kNone;
    }
  }
  int const only = search == SideSearch::kParallelFirst ? 0 : search == SideSearch::kParallelSecond ? 1 : -1;
  if (why != ContourRejection::kNone && p.min_parallel_side_ratio > 0.0 && search != SideSearch::kStretchPair) {
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
        // A region that meets the border again (the blob reaches it): this side's chain ends
        // there, and the shaft's side beyond the blob is on the other chain, after the other
        // side's end (around the tip and back): walked from the border, off the other side's
        // line. The other side's points beyond the gap where following it stopped (noise, an
        // instrument crossing it) are added to it.
        Eigen::Vector3d const o = other.line;
        for (int i = static_cast<int>(chain[1 - s].size()) - 1; i >= fwd[1 - s]->traversed; --i) {
          double const d = std::abs(o.head<2>().dot(chain[1 - s][i]) + o.z());
          if (d > 1.5) head.push_back(chain[1 - s][i]);
          else if (d <= 1.0) other.points.push_back(chain[1 - s][i]);
        }
        if (auto const l = fitLineLS(other.points)) other.line = *l;
      }
      auto const side = parallelSide(head, other, p, p.seed + 2 + s);
      if (side && pairUp(s == 0 ? *side : other, s == 0 ? other : *side) == ContourRejection::kNone) {
        fit.parallel = true;
        why = ContourRejection::kNone;
        break;
      }
    }
  }
  if (why != ContourRejection::kNone) return reject(why);
  fit.entry = toFull(Eigen::Vector2d(region.seed.x, region.seed.y));
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
  SideFit fit = fitSidesFrom(*sc, region, fov, scale, p, search);
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
    out.push_back(fitSidesFrom(*sc, region, fov, scale, p, s));
    out.back().chains = sc;
  }
  return out;
}

namespace {
// The steepest crossing of the view's border by the contour's axis or either line, as the sine
// of its angle with the border (the inward unit normal dotted with axis_dir, the direction into
// the view): each line is followed back from its foot of `entry` to where it leaves the view,
// within two widths (w_proc, processing px); the axis falls back to the entry itself.
double enteringSine(geometry::ApparentContour const& c, FieldOfView const& fov, Eigen::Vector2d const& entry,
                    Eigen::Vector2d const& axis_dir, double w_proc, int scale) {
  int const kmax = static_cast<int>(std::ceil(std::max(10.0, 2.0 * w_proc)));
  double best = -1.0;
  for (int k = 0; k < 3; ++k) {
    geometry::ImageLine const l = k == 0 ? geometry::imageAxis(c) : c.lines[static_cast<std::size_t>(k - 1)];
    Eigen::Vector2d d(-l.y(), l.x());
    if (k == 0 || d.norm() < 1e-12) d = axis_dir;
    d.normalize();
    if (d.dot(axis_dir) < 0.0) d = -d;
    std::optional<Eigen::Vector2d> q = walkToEdge(fov, toProcessing(geometry::footOnLine(l, entry), scale), d, kmax);
    if (!q) {
      if (k > 0) continue;  // a line that never meets the view near the entry crosses no border there
      q = toProcessing(entry, scale);  // no exit found: the seed
    }
    Eigen::Vector2d const g =
        depthGradient(fov, cv::Point(static_cast<int>(std::lround(q->x())), static_cast<int>(std::lround(q->y()))));
    if (g.norm() <= 1e-6) return 1.0;  // no border in reach: nothing to run along
    best = std::max(best, g.normalized().dot(axis_dir));
  }
  return best;
}
}  // namespace

ContourFit refineContour(SideFit const& sides, Region const& region, FieldOfView const& fov, cv::Mat const& bgr,
                         int scale, ContourLinesParams const& p) {
  ContourFit fit;
  auto reject = [&](ContourRejection r) {
    fit.rejection = r;
    return fit;
  };
  if (sides.rejection != ContourRejection::kNone) return reject(sides.rejection);
  auto const& coarse = sides.lines;
  auto const& full = sides.points;
  Eigen::Vector2d const entry = sides.entry, far = sides.far;
  auto const& B = region.boundary;
  // Sub-pixel refinement on the full-resolution image, over the extent of the side's inliers
  // (2 px in from each end).
  RefinedLine ref[2];
  for (int s = 0; s < 2; ++s) {
    Eigen::Vector2d const d(-coarse[s].y(), coarse[s].x());
    double t0 = std::numeric_limits<double>::infinity(), t1 = -t0;
    for (auto const& q : full[s]) {
      t0 = std::min(t0, d.dot(q));
      t1 = std::max(t1, d.dot(q));
    }
    // Two passes: a wide search (the region boundary can sit several px inside the shaft's
    // shaded rim), then a narrow one around the refitted line.
    ContourLinesParams wide = widePass(p);
    // (every profile: sparser recentring cost 5 points of in-vivo recall)
    wide.max_residual_px = 1e9;
    auto const r0 = refineLineProfiles(bgr, coarse[s], t0 + 2.0, t1 - 2.0, wide, &sides.scored[s], nullptr);
    if (!r0) return reject(ContourRejection::kWeakEdges);
    auto r = refineLineSubpixel(bgr, r0->line, t0 + 2.0, t1 - 2.0, p);
    if (!r) return reject(ContourRejection::kWeakEdges);
    if (r->residual_px > p.max_residual_px) return reject(ContourRejection::kResidual);
    // The region's side can stop short of the shaft's edge (a highlight, noise, JPEG, a
    // touching blob): the edge is followed along the refined line, back to the entry and on
    // until it ends (the image bounds it), and the line refitted over it all: a longer baseline,
    // a better direction (hard scene: line p95 0.473 -> 0.442 px, direction 1.03 -> 0.91 deg).
    {
      Eigen::Vector2d const dr(-r->line.y(), r->line.x());
      double const te = dr.dot(geometry::footOnLine(r->line, entry)), tf = dr.dot(geometry::footOnLine(r->line, far));
      double const inf = std::numeric_limits<double>::infinity();
      if (auto const x = extendLineSubpixel(bgr, *r, t0 + 2.0, t1 - 2.0, tf > te ? te : -inf, tf > te ? inf : te, p)) r = x;
    }
    ref[s] = *r;
    fit.edge_points += r->points;
  }
  // Order: lines[0] on the left walking from the entry toward the tip (v down).
  Eigen::Vector2d axis_dir(-(ref[0].line.y() - ref[1].line.y()), ref[0].line.x() - ref[1].line.x());
  if (axis_dir.norm() < 1e-9) return reject(ContourRejection::kCrossing);
  axis_dir.normalize();
  if (axis_dir.dot(far - entry) < 0.0) axis_dir = -axis_dir;
  Eigen::Vector2d const left(axis_dir.y(), -axis_dir.x());
  int const L = ref[0].line.head<2>().dot(left) < 0.0 ? 0 : 1;  // normal pointing right: left line
  if (!(ref[L].line.head<2>().dot(left) < 0.0 && ref[1 - L].line.head<2>().dot(left) > 0.0))
    return reject(ContourRejection::kCrossing);
  geometry::ApparentContour c;
  c.lines = {ref[L].line, ref[1 - L].line};
  c.line_covariances = {ref[L].covariance, ref[1 - L].covariance};
  c.line_residual_px = {ref[L].residual_px, ref[1 - L].residual_px};
  fit.edges = {ref[L].inliers, ref[1 - L].inliers};
  c.residual_px = std::sqrt(0.5 * (ref[0].residual_px * ref[0].residual_px + ref[1].residual_px * ref[1].residual_px));
  // Tip: the region point farthest from the entry along the axis, among those inside the strip
  // between the lines (not the jaws' spread, nor a touching instrument beyond the tip).
  // Beyond the end of the straight sides only the jaws may follow (up to 2.5 widths), not a
  // gauze or tissue blob that the region ran into.
  double t_sides = 0.0;
  for (int s = 0; s < 2; ++s)
    for (auto const& q : full[s]) t_sides = std::max(t_sides, axis_dir.dot(q - entry));
  Eigen::Vector2d const end = entry + t_sides * axis_dir;
  double const end_width = c.lines[0].dot(Eigen::Vector3d(end.x(), end.y(), 1.0)) + c.lines[1].dot(Eigen::Vector3d(end.x(), end.y(), 1.0));
  double const t_limit = t_sides + 2.5 * std::max(end_width, 2.0 * scale);
  double best = -1e300;
  Eigen::Vector2d tip = end;
  for (auto const& q : B) {
    Eigen::Vector2d const x = toFullRes(Eigen::Vector2d(q.x, q.y), scale);
    Eigen::Vector3d const xh(x.x(), x.y(), 1.0);
    if (c.lines[0].dot(xh) < -scale || c.lines[1].dot(xh) < -scale) continue;
    double const t = axis_dir.dot(x - entry);
    if (t > t_limit) continue;
    if (t > best) {
      best = t;
      tip = x;
    }
  }
  c.entry_px = entry;
  c.tip_px = tip;
  if ((tip - entry).norm() < p.min_length_px) return reject(ContourRejection::kTooShort);
  // Width where the shaft is seen: sum of the signed distances at entry and tip (both positive inside).
  double width_at[2];
  for (int k = 0; k < 2; ++k) {
    Eigen::Vector3d const x = (k == 0 ? entry : tip).homogeneous();
    width_at[k] = c.lines[0].dot(x) + c.lines[1].dot(x);
    if (width_at[k] < p.min_width_px) return reject(ContourRejection::kTooThin);
  }
  if (p.max_widening > 0.0 && width_at[1] > p.max_widening * width_at[0]) return reject(ContourRejection::kWidens);
  // A shaft enters the view across its border: its direction (entry -> tip) must point inward,
  // not along the border (the inward normal is the gradient of the distance to the FOV edge).
  // The normal is taken where the axis itself leaves the view: near a corner the seed can lie on
  // the other border than the one the shaft crosses (a shaft entering from the side close to
  // the bottom seeds on the bottom). The exit is searched within two widths of the entry, so a
  // band along the border (vignetted rim) still meets the border it runs along.
  // A shaft that enters through a corner crosses two borders: its axis can meet one at a grazing
  // angle while a contour line crosses the other squarely (hard scene frames 11 and 234). It
  // enters if its axis or either line crosses the border steeply enough; a band along one border
  // has all three along it.
  if (enteringSine(c, fov, entry, axis_dir, std::max(1.0, width_at[0] / scale), scale) < p.min_entry_sine)
    return reject(ContourRejection::kAlongBorder);
  // Shape: a shaft region fills the strip between its lines and stays inside it, and the strip
  // is elongated. Tissue blobs that happen to have two straight-ish sides fail here.
  {
    double const len = (tip - entry).norm();
    double const width = 0.5 * (width_at[0] + width_at[1]);
    if (len < p.min_elongation * width) return reject(ContourRejection::kNotElongated);
    // Rasterise at processing scale over the region's box (plus margin).
    cv::Rect const box = region.box + cv::Size(4, 4) - cv::Point(2, 2);
    cv::Mat reg = cv::Mat::zeros(box.size(), CV_8U), quad = cv::Mat::zeros(box.size(), CV_8U);
    std::vector<std::vector<cv::Point>> poly{region.boundary};
    cv::fillPoly(reg, poly, 255, cv::LINE_8, 0, -box.tl());
    std::vector<cv::Point> q;
    for (Eigen::Vector2d const& foot : geometry::shaftQuad(c, entry, tip)) {
      Eigen::Vector2d const ps = toProcessing(foot, scale);
      q.emplace_back(static_cast<int>(std::lround(ps.x())) - box.x, static_cast<int>(std::lround(ps.y())) - box.y);
    }
    cv::fillConvexPoly(quad, q, 255);
    // The nearby slab: the same axial extent, four widths to each side. Region pixels beyond the
    // tip or far to the side (a touching or crossing instrument) do not count against the shaft.
    cv::Mat slab = cv::Mat::zeros(box.size(), CV_8U);
    {
      Eigen::Vector2d const nrm(-axis_dir.y(), axis_dir.x());
      double const half = 4.0 * width + 4.0 * scale;
      std::vector<cv::Point> sp;
      std::array<Eigen::Vector2d, 4> const corners{Eigen::Vector2d(entry + nrm * half), Eigen::Vector2d(tip + nrm * half),
                                                    Eigen::Vector2d(tip - nrm * half), Eigen::Vector2d(entry - nrm * half)};
      for (Eigen::Vector2d const& e : corners) {
        Eigen::Vector2d const ps = toProcessing(e, scale);
        sp.emplace_back(static_cast<int>(std::lround(ps.x())) - box.x, static_cast<int>(std::lround(ps.y())) - box.y);
      }
      cv::fillConvexPoly(slab, sp, 255);
    }
    double const nq = cv::countNonZero(quad), nr = cv::countNonZero(reg & slab), both = cv::countNonZero(quad & reg);
    // A region merged with a crossing or touching instrument has that instrument's pixels near
    // the strip too, and one with a side found as the parallel stretch the blob beside it: only
    // the fill of the strip is required then (hard scene 87.2 -> 90.0 % found with the latter).
    double const inside = sides.merged || sides.parallel ? p.min_inside_merged : p.min_inside;
    if (nq <= 0 || nr <= 0 || both < p.min_fill * nq || both < inside * nr) return reject(ContourRejection::kNotFilled);
  }
  fit.contour = c;
  return fit;
}

double scoreSides(SideFit& sides, cv::Mat const& bgr, ContourLinesParams const& p) {
  if (sides.rejection != ContourRejection::kNone) return -1.0;
  ContourLinesParams wide = widePass(p);
  wide.refine_step_px = p.score_step_px;
  wide.min_edge_points = std::max(3, p.min_edge_points / 3);
  double score = 0.0;
  for (int s = 0; s < 2; ++s) {
    Eigen::Vector2d const d(-sides.lines[s].y(), sides.lines[s].x());
    double t0 = std::numeric_limits<double>::infinity(), t1 = -t0;
    for (auto const& q : sides.points[s]) {
      t0 = std::min(t0, d.dot(q));
      t1 = std::max(t1, d.dot(q));
    }
    auto const r = refineLineProfiles(bgr, sides.lines[s], t0 + 2.0, t1 - 2.0, wide, nullptr, &sides.scored[s]);
    if (!r) return -1.0;
    score += r->points / (1.0 + r->residual_px);
  }
  return score;
}

ContourFit fitApparentContour(Region const& region, FieldOfView const& fov, cv::Mat const& bgr, int scale,
                              ContourLinesParams const& p) {
  return refineContour(fitSides(region, fov, scale, p), region, fov, bgr, scale, p);
}

std::optional<geometry::ApparentContour> rectifyContour(geometry::ApparentContour const& contour,
                                              std::array<std::vector<Eigen::Vector2d>, 2> const& edges,
                                              std::function<Eigen::Vector2d(Eigen::Vector2d const&)> const& rectify,
                                              int min_points, double sigma_floor_px) {
  geometry::ApparentContour out = contour;
  out.entry_px = rectify(contour.entry_px);
  out.tip_px = rectify(contour.tip_px);
  // A point inside the shaft (between the lines, half-way along): it stays inside after the
  // mapping and orients the refitted lines.
  Eigen::Vector2d const mid = 0.5 * (contour.entry_px + contour.tip_px);
  Eigen::Vector2d const inside = rectify(0.5 * (geometry::footOnLine(contour.lines[0], mid) + geometry::footOnLine(contour.lines[1], mid)));
  for (int s = 0; s < 2; ++s) {
    std::vector<Eigen::Vector2d> pts;
    pts.reserve(edges[s].size());
    for (auto const& q : edges[s]) {
      Eigen::Vector2d const r = rectify(q);
      if (r.allFinite()) pts.push_back(r);
    }
    if (static_cast<int>(pts.size()) < min_points) return std::nullopt;
    auto l = fitLineLS(pts);
    if (!l) return std::nullopt;
    if (l->head<2>().dot(inside) + l->z() < 0.0) *l = -*l;
    auto const r = summarizeLine(*l, pts, std::vector<double>(pts.size(), 1.0), min_points, sigma_floor_px);
    if (!r) return std::nullopt;
    out.lines[s] = r->line;
    out.line_covariances[s] = r->covariance;
    out.line_residual_px[s] = r->residual_px;
  }
  out.residual_px = std::sqrt(0.5 * (out.line_residual_px[0] * out.line_residual_px[0] +
                                     out.line_residual_px[1] * out.line_residual_px[1]));
  Eigen::Vector3d const in(inside.x(), inside.y(), 1.0);
  if (!(out.lines[0].dot(in) > 0.0 && out.lines[1].dot(in) > 0.0)) return std::nullopt;
  return out;
}

AcrossSamples acrossContour(cv::Mat const& bgr, geometry::ApparentContour const& c, float w) {
  CV_Assert(bgr.type() == CV_8UC3);
  AcrossSamples s;
  Eigen::Vector2d const e = c.entry_px, ax = c.tip_px - c.entry_px;
  auto at = [&](Eigen::Vector2d const& q, std::vector<float>& v, bool inside) {
    int const x = static_cast<int>(std::lround(q.x())), y = static_cast<int>(std::lround(q.y()));
    if (x < 0 || y < 0 || x >= bgr.cols || y >= bgr.rows) return;
    cv::Vec3b const& px = bgr.at<cv::Vec3b>(y, x);
    v.push_back(edgeChannel(px[0], px[1], px[2], w));
    if (inside && std::max({px[0], px[1], px[2]}) >= 230 && ColourFeature::chroma(px[0], px[1], px[2]) < 30.f) ++s.glare;
  };
  for (int i = 1; i < 40; ++i) {
    Eigen::Vector2d const m = e + (i / 40.0) * ax;
    Eigen::Vector2d const f0 = geometry::footOnLine(c.lines[0], m), f1 = geometry::footOnLine(c.lines[1], m);
    double const d = std::max(3.0, 0.3 * (f1 - f0).norm());
    for (double f : {0.25, 0.5, 0.75}) at(f0 + f * (f1 - f0), s.inside, true);
    at(f0 - d * c.lines[0].head<2>(), s.outside[0], false);  // the normals point into the shaft
    at(f1 - d * c.lines[1].head<2>(), s.outside[1], false);
  }
  return s;
}

bool mostlyGlare(AcrossSamples const& s, ContourLinesParams const& p) {
  return !s.inside.empty() && s.glare > p.max_glare_fraction * static_cast<double>(s.inside.size());
}

bool mostlyGlare(cv::Mat const& bgr, geometry::ApparentContour const& contour, ContourLinesParams const& p) {
  return mostlyGlare(acrossContour(bgr, contour, static_cast<float>(p.edge_red_green_weight)), p);
}

}  // namespace endo_guidance::perception
