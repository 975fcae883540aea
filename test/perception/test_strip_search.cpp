// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The strip search (sides of a shaft searched from a border seed in the feature gradient), on
// drawn feature images with exact sides, and inside the segmentation on a shaft whose grown
// region leaks into a grey membrane along the border.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>
#include <random>

#include "endo_guidance/perception/colour_feature.h"
#include "endo_guidance/perception/segmentation.h"
#include "endo_guidance/perception/strip_search.h"

#include "colour_params.h"

using namespace endo_guidance::perception;
using namespace endo_guidance::geometry;
using endo_guidance::test::colourParams;

namespace {

// Distance of the line l (full-res, normalised) to the point q.
double dist(Eigen::Vector3d const& l, Eigen::Vector2d const& q) { return std::abs(l.head<2>().dot(q) + l.z()); }

struct Drawn {
  cv::Mat feature, gx, gy;
  FieldOfView fov;
  std::vector<Seed> seeds;
};

// A 320x240 feature image: tissue at 120, the polygon at 10, lightly blurred (as the Sigma
// filter leaves an edge); the full rectangle as the field of view.
Drawn draw(std::vector<cv::Point2d> const& poly) {
  Drawn d;
  d.feature = cv::Mat(240, 320, CV_8U, cv::Scalar(120));
  std::vector<cv::Point> p;
  for (auto const& q : poly) p.emplace_back(static_cast<int>(std::lround(q.x * 16)), static_cast<int>(std::lround(q.y * 16)));
  if (!p.empty()) cv::fillPoly(d.feature, std::vector<std::vector<cv::Point>>{p}, cv::Scalar(10), cv::LINE_AA, 4);
  cv::GaussianBlur(d.feature, d.feature, cv::Size(3, 3), 0.7);
  d.fov = detectFieldOfView(cv::Mat(240, 320, CV_8UC3, cv::Scalar(60, 80, 190)));
  cv::Sobel(d.feature, d.gx, CV_16S, 1, 0, 3);
  cv::Sobel(d.feature, d.gy, CV_16S, 0, 1, 3);
  d.seeds = findSeeds(d.feature, d.fov);
  return d;
}

// Lines through two points.
Eigen::Vector3d lineThrough(cv::Point2d a, cv::Point2d b) {
  Eigen::Vector3d l = Eigen::Vector3d(a.x, a.y, 1).cross(Eigen::Vector3d(b.x, b.y, 1));
  return l / l.head<2>().norm();
}

// Fills a polygon (pixel centres at integer coordinates) with exact area coverage: drawn 8x
// supersampled (supersampled pixel J covers [J/8 - 1/2, (J+1)/8 - 1/2)) and box-averaged.
void fillExact(cv::Mat& img, std::vector<cv::Point2d> const& poly, cv::Scalar const& colour) {
  int const f = 8;
  cv::Mat big = cv::Mat::zeros(img.rows * f, img.cols * f, CV_8U);
  std::vector<cv::Point> p;
  for (auto const& q : poly)
    p.emplace_back(static_cast<int>(std::lround((f * (q.x + 0.5) - 0.5) * 16)), static_cast<int>(std::lround((f * (q.y + 0.5) - 0.5) * 16)));
  cv::fillPoly(big, std::vector<std::vector<cv::Point>>{p}, cv::Scalar(255), cv::LINE_8, 4);
  cv::Mat cover;
  cv::resize(big, cover, img.size(), 0, 0, cv::INTER_AREA);
  for (int y = 0; y < img.rows; ++y)
    for (int x = 0; x < img.cols; ++x) {
      double const a = cover.at<std::uint8_t>(y, x) / 255.0;
      auto& px = img.at<cv::Vec3b>(y, x);
      for (int k = 0; k < 3; ++k) px[k] = cv::saturate_cast<std::uint8_t>((1 - a) * px[k] + a * colour[k]);
    }
}

}  // namespace

TEST(StripSearch, FindsTheSidesOfAStripFromItsSeed) {
  // A shaft entering across the left border, narrowing slightly (perspective).
  cv::Point2d const a0(0, 100), a1(250, 140), b1(250, 162), b0(0, 128);
  Drawn const d = draw({a0, a1, b1, b0});
  ASSERT_EQ(d.seeds.size(), 1u);
  StripSearchParams const p;
  auto const sc = searchStrip(d.feature, d.gx, d.gy, d.fov, d.seeds[0], 60, 1, p, ContourLinesParams{});
  ASSERT_TRUE(sc.has_value());
  Eigen::Vector3d const la = lineThrough(a0, a1), lb = lineThrough(b0, b1);
  // Each side's sampled points within 2.5 px of one true side: the search is at whole pixels and
  // a strong edge saturates the response over a band about 3 px wide (the sub-pixel pass follows).
  auto onTruth = [&](StripCandidate const& c) {
    for (int s = 0; s < 2; ++s) {
      auto const& pts = c.sides.points[s];
      ASSERT_GT(pts.size(), 150u) << "side " << s << " too short";
      double worst_a = 0, worst_b = 0;
      for (auto const& q : pts) {
        worst_a = std::max(worst_a, dist(la, q));
        worst_b = std::max(worst_b, dist(lb, q));
      }
      EXPECT_LT(std::min(worst_a, worst_b), 2.5) << "side " << s;
    }
  };
  onTruth(*sc);
  // Lines oriented with the shaft on their positive side.
  Eigen::Vector3d const mid(125, 132, 1);
  EXPECT_GT(sc->sides.lines[0].dot(mid), 0.0);
  EXPECT_GT(sc->sides.lines[1].dot(mid), 0.0);

  // Tracked: searched only about the previous sides, the same strip again.
  auto const tr = searchStrip(d.feature, d.gx, d.gy, d.fov, d.seeds[0], 60, 1, p, ContourLinesParams{}, &*sc);
  ASSERT_TRUE(tr.has_value());
  onTruth(*tr);
  for (int s = 0; s < 2; ++s) EXPECT_GT(tr->dir[s].dot(sc->dir[s]), std::cos(1.5 * M_PI / 180.0));
}

void show(std::optional<StripCandidate> const& c) {
  if (!c) return;
  for (int s = 0; s < 2; ++s)
    std::printf("side %d: (%.1f %.1f) -> (%.1f %.1f)\n", s, c->sides.points[s].front().x(), c->sides.points[s].front().y(),
                c->sides.points[s].back().x(), c->sides.points[s].back().y());
}

TEST(StripSearch, RejectsWedgesBlobsAndWeakStrips) {
  StripSearchParams const p;
  ContourLinesParams const lp;
  // Sides 40 degrees apart: not the contours of a cylinder.
  {
    Drawn const d = draw({{0, 60}, {200, 120}, {0, 200}});
    ASSERT_FALSE(d.seeds.empty());
    for (auto const& s : d.seeds) { auto c = searchStrip(d.feature, d.gx, d.gy, d.fov, s, 60, 1, p, lp); show(c); EXPECT_FALSE(c) << "wedge"; }
  }
  // A round blob on the border (a gauze, a pool): no two long straight sides.
  {
    Drawn d = draw({});
    cv::circle(d.feature, {0, 120}, 50, cv::Scalar(10), cv::FILLED, cv::LINE_AA);
    cv::Sobel(d.feature, d.gx, CV_16S, 1, 0, 3);
    cv::Sobel(d.feature, d.gy, CV_16S, 0, 1, 3);
    d.seeds = findSeeds(d.feature, d.fov);
    ASSERT_FALSE(d.seeds.empty());
    for (auto const& s : d.seeds) { auto c = searchStrip(d.feature, d.gx, d.gy, d.fov, s, 60, 1, p, lp); show(c); EXPECT_FALSE(c) << "blob"; }
  }
  // A strip barely darker than the tissue beside it (a fold, a shadow): no contrast.
  {
    Drawn d = draw({});
    std::vector<cv::Point> q{{0, 100 * 16}, {250 * 16, 140 * 16}, {250 * 16, 162 * 16}, {0, 128 * 16}};
    cv::fillPoly(d.feature, std::vector<std::vector<cv::Point>>{q}, cv::Scalar(70), cv::LINE_AA, 4);
    cv::Sobel(d.feature, d.gx, CV_16S, 1, 0, 3);
    cv::Sobel(d.feature, d.gy, CV_16S, 0, 1, 3);
    d.seeds = findSeeds(d.feature, d.fov, SeedSearchParams{75});
    ASSERT_FALSE(d.seeds.empty());
    for (auto const& s : d.seeds) EXPECT_FALSE(searchStrip(d.feature, d.gx, d.gy, d.fov, s, 80, 1, p, lp)) << "low contrast";
    // The same strip at full contrast is found (the case above fails for its contrast only).
    cv::fillPoly(d.feature, std::vector<std::vector<cv::Point>>{q}, cv::Scalar(10), cv::LINE_AA, 4);
    cv::Sobel(d.feature, d.gx, CV_16S, 1, 0, 3);
    cv::Sobel(d.feature, d.gy, CV_16S, 0, 1, 3);
    EXPECT_TRUE(searchStrip(d.feature, d.gx, d.gy, d.fov, d.seeds[0], 80, 1, p, lp));
  }
}

TEST(StripSearch, BadInput) {
  Drawn const d = draw({{0, 100}, {250, 140}, {250, 162}, {0, 128}});
  ASSERT_FALSE(d.seeds.empty());
  cv::Mat gxf;
  d.gx.convertTo(gxf, CV_32F);
  EXPECT_THROW(searchStrip(d.feature, gxf, d.gy, d.fov, d.seeds[0], 60, 1, {}, {}), cv::Exception);
  Seed tiny = d.seeds[0];
  tiny.width = 2;
  EXPECT_FALSE(searchStrip(d.feature, d.gx, d.gy, d.fov, tiny, 60, 1, {}, {}));
  FieldOfView empty = d.fov;
  empty.border.clear();
  EXPECT_FALSE(searchStrip(d.feature, d.gx, d.gy, empty, d.seeds[0], 60, 1, {}, {}));
  // The walks index the gradient and the view's mask with the same coordinates: a float
  // gradient or a mask of another size is refused, not read out of bounds.
  std::vector<StripRay> rays(3);
  for (auto& r : rays) {
    r.start = Eigen::Vector2d(5, 5);
    r.dir = Eigen::Vector2d(1, 0);
    r.out = Eigen::Vector2d(0, 1);
  }
  EXPECT_THROW(walkRays(rays, gxf, d.gy, d.fov, {}), cv::Exception);
  EXPECT_THROW(walkRay(rays[0], gxf, d.gy, d.fov, {}), cv::Exception);
  FieldOfView half = d.fov;
  half.mask = d.fov.mask(cv::Rect(0, 0, 160, 120)).clone();
  EXPECT_THROW(walkRays(rays, d.gx, d.gy, half, {}), cv::Exception);
  EXPECT_NO_THROW(walkRays(rays, d.gx, d.gy, d.fov, {}));
}

namespace {
// A grey shaft entering at the left border (sides from (-5, 200) to (450, 290) and from (-5, 258)
// to (450, 334)) on red tissue, whose grown region runs into a pale grey membrane below it, 20 px
// in from the border: the shaft's border run is its own (a run over both lets no side start at
// the shaft's lower edge). crease > 0: a dark red crease in the tissue along the shaft's upper
// side (as chromatic as the tissue in S.H, less in chroma: 32 against 130), its outer edge
// `crease` px beyond the shaft's, 3 px wide, and darker tissue between them (chroma 65).
struct LeakingShaft {
  cv::Mat img;
  Eigen::Vector3d la, lb;  // the true sides
  // The largest distance of the contour's lines, at u = 60, 250 and 400, to the nearer true side.
  double error(ApparentContour const& c) const {
    double worst = 0.0;
    for (auto const& l : c.lines)
      for (double x : {60.0, 250.0, 400.0}) {
        double const y = -(l.x() * x + l.z()) / l.y();
        worst = std::max(worst, std::min(dist(la, {x, y}), dist(lb, {x, y})));
      }
    return worst;
  }
};
LeakingShaft leakingShaft(std::uint64_t noise_seed, double crease) {
  LeakingShaft s;
  s.img = cv::Mat(480, 640, CV_8UC3, cv::Scalar(70, 90, 200));
  cv::Mat noise(s.img.size(), CV_8UC3);
  cv::RNG(noise_seed).fill(noise, cv::RNG::NORMAL, 0, 3);  // (its own generator: not the tests' order)
  s.img += noise;
  cv::rectangle(s.img, cv::Rect(20, 255, 160, 225), cv::Scalar(150, 150, 158), cv::FILLED);
  cv::Point2d const a0(-5, 200), a1(450, 290), b1(450, 334), b0(-5, 258);
  if (crease > 0.0) {
    Eigen::Vector2d const u = Eigen::Vector2d(a1.x - a0.x, a1.y - a0.y).normalized(), up(u.y(), -u.x());
    auto off = [&](cv::Point2d p, double d) { return cv::Point2d(p.x + d * up.x(), p.y + d * up.y()); };
    fillExact(s.img, {off(a0, crease), off(a1, crease), a1, a0}, cv::Scalar(35, 45, 100));
    fillExact(s.img, {off(a0, crease), off(a1, crease), off(a1, crease - 3), off(a0, crease - 3)}, cv::Scalar(8, 10, 40));
  }
  fillExact(s.img, {a0, a1, b1, b0}, cv::Scalar(118, 118, 122));
  cv::GaussianBlur(s.img, s.img, cv::Size(5, 5), 1.0);  // symmetric: the edges stay where they are
  s.la = lineThrough(a0, a1);
  s.lb = lineThrough(b0, b1);
  return s;
}
}  // namespace

// In the segmentation: the shaft whose grown region runs into the membrane (leakingShaft()).
// Without the strip search the shaft is lost; with it, the contour lines are sub-pixel. Both
// without the side pair sought as the stretch parallel to the other side (SideSearch), which
// finds this shaft too: with it on, this test passed without the strip search finding anything
// (and with the membrane along the border, the strip search found nothing).
TEST(StripSearch, SegmentationFindsAShaftWhoseRegionLeaks) {
  LeakingShaft const scene = leakingShaft(5, 0.0);
  SegmentationParams sp = colourParams();
  sp.strip.enabled = false;
  sp.contours.min_parallel_side_ratio = 0.0;
  InstrumentSegmenter without(sp);
  auto const r0 = without.process(scene.img);
  for (auto const& c : r0.contours) EXPECT_GT(scene.error(c), 0.5) << "found without the strip search: the test scene does not leak";
  sp.strip.enabled = true;
  InstrumentSegmenter with(sp);
  auto const r1 = with.process(scene.img);
  ASSERT_EQ(r1.contours.size(), 1u);
  EXPECT_LT(scene.error(r1.contours[0]), 0.5);
  // Video: the next frame tracks the strip and finds it again.
  auto const r2 = with.process(scene.img);
  ASSERT_EQ(r2.contours.size(), 1u);
  EXPECT_LT(scene.error(r2.contours[0]), 0.5);
}

// refineStrip(): the leaking shaft with a crease 6.5 px beyond its upper side (in-vivo OP2/img_20
// and img_24). The wide pass (+-9 px) takes the crease's edge, steeper in chroma than the
// shaft's, and the line leaves the strip (more than max_refine_shift, 6 px): without the retry
// the shaft is not found; with it, a narrower pass finds the shaft's edge. (At 6 px the line
// stays within the tolerance, at the crease, retry or not; at 5.5 px the retry's first pass
// stays on it too.)
TEST(StripSearch, AStripWhoseLinesLockedOntoACreaseIsRefinedAgainNarrower) {
  LeakingShaft const scene = leakingShaft(11, 6.5);
  SegmentationParams sp = colourParams();
  sp.contours.min_parallel_side_ratio = 0.0;  // (the strip search finds it)
  SegmentationParams no_retry = sp;
  no_retry.strip.retry_min_halfwidth_px = 0.0;
  InstrumentSegmenter without(no_retry);
  auto const r0 = without.process(scene.img);
  for (auto const& c : r0.contours) EXPECT_GT(scene.error(c), 0.5) << "found without the retry: the crease did not capture the wide pass";
  InstrumentSegmenter with(sp);
  auto const r1 = with.process(scene.img);
  ASSERT_EQ(r1.contours.size(), 1u);
  EXPECT_LT(scene.error(r1.contours[0]), 0.5);
}

namespace {
// A horizontal shaft's contour from the left border to u = 400, between v = 220 and 260.
ApparentContour horizontalShaft() {
  ApparentContour c;
  c.entry_px = {0, 240};
  c.tip_px = {400, 240};
  c.lines = {Eigen::Vector3d(0, 1, -220), Eigen::Vector3d(0, -1, 260)};
  return c;
}
}  // namespace

// Full-resolution contrast: a band of white specular speckles on red tissue (grey once averaged
// at the processing scale) is refused; a grey shaft on the same tissue is accepted.
TEST(StripSearch, FullResolutionContrastRefusesSpeckleBands) {
  cv::Mat img(480, 640, CV_8UC3, cv::Scalar(70, 90, 200));
  ApparentContour const c = horizontalShaft();
  cv::Mat speckled = img.clone();
  cv::RNG rng(3);
  for (int y = 220; y <= 260; ++y)
    for (int x = 0; x < 400; ++x)
      if (rng.uniform(0.0, 1.0) < 0.4) speckled.at<cv::Vec3b>(y, x) = cv::Vec3b(255, 255, 255);  // 40 % of the band
  cv::Mat small;
  cv::resize(speckled, small, cv::Size(320, 240), 0, 0, cv::INTER_AREA);
  cv::Vec3b const avg = small.at<cv::Vec3b>(120, 100);
  float const averaged = ColourFeature::chroma(avg[0], avg[1], avg[2]), tissue = ColourFeature::chroma(70, 90, 200);
  EXPECT_LT(averaged, 0.75 * tissue) << "the band is not greyer than the tissue once averaged: no test";
  StripSearchParams const sp;
  EXPECT_FALSE(stripContrastFullRes(speckled, c, sp));
  cv::Mat shaft = img.clone();
  shaft(cv::Rect(0, 220, 400, 41)).setTo(cv::Scalar(120, 120, 125));
  EXPECT_TRUE(stripContrastFullRes(shaft, c, sp));
  // Metal mirroring the tissue: weakly contrasted (chroma at 0.7 of the tissue's) but matte.
  cv::Mat mirror = img.clone();
  float const t = ColourFeature::chroma(70, 90, 200);
  mirror(cv::Rect(0, 220, 400, 41)).setTo(cv::Scalar(100, 110, 100 + 0.7 * t));
  cv::Vec3b const mp = mirror.at<cv::Vec3b>(240, 100);
  ASSERT_NEAR(ColourFeature::chroma(mp[0], mp[1], mp[2]), 0.7 * t, 2.0);
  EXPECT_TRUE(stripContrastFullRes(mirror, c, sp));
  StripSearchParams strict = sp;
  strict.max_full_res_ratio_matte = strict.max_full_res_ratio;
  EXPECT_FALSE(stripContrastFullRes(mirror, c, strict));
  EXPECT_THROW(stripContrastFullRes(cv::Mat(480, 640, CV_8UC1), c, sp), cv::Exception);
}

// The tissue's level beside a line is an upper quantile of its samples, not their median: a grey
// shaft with a grey blob (gauze) along 60 % of one side is accepted (it fails with the median);
// the same strip on pale tissue all along both sides is still refused.
TEST(StripSearch, FullResolutionContrastAllowsABlobAlongPartOfASide) {
  cv::Mat img(480, 640, CV_8UC3, cv::Scalar(70, 90, 200));
  ApparentContour const c = horizontalShaft();
  img(cv::Rect(0, 220, 400, 41)).setTo(cv::Scalar(120, 120, 125));
  cv::Mat gauze = img.clone();
  gauze(cv::Rect(0, 160, 240, 60)).setTo(cv::Scalar(150, 150, 152));  // above the shaft, 60 % of its length
  StripSearchParams sp;
  EXPECT_TRUE(stripContrastFullRes(gauze, c, sp));
  StripSearchParams median = sp;
  median.full_res_outside_quantile = 0.5;
  EXPECT_FALSE(stripContrastFullRes(gauze, c, median)) << "the blob does not veto the median: no test";
  cv::Mat pale(480, 640, CV_8UC3, cv::Scalar(140, 141, 144));  // pale tissue, as grey as the strip: a fold
  pale(cv::Rect(0, 220, 400, 41)).setTo(cv::Scalar(120, 120, 125));
  EXPECT_FALSE(stripContrastFullRes(pale, c, sp));
  // Out-of-range quantiles are clamped: 0 (the least chromatic sample) and 1 (the most).
  StripSearchParams lo = sp, hi = sp;
  lo.full_res_outside_quantile = -1.0;
  hi.full_res_outside_quantile = 2.0;
  EXPECT_FALSE(stripContrastFullRes(gauze, c, lo));
  EXPECT_TRUE(stripContrastFullRes(gauze, c, hi));
}

// The SIMD walk (four rays per step) gives every ray exactly the scalar walk's score and length:
// rays of every angle from the border and from inside, on a gradient of random blobs and edges
// in a circular field of view (rays that leave the image, the view, end on a weak edge, or run
// the whole image), in batches of 1 to 9 (idle lanes at the end).
TEST(StripSearch, SimdWalkEqualsTheScalarWalk) {
  cv::Mat img(120, 160, CV_8UC3, cv::Scalar(0, 0, 0));
  cv::circle(img, {80, 60}, 58, cv::Scalar(60, 80, 190), cv::FILLED);
  FieldOfView const fov = detectFieldOfView(img);
  ASSERT_TRUE(fov.valid());
  cv::Mat feature(120, 160, CV_8U);
  cv::RNG(7).fill(feature, cv::RNG::UNIFORM, 60, 140);  // (not the global RNG: other tests use it)
  cv::GaussianBlur(feature, feature, cv::Size(7, 7), 2.0);
  cv::rectangle(feature, {70, 0}, {84, 90}, cv::Scalar(10), cv::FILLED);  // a strip: long straight edges
  // A strip whose edge has a 30 px gap: a walk stops in it (8 below its best), not beyond.
  cv::rectangle(feature, {100, 0}, {114, 40}, cv::Scalar(10), cv::FILLED);
  cv::rectangle(feature, {100, 70}, {114, 119}, cv::Scalar(10), cv::FILLED);
  cv::Mat gx, gy;
  cv::Sobel(feature, gx, CV_16S, 1, 0, 3);
  cv::Sobel(feature, gy, CV_16S, 0, 1, 3);
  StripSearchParams p;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  std::vector<StripRay> rays;
  for (int i = 0; i < 400; ++i) {
    StripRay r;
    cv::Point const b = fov.border[static_cast<std::size_t>(rng() % fov.border.size())];
    r.start = i % 5 == 0 ? Eigen::Vector2d(159.0 * U(rng), 119.0 * U(rng)) : Eigen::Vector2d(b.x, b.y);
    bool const along = i % 20 < 2;  // down the left edge of a strip, tissue on the left
    if (along) r.start = Eigen::Vector2d((i % 20 == 0 ? 69.0 : 99.0) + i % 3, 8.0);
    double const a = along ? M_PI / 2 + 0.01 * (U(rng) - 0.5) : 2.0 * M_PI * U(rng);
    r.dir = Eigen::Vector2d(std::cos(a), std::sin(a));
    r.out = Eigen::Vector2d(-r.dir.y(), r.dir.x()) * (along || U(rng) < 0.5 ? 1.0 : -1.0);
    rays.push_back(r);
  }
  std::vector<StripRay> scalar = rays;
  for (auto& r : scalar) walkRay(r, gx, gy, fov, p);
  int long_sides = 0, gap_ends = 0;
  for (std::size_t i = 0; i < scalar.size(); ++i) {
    long_sides += i % 20 == 0 && scalar[i].length >= 60.0;                           // the strip's edge followed
    gap_ends += i % 20 == 1 && scalar[i].length >= 25.0 && scalar[i].length <= 35.0;  // ... and stopped in the gap
  }
  EXPECT_GT(long_sides, 10);
  EXPECT_GT(gap_ends, 10);
  // Eight lanes with AVX2 (the packed field gathered), four without it or with OpenCV's
  // optimisations off; from the gradient or from the field packed once.
  RayField const field = packRayField(gx, gy, fov);
  for (bool optimised : {true, false}) {
    cv::setUseOptimized(optimised);
    for (bool packed : {false, true})
      for (std::size_t batch : {1u, 2u, 3u, 4u, 5u, 8u, 9u, 17u, 400u}) {
        for (std::size_t i = 0; i < rays.size(); i += batch) {
          std::vector<StripRay> part(rays.begin() + static_cast<long>(i), rays.begin() + static_cast<long>(std::min(rays.size(), i + batch)));
          if (packed) walkRays(part, field, p);
          else walkRays(part, gx, gy, fov, p);
          for (std::size_t j = 0; j < part.size(); ++j) {
            ASSERT_EQ(part[j].score, scalar[i + j].score) << "ray " << i + j << " batch " << batch << " optimised " << optimised;
            ASSERT_EQ(part[j].length, scalar[i + j].length) << "ray " << i + j << " batch " << batch << " optimised " << optimised;
          }
        }
      }
  }
  cv::setUseOptimized(true);
}

// The packed field: each pixel's gradient and whether it is inside the view, read back exactly
// (signs, the extremes of a 3x3 Sobel of 8-bit data); a gradient out of range is refused.
TEST(StripSearch, RayFieldPacksGradientAndView) {
  cv::Mat img(40, 50, CV_8UC3, cv::Scalar(0, 0, 0));
  cv::rectangle(img, {5, 5}, {44, 34}, cv::Scalar(60, 80, 190), cv::FILLED);
  FieldOfView const fov = detectFieldOfView(img);
  ASSERT_TRUE(fov.valid());
  cv::Mat gx(40, 50, CV_16S), gy(40, 50, CV_16S);
  cv::RNG(3).fill(gx, cv::RNG::UNIFORM, -1020, 1021);
  cv::RNG(4).fill(gy, cv::RNG::UNIFORM, -1020, 1021);
  gx.at<std::int16_t>(0, 0) = -1020;
  gy.at<std::int16_t>(0, 1) = 1020;
  gy.at<std::int16_t>(0, 2) = -16383;
  RayField const f = packRayField(gx, gy, fov);
  ASSERT_EQ(f.packed.type(), CV_32S);
  for (int y = 0; y < 40; ++y)
    for (int x = 0; x < 50; ++x) {
      std::int32_t const v = f.packed.at<std::int32_t>(y, x);
      ASSERT_EQ(static_cast<std::int16_t>(v & 0xffff), gx.at<std::int16_t>(y, x)) << x << "," << y;
      ASSERT_EQ((v >> 16) >> 1, gy.at<std::int16_t>(y, x)) << x << "," << y;
      ASSERT_EQ((v >> 16) & 1, fov.mask.at<std::uint8_t>(y, x) ? 1 : 0) << x << "," << y;
    }
  gy.at<std::int16_t>(3, 3) = 16384;
  EXPECT_THROW(packRayField(gx, gy, fov), cv::Exception);
  gy.at<std::int16_t>(3, 3) = -16384;
  EXPECT_THROW(packRayField(gx, gy, fov), cv::Exception);
}
