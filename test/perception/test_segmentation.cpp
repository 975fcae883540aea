// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// Whole-sequence regression of the segmentation on rendered scenes (the accuracy table of the
// README comes from endo_guidance_eval_synthetic; these bounds guard against regressions).
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <tuple>
#include <opencv2/imgproc.hpp>

#include "endo_guidance/perception/colour_feature.h"
#include "endo_guidance/perception/segmentation.h"
#include "endo_guidance/pipeline/pipeline.h"
#include "endo_guidance/sim/scene_renderer.h"

#include "colour_params.h"
#include "contour_test_util.h"

using namespace endo_guidance::perception;
using namespace endo_guidance::geometry;
using namespace endo_guidance::sim;
using endo_guidance::test::bandContour;
using endo_guidance::test::lineErrorOverItsExtent;
using namespace endo_guidance::pipeline;
using endo_guidance::test::colourParams;
using endo_guidance::test::colourPipelineParams;

namespace {
// The hard evaluation scene (endo_guidance_eval_synthetic --scene hard): 2 mm of breathing.
struct HardScene {
  SyntheticSceneOptions options = [] {
    SyntheticSceneOptions o;
    o.breathing_amplitude = 0.002;
    return o;
  }();
  SyntheticScene scene{defaultInstruments(), options};
  SceneRenderer renderer{options.width, options.height, hardRenderOptions()};
  // Frames k0..k1 through the whole pipeline (as endo_guidance_eval_synthetic runs them), each
  // frame's truth and output handed to `look`.
  template <class F>
  void throughPipeline(PipelineParams const& pp, int k0, int k1, F look) {
    Pipeline pipe(options.K, cv::Size(options.width, options.height), pp);
    for (int k = k0; k <= k1; ++k) {
      auto const views = scene.frame(k);
      look(k, views, pipe.process(renderer.render(views, k)));
    }
  }
};

struct Stats {
  int visible = 0, found = 0, false_shafts = 0;
  std::vector<double> err;
  std::vector<double> tip_err;  // |tip - the jaws' end| along the axis (px)
  double tipP50() const {
    std::vector<double> t = tip_err;
    std::sort(t.begin(), t.end());
    return t.empty() ? 1e9 : t[t.size() / 2];
  }
};

Stats run(RenderOptions const& ro, int frames, std::size_t instruments = 3) {
  std::vector<SyntheticInstrument> motions = defaultInstruments();
  motions.resize(std::min(instruments, motions.size()));
  SyntheticScene scene(motions);
  SceneRenderer renderer(640, 480, ro);
  InstrumentSegmenter seg(colourParams());
  Stats s;
  for (int k = 0; k < frames; ++k) {
    auto const views = scene.frame(k);
    auto const res = seg.process(renderer.render(views, k));
    std::vector<bool> used(res.contours.size(), false);
    for (auto const& v : views) {
      ++s.visible;
      Eigen::Vector3d ta = v.truth.lines[0] - v.truth.lines[1];
      ta /= ta.head<2>().norm();
      for (std::size_t j = 0; j < res.contours.size(); ++j) {
        auto const& c = res.contours[j];
        Eigen::Vector2d const m = 0.5 * (c.entry_px + c.tip_px);
        // As endo_guidance_eval_synthetic: the mean distance of entry and midpoint to the true axis.
        if (used[j] || 0.5 * (std::abs(ta.dot(Eigen::Vector3d(m.x(), m.y(), 1))) +
                              std::abs(ta.dot(Eigen::Vector3d(c.entry_px.x(), c.entry_px.y(), 1)))) > 12.0)
          continue;
        used[j] = true;
        ++s.found;
        s.tip_err.push_back(std::abs((v.truth.tip_px - v.truth.entry_px).normalized().dot(c.tip_px - SceneRenderer::visibleTip(v, k))));
        for (int l = 0; l < 2; ++l) {
          Eigen::Vector2d const q = v.truth.tip_px;
          Eigen::Vector2d const f = q - v.truth.lines[l].head<2>() * v.truth.lines[l].dot(Eigen::Vector3d(q.x(), q.y(), 1));
          s.err.push_back(std::abs(c.lines[l].dot(Eigen::Vector3d(f.x(), f.y(), 1))));
        }
        break;
      }
    }
    for (bool u : used) s.false_shafts += !u;
  }
  std::sort(s.err.begin(), s.err.end());
  return s;
}

// A grey bar 32 px wide along a -> b (either end may lie outside) on plain red tissue, 640x480.
cv::Mat greyBarOnTissue(Eigen::Vector2d const& a, Eigen::Vector2d const& b) {
  cv::Mat im(480, 640, CV_8UC3, cv::Scalar(60, 70, 170));
  Eigen::Vector2d const d = (b - a).normalized(), n(-d.y(), d.x());
  std::vector<cv::Point> bar;
  for (Eigen::Vector2d const& q : {Eigen::Vector2d(a + 16 * n), Eigen::Vector2d(b + 16 * n), Eigen::Vector2d(b - 16 * n),
                                   Eigen::Vector2d(a - 16 * n)})
    bar.emplace_back(static_cast<int>(std::lround(q.x())), static_cast<int>(std::lround(q.y())));
  cv::fillConvexPoly(im, bar, cv::Scalar(110, 110, 110), cv::LINE_AA);
  return im;
}
// A grey bar 32 px wide entering from the left border (its edges through (-10, 224) -> (420, 194)
// and (-8, 256) -> (422, 226), or on to the right border), and a grey blob of the same colour
// joined to its lower side near the entry and reaching the bottom border, 640x480.
cv::Mat barWithBlobToTheBorder(bool across_the_view) {
  cv::Mat im(480, 640, CV_8UC3, cv::Scalar(60, 70, 170));
  std::vector<cv::Point> bar{{-10, 224}, {420, 194}, {422, 226}, {-8, 256}};
  if (across_the_view) bar = {{-10, 224}, {660, 177}, {662, 209}, {-8, 256}};
  cv::fillConvexPoly(im, bar, cv::Scalar(110, 110, 110), cv::LINE_AA);
  std::vector<cv::Point> blob{{40, 250}, {170, 240}, {230, 479}, {90, 479}};
  cv::fillConvexPoly(im, blob, cv::Scalar(110, 110, 110), cv::LINE_AA);
  return im;
}
// Shaft A, grey, from the left border to x = 460 near the bottom (edges (-10, 424) -> (460, 404)
// and (-8, 460) -> (462, 440)); bar B, a lighter grey, 34 px wide, up to y = 60 (edges
// (282, 490) -> (296, 60) and (318, 490) -> (330, 60)). `crossing`: B enters from the bottom
// border and crosses A just above its entry (B's part below A is about 30 px long); otherwise B
// starts on A's upper side, and a short grey stub crosses the bottom border into A elsewhere
// (x 150-186). 640x480 on plain red tissue.
// `bottom`, `top`: B's width at its lower and upper ends (34 px by default).
cv::Mat crossingBars(bool crossing, int bottom = 34, int top = 34) {
  cv::Mat im(480, 640, CV_8UC3, cv::Scalar(60, 70, 170));
  std::vector<cv::Point> b{{300 - bottom / 2, crossing ? 490 : 420}, {313 - top / 2, 60}, {313 + top / 2, 60},
                           {300 + bottom / 2, crossing ? 490 : 420}};
  cv::fillConvexPoly(im, b, cv::Scalar(110, 110, 110), cv::LINE_AA);
  if (!crossing) {
    std::vector<cv::Point> stub{{150, 490}, {152, 430}, {186, 430}, {184, 490}};
    cv::fillConvexPoly(im, stub, cv::Scalar(110, 110, 110), cv::LINE_AA);
  }
  std::vector<cv::Point> a{{-10, 424}, {460, 404}, {462, 440}, {-8, 460}};
  cv::fillConvexPoly(im, a, cv::Scalar(90, 90, 90), cv::LINE_AA);
  return im;
}
// Whether c lies on bar B of crossingBars(): both lines within 1 px of its edges at y = 100 and
// y = 380 (beyond A), and its tip near B's end.
bool onCrossingBar(ApparentContour const& c) {
  ImageLine const left = *lineThrough({282, 490}, {296, 60}), right = *lineThrough({318, 490}, {330, 60});
  double e = 0.0;
  for (double y : {100.0, 380.0})
    for (ImageLine const& edge : {left, right}) {
      Eigen::Vector2d const q(-(edge.z() + edge.y() * y) / edge.x(), y);
      e = std::max(e, std::min(std::abs(c.lines[0].dot(q.homogeneous())), std::abs(c.lines[1].dot(q.homogeneous()))));
    }
  return e < 1.0 && c.tip_px.y() < 80.0;
}
}  // namespace

TEST(Segmentation, CleanSceneRegression) {
  Stats const s = run(RenderOptions{}, 80);
  double const p50 = s.err.empty() ? 1e9 : s.err[s.err.size() / 2];
  std::printf("[ clean, 80 frames ] found %d/%d, false %d, line error at the tip p50 %.3f px\n", s.found, s.visible,
              s.false_shafts, p50);
  EXPECT_GT(s.found, 0.7 * s.visible);
  EXPECT_LT(s.false_shafts, 0.2 * 80);
  EXPECT_LT(p50, 0.05);
}

TEST(Segmentation, BlackShaftsInACircularView) {
  RenderOptions ro;
  ro.black_shafts = true;
  ro.circular_fov = true;
  Stats const s = run(ro, 60);
  std::printf("[ black, circular, 60 frames ] found %d/%d, false %d\n", s.found, s.visible, s.false_shafts);
  EXPECT_GT(s.found, 0.6 * s.visible);
}

// The tip is the jaws' end located on the frame, not the region's end (at half resolution, a few
// px short of thin jaws): one instrument, grey on tissue and black with metal jaws in a circular view.
TEST(Segmentation, TheTipIsTheJawsEndOnTheFrame) {
  RenderOptions black;
  black.black_shafts = true;
  black.circular_fov = true;
  for (RenderOptions const& ro : {RenderOptions{}, black}) {
    Stats const s = run(ro, 60, 1);
    std::printf("[ one instrument%s, 60 frames ] found %d/%d, tip (the jaws' end) along the axis p50 %.2f px\n",
                ro.black_shafts ? ", black" : "", s.found, s.visible, s.tipP50());
    EXPECT_GT(s.found, 0.9 * s.visible);
    EXPECT_LT(s.tipP50(), 0.75);
  }
}

TEST(Segmentation, RejectsBadInput) {
  InstrumentSegmenter seg(colourParams());
  EXPECT_THROW(seg.process(cv::Mat()), cv::Exception);
  EXPECT_THROW(seg.process(cv::Mat(10, 10, CV_8U)), cv::Exception);
  // A plain tissue image: no shaft.
  EXPECT_TRUE(seg.process(cv::Mat(240, 320, CV_8UC3, cv::Scalar(60, 70, 170))).contours.empty());
}

// A frame far wider than tall (fuzz_pipeline: 1920x1 reduced six-fold had no row left, and the
// field of view read an empty channel list) is segmented, finding nothing, and so is 1x1.
TEST(Segmentation, FramesOfOnePixelEitherWay) {
  for (cv::Size size : {cv::Size(1920, 1), cv::Size(1, 1080), cv::Size(1, 1), cv::Size(1500, 3)}) {
    InstrumentSegmenter seg(colourParams());
    SegmentationResult r;
    EXPECT_NO_THROW(r = seg.process(cv::Mat(size, CV_8UC3, cv::Scalar(60, 70, 170)))) << size;
    EXPECT_TRUE(r.contours.empty()) << size;
  }
}

// A tracked shaft whose feature level jumps between two frames (a change of light or of the
// tissue it mirrors) is searched at every growth level in that same frame, not lost until the
// next full search. (The strip search is off here: it would find the shaft on its own.)
TEST(Segmentation, TrackedShaftFoundAgainWhenItsLevelJumps) {
  SegmentationParams p = colourParams();
  p.strip.enabled = false;
  p.tracking.detect_every = 1;  // every frame a detection frame: the seed memory is under test
  InstrumentSegmenter seg(p);
  ColourFeature const cf(p.feature);
  cv::Scalar const tissue(60, 70, 170);
  // A grey with a blue tint whose feature lies between the 3rd and 4th growth levels.
  double const target = 0.5 * (p.regions.thresholds[2] + p.regions.thresholds[3]);
  cv::Scalar tinted(100, 100, 100);
  for (int t = 0; t < 120; ++t) {
    tinted = cv::Scalar(100 + t, 100, 100 - t / 2);
    if (cf.exact(static_cast<float>(tinted[0]), static_cast<float>(tinted[1]), static_cast<float>(tinted[2])) >= target) break;
  }
  ASSERT_GE(cf.exact(static_cast<float>(tinted[0]), static_cast<float>(tinted[1]), static_cast<float>(tinted[2])),
            p.regions.thresholds[2] + 2);
  auto frame = [&](cv::Scalar const& shaft) {
    cv::Mat im(480, 640, CV_8UC3, tissue);
    std::vector<cv::Point> bar{{280, 479}, {340, 479}, {350, 200}, {300, 200}};
    cv::fillConvexPoly(im, bar, shaft, cv::LINE_AA);
    return im;
  };
  for (int k = 0; k < 3; ++k) ASSERT_EQ(seg.process(frame(cv::Scalar(100, 100, 100))).contours.size(), 1u) << k;
  EXPECT_EQ(seg.process(frame(tinted)).contours.size(), 1u);
  EXPECT_EQ(seg.process(frame(tinted)).contours.size(), 1u);
}

// A shaft crossing the border obliquely: its border run (and the seed, its middle) is off the
// axis, and the farthest region point is a corner of the end; entry and tip are reported on the
// image axis (the bisector of the contour lines).
TEST(Segmentation, EntryAndTipOnTheImageAxis) {
  Eigen::Vector2d const a(60.0, 540.0), b(470.0, 300.0);
  Eigen::Vector2d const d = (b - a).normalized();
  cv::Mat const im = greyBarOnTissue(a, b);
  InstrumentSegmenter seg(colourParams());
  auto const res = seg.process(im);
  ASSERT_EQ(res.contours.size(), 1u);
  auto const& c = res.contours[0];
  ImageLine const ax = imageAxis(c);
  ImageLine const truth = *lineThrough(a, b);
  for (Eigen::Vector2d const& q : {c.entry_px, c.tip_px}) {
    EXPECT_LT(std::abs(ax.dot(q.homogeneous())), 1e-9);
    EXPECT_LT(std::abs(truth.dot(q.homogeneous())), 1.0) << q.transpose();
  }
  Eigen::Vector2d const exit = a + (479.0 - a.y()) / d.y() * d;  // where the axis leaves the image
  // (the border of the reduced image lies a few pixels inside, the axis meets it at 30 deg)
  EXPECT_LT((c.entry_px - exit).norm(), 16.0) << c.entry_px.transpose();
  EXPECT_LT((c.tip_px - b).norm(), 6.0) << c.tip_px.transpose();  // the end of the bar
}

// A shaft entering through the side of the view close to a corner, at a shallow angle to the
// bottom: its border run (the seed) lies on the bottom, but its axis leaves the view through the
// side, which it crosses steeply: it is a shaft, not a band along the border.
TEST(Segmentation, ShaftEnteringNearACorner) {
  Eigen::Vector2d const a(700.0, 470.0), b(250.0, 432.0);  // 4.8 deg to the bottom
  cv::Mat const im = greyBarOnTissue(a, b);
  InstrumentSegmenter seg(colourParams());
  auto const res = seg.process(im);
  ASSERT_FALSE(res.seeds.empty());
  std::printf("seed (%d, %d) at processing scale\n", res.seeds[0].position.x, res.seeds[0].position.y);
  ASSERT_EQ(res.contours.size(), 1u);
  ImageLine const truth = *lineThrough(a, b);
  for (Eigen::Vector2d const& q : {res.contours[0].entry_px, res.contours[0].tip_px})
    EXPECT_LT(std::abs(truth.dot(q.homogeneous())), 1.0) << q.transpose();
}

// The hard rendered scene, frames 0-19: the gauze's seed (the greyest) grows over the gauze and
// the left shaft, a region that is refused; in this video the right shaft's seed also falls
// inside a refused region, but on another stretch of the border than that region's seed: its
// strip search finds the shaft (before, the seed was skipped as claimed, and the right shaft was
// found in 10 of these 20 frames). The gauze is never reported.
TEST(Segmentation, ShaftInsideARegionRefusedForAnotherSeed) {
  HardScene hard;
  SyntheticScene& scene = hard.scene;
  SceneRenderer const& renderer = hard.renderer;
  InstrumentSegmenter seg(colourParams());
  int right = 0, right_found = 0, unmatched = 0;
  for (int k = 0; k < 20; ++k) {
    auto const views = scene.frame(k);
    auto const res = seg.process(renderer.render(views, k));
    for (auto const& v : views) right += v.truth.entry_px.x() > 600.0;  // the shaft entering from the right
    for (auto const& c : res.contours) {
      bool any = false;
      for (auto const& v : views) {
        ImageLine const ta = imageAxis(v.truth);
        bool const on = std::abs(ta.dot(c.entry_px.homogeneous())) < 3.0 && std::abs(ta.dot(c.tip_px.homogeneous())) < 3.0;
        any |= on;
        right_found += on && v.truth.entry_px.x() > 600.0;
      }
      unmatched += !any;
    }
  }
  std::printf("right shaft found in %d of %d frames; %d contours on no instrument\n", right_found, right, unmatched);
  EXPECT_GE(right_found, right - 2);
  EXPECT_EQ(unmatched, 0);
}

// The hard rendered scene, frames 100, 105 and 116 each alone: the gauze lies across both sides
// of the left shaft near its entry and reaches the bottom border, where its own seed is searched
// first and its region (gauze and shaft) refused. The left border's seed sees that region from
// its own entry; the pair followed from there has no edges (gauze beside the shaft; in frame
// 116 the pair is not even near-parallel), and the sides sought again as the facing straight
// stretches beyond the gauze are the shaft's: found, both lines within 1 px of the truth. Not
// found without the re-sought sides (no parallel sides at all), nor when re-sought pairs must
// enter at more than 90 deg (sine 1).
TEST(Segmentation, AShaftMergedWithGauzeOnBothSidesIsFoundFromItsOwnEntry) {
  HardScene hard;
  auto found = [&](int k, SegmentationParams const& sp) {
    auto const views = hard.scene.frame(k);
    ApparentContour const& truth = views[0].truth;  // the left shaft
    EXPECT_LT(truth.entry_px.x(), 1.0);
    InstrumentSegmenter seg(sp);
    auto const res = seg.process(hard.renderer.render(views, k));
    for (auto const& c : res.contours) {
      double e = 0.0;
      for (int l = 0; l < 2; ++l)
        for (Eigen::Vector2d const& q : {truth.entry_px, truth.tip_px})
          e = std::max(e, std::abs(c.lines[l].dot(footOnLine(truth.lines[l], q).homogeneous())));
      if (e < 1.0) return true;
    }
    return false;
  };
  for (int k : {100, 105, 116}) {
    SegmentationParams sp = colourParams();
    EXPECT_TRUE(found(k, sp)) << "frame " << k;
    sp.resought_min_entry_sine = 1.0;
    EXPECT_FALSE(found(k, sp)) << "frame " << k;
    sp = colourParams();
    sp.contours.min_parallel_side_ratio = 0.0;
    EXPECT_FALSE(found(k, sp)) << "frame " << k;
  }
}

// The hard rendered scene, frames 3 and 8 each alone: the left shaft enters the bottom border
// beside the gauze blob, which lies on the border; the border's tissue level there is the
// gauze's, low, so the seed's growth levels were all lowered below the metal's level and the
// shaft was never grown whole. The absolute levels above the lowered ones are tried after them:
// the left shaft is found, its lines within 1.5 px of the truth over the part of each in the view
// (from the entry it reports, or where the line enters the view, to the shaft's end; the lower
// line leaves the image 90 px before the entry; beside the gauze, under noise and JPEG, it is
// 1.0 px off where it does).
TEST(Segmentation, AShaftBesideAGreyBlobOnTheBorderIsGrownAtTheAbsoluteLevels) {
  HardScene hard;
  SyntheticScene& scene = hard.scene;
  SceneRenderer const& renderer = hard.renderer;
  for (int k : {3, 8}) {
    auto const views = scene.frame(k);
    ApparentContour const& truth = views[0].truth;  // the left shaft, entering at the bottom-left
    ASSERT_LT(truth.entry_px.x(), 5.0);
    auto const res = InstrumentSegmenter(colourParams()).process(renderer.render(views, k));
    bool found = false;
    for (auto const& c : res.contours) {
      double e = 0.0;
      for (int l = 0; l < 2; ++l) {
        Eigen::Vector2d const end = footOnLine(truth.lines[l], truth.tip_px), d = (end - footOnLine(truth.lines[l], c.entry_px)).normalized();
        Eigen::Vector2d start = footOnLine(truth.lines[l], c.entry_px);  // moved along the line into the view
        for (int i = 0; i < 4000 && (start.x() < 0.0 || start.y() < 0.0 || start.x() > 639.0 || start.y() > 479.0); ++i) start += 0.25 * d;
        for (Eigen::Vector2d const& q : {start, end}) e = std::max(e, std::abs(c.lines[l].dot(q.homogeneous())));
      }
      found |= e < 1.5;
    }
    EXPECT_TRUE(found) << "frame " << k;
  }
}

// The clean rendered scene through the pipeline, about frame 51: the bottom shaft crosses the
// border obliquely and, with the seed search focused by the trocars found by then, two seeds lie
// on its border run, each giving the shaft. It is reported once; the second is claimed as a
// duplicate (before, both were reported, and one counted as a false shaft).
TEST(Segmentation, AShaftWithTwoSeedsIsReportedOnce) {
  SyntheticSceneOptions so;
  SyntheticScene scene(defaultInstruments(), so);
  SceneRenderer renderer(so.width, so.height, RenderOptions{});
  Pipeline pipe(so.K, cv::Size(so.width, so.height), colourPipelineParams());
  int twice = 0, duplicates = 0, shafts = 0, found = 0;
  for (int k = 0; k <= 56; ++k) {
    auto const views = scene.frame(k);
    auto const res = pipe.process(renderer.render(views, k)).segmentation;
    if (k < 44) continue;  // (the seed memory is that of a video)
    for (auto const& st : res.region_status) duplicates += st == ContourRejection::kDuplicate;
    for (auto const& v : views) {
      ImageLine const ta = imageAxis(v.truth);
      int on = 0;
      for (auto const& c : res.contours)
        on += std::abs(ta.dot(footOnLine(imageAxis(c), c.entry_px).homogeneous())) < 6.0 &&
              std::abs(ta.dot(footOnLine(imageAxis(c), c.tip_px).homogeneous())) < 6.0;
      ++shafts;
      found += on > 0;
      twice += on > 1;
    }
  }
  std::printf("frames 44-56: %d of %d shafts found, %d twice; %d duplicate regions claimed\n", found, shafts, twice, duplicates);
  EXPECT_EQ(twice, 0);
  EXPECT_GE(found, shafts - 1);
}

// A grey wedge from the bottom border that widens toward its far end: 24 px at the border and
// 36 px at the end (1.5x, a shaft pointing toward the camera) is a shaft; 20 px to 60 px (3x) is
// not (a dark wedge in a corner, robotic Dataset 2), and is refused as widening.
TEST(Segmentation, AWedgeWideningThreefoldIsNotAShaft) {
  auto wedge = [](double w_border, double w_end) {
    cv::Mat im(480, 640, CV_8UC3, cv::Scalar(60, 70, 170));
    std::vector<cv::Point> poly{{static_cast<int>(320 - w_border / 2), 479}, {static_cast<int>(320 + w_border / 2), 479},
                                {static_cast<int>(320 + w_end / 2), 260}, {static_cast<int>(320 - w_end / 2), 260}};
    cv::fillConvexPoly(im, poly, cv::Scalar(110, 110, 110), cv::LINE_AA);
    return im;
  };
  SegmentationParams p = colourParams();
  {
    InstrumentSegmenter seg(p);
    EXPECT_EQ(seg.process(wedge(24.0, 36.0)).contours.size(), 1u);
  }
  InstrumentSegmenter seg(p);
  auto const res = seg.process(wedge(20.0, 60.0));
  EXPECT_TRUE(res.contours.empty());
  bool widens = false;
  for (auto const& st : res.region_status) widens |= st == ContourRejection::kWidens;
  EXPECT_TRUE(widens);
  // Without the bound, the same wedge is taken for a shaft.
  p.contours.max_widening = 0.0;
  InstrumentSegmenter unbounded(p);
  EXPECT_EQ(unbounded.process(wedge(20.0, 60.0)).contours.size(), 1u);
}

TEST(Segmentation, ParametersItCannotWorkWithAreRefused) {
  SegmentationParams p = colourParams();
  p.regions.thresholds.clear();
  EXPECT_THROW(InstrumentSegmenter{p}, std::invalid_argument);
  InstrumentSegmenter seg(colourParams());
  EXPECT_THROW(seg.setParams(p), std::invalid_argument);
  p = colourParams();
  p.processing_width = 0;
  EXPECT_THROW(seg.setParams(p), std::invalid_argument);
  EXPECT_EQ(seg.params().processing_width, colourParams().processing_width);  // unchanged
}

// The bar's lower side, followed from its entry, runs along the blob down to the bottom border:
// the two sides from the entry diverge (not near-parallel), and the lower side's chain holds
// only 30 px of the bar's edge before the blob. Its sides are sought again: the lower one as the
// stretch parallel to the upper one beyond the blob, on the boundary's other chain (around the
// tip and back). Found, both lines within 1 px of the bar's edges, the blob not reported (before
// the sides of a diverging pair were sought again the bar was missed, and the strip search took
// the blob for a shaft). Not found without re-sought sides (min_parallel_side_ratio 0).
TEST(Segmentation, ASideRunningAlongABlobToTheBorderIsSoughtAgainBeyondIt) {
  ImageLine const upper = *lineThrough({-10, 224}, {420, 194}), lower = *lineThrough({-8, 256}, {422, 226});
  auto onBar = [&](ApparentContour const& c) {
    double e = 0.0;
    for (Eigen::Vector2d const& q : {c.entry_px, c.tip_px}) {
      double const a = std::min(std::abs(c.lines[0].dot(footOnLine(upper, q).homogeneous())), std::abs(c.lines[1].dot(footOnLine(upper, q).homogeneous())));
      double const b = std::min(std::abs(c.lines[0].dot(footOnLine(lower, q).homogeneous())), std::abs(c.lines[1].dot(footOnLine(lower, q).homogeneous())));
      e = std::max({e, a, b});
    }
    return e < 1.0 && c.entry_px.x() < 10.0 && c.tip_px.x() > 400.0;
  };
  cv::Mat const im = barWithBlobToTheBorder(false);
  auto const res = InstrumentSegmenter(colourParams()).process(im);
  ASSERT_EQ(res.contours.size(), 1u);
  EXPECT_TRUE(onBar(res.contours[0]));
  SegmentationParams sp = colourParams();
  sp.contours.min_parallel_side_ratio = 0.0;
  for (auto const& c : InstrumentSegmenter(sp).process(im).contours) EXPECT_FALSE(onBar(c));
}

// The same bar across the whole view, to the right border: from its left entry, the sides
// sought again (as above) give a band whose far end is on the field of view's border too. A
// re-sought pair must end inside the view (resought_min_tip_depth_px): refused, saying so (a
// band across a corner of the view, robotic Dataset 2). With the bound at 0, taken.
TEST(Segmentation, AReSoughtBandWithItsTipOnTheBorderIsNotAShaft) {
  cv::Mat const im = barWithBlobToTheBorder(true);
  SegmentationParams sp = colourParams();
  sp.strip.enabled = false;  // (it finds the bar from its right end, and the blob)
  auto const res = InstrumentSegmenter(sp).process(im);
  EXPECT_TRUE(res.contours.empty());
  bool tip_on_border = false;
  for (auto const& st : res.region_status) tip_on_border |= st == ContourRejection::kTipOnBorder;
  EXPECT_TRUE(tip_on_border);
  sp.resought_min_tip_depth_px = 0.0;
  auto const taken = InstrumentSegmenter(sp).process(im);
  ASSERT_EQ(taken.contours.size(), 1u);
  EXPECT_LT(taken.contours[0].entry_px.x(), 10.0);
  EXPECT_GT(taken.contours[0].tip_px.x(), 620.0);
}

// crossingBars(true): shaft A, from the left border, is searched first (the border's seeds in
// its order) and claims its strip, which cuts bar B where B crosses it: B's part below A, from
// its bottom-border seed, is too short to be a shaft and is refused. Seeded on A's edge, where
// that refused region touches A, B's part above A is found (the strip search, which also finds
// B from its border seed here, is off): both lines within 1 px of B's edges. Not found without
// the crossing seeds.
TEST(Segmentation, AShaftCrossingAnotherIsFoundBeyondIt) {
  cv::Mat const im = crossingBars(true);
  SegmentationParams sp = colourParams();
  sp.strip.enabled = false;
  auto const res = InstrumentSegmenter(sp).process(im);
  ASSERT_EQ(res.contours.size(), 2u);
  EXPECT_TRUE(onCrossingBar(res.contours[1]));
  EXPECT_LT(res.contours[0].entry_px.x(), 10.0);  // A
  sp.crossing_seeds = false;
  auto const without = InstrumentSegmenter(sp).process(im);
  for (auto const& c : without.contours) EXPECT_FALSE(onCrossingBar(c));
}

// crossingBars(false): bar B starts on A's upper side. The stub's refused region touches A, so A's
// edge is seeded and B's region is grown from there; it has two straight sides, but walking
// back along its axis across A finds tissue, not a shaft going on under A: refused as not
// continued (a blob or a jaw beside a shaft ends at it).
TEST(Segmentation, ABarStartingAtAShaftIsNotACrossingShaft) {
  SegmentationParams sp = colourParams();
  sp.strip.enabled = false;
  auto const res = InstrumentSegmenter(sp).process(crossingBars(false));
  ASSERT_EQ(res.contours.size(), 1u);  // A
  EXPECT_LT(res.contours[0].entry_px.x(), 10.0);
  bool not_continued = false;
  for (auto const& st : res.region_status) not_continued |= st == ContourRejection::kNotContinued;
  EXPECT_TRUE(not_continued);
}

// The hard rendered scene as the evaluation runs it (the whole pipeline, here from frame 200:
// the insertion points found focus the seeds): from frame 266 the left shaft passes under the top
// one, which is searched first, and the left shaft's part between the border and the crossing
// is merged with the gauze: refused. The part beyond the crossing is found from the top shaft's
// edge (crossing seeds) in most of frames 266-273 (7 of 8), its lines within 1 px of the truth
// over the extent it reports; without the crossing seeds in one.
TEST(Segmentation, TheHardScenesCrossingShaftIsFoundBeyondTheCrossing) {
  HardScene hard;
  auto count = [&](bool crossing_seeds) {
    PipelineParams pp = colourPipelineParams();
    pp.segmentation.crossing_seeds = crossing_seeds;
    int found = 0;
    // (the insertion points are known well before frame 266)
    hard.throughPipeline(pp, 200, 273, [&](int k, std::vector<SyntheticView> const& views, PipelineOutput const& out) {
      if (k < 266) return;
      for (auto const& c : out.segmentation.contours)
        if (lineErrorOverItsExtent(c, views[0].truth) < 1.0) {  // the left shaft
          ++found;
          break;
        }
    });
    return found;
  };
  int const with = count(true), without = count(false);
  std::printf("left shaft found in %d of frames 266-273 (%d without crossing seeds)\n", with, without);
  EXPECT_GE(with, 6);
  EXPECT_LE(without, 2);
}

// crossingBars(true) with bar B much thinner than A (8 px, a quarter of A's width: a jaw or a
// suture across the shaft), or widening from 34 to 60 px away from A: crossing seeds find its
// part above A, but instruments of one radius are about as wide where they cross (at about the
// same depth), and a shaft's part beyond another narrows or keeps its width away from it (the
// hard scene's false pairs of this kind: jaws at 0.2x, blobs widening 1.9x). Refused, saying why.
TEST(Segmentation, ACrossingBarTooThinOrWideningIsNotAShaft) {
  SegmentationParams sp = colourParams();
  sp.strip.enabled = false;
  for (auto const& [bottom, top, why] : {std::tuple<int, int, ContourRejection>{8, 8, ContourRejection::kTooThin},
                                         std::tuple<int, int, ContourRejection>{34, 60, ContourRejection::kWidens}}) {
    auto const res = InstrumentSegmenter(sp).process(crossingBars(true, bottom, top));
    EXPECT_EQ(res.contours.size(), 1u) << bottom << " -> " << top << " px";  // A
    if (!res.contours.empty()) {
      EXPECT_LT(res.contours[0].entry_px.x(), 10.0);
    }
    bool refused = false;
    for (std::size_t i = 0; i < res.regions.size(); ++i)
      refused |= res.region_status[i] == why && res.regions[i].seed.y < 210;  // seeded on A's upper edge
    EXPECT_TRUE(refused) << bottom << " -> " << top << " px";
  }
}

// A blob (not a shaft) entering from the left border, whose border run is low enough to be a seed
// only under the relaxed threshold of the arc facing a trocar image (feature about 46: above
// seed_threshold 40, below seed_near_threshold 55) has no strip search; the same blob darker
// (feature about 30, a seed under the ordinary threshold) has one. Neither is a shaft.
TEST(Segmentation, ASeedOnlyUnderTheRelaxedThresholdHasNoStripSearch) {
  auto blob = [](cv::Scalar const& colour) {
    cv::Mat im(480, 640, CV_8UC3, cv::Scalar(60, 70, 170));
    cv::ellipse(im, {0, 240}, {120, 70}, 20.0, 0.0, 360.0, colour, -1, cv::LINE_AA);
    return im;
  };
  ColourFeature const f;
  EXPECT_GT(f.exact(90, 95, 126), 40.f);
  EXPECT_LT(f.exact(90, 95, 126), 55.f);
  EXPECT_LT(f.exact(100, 104, 123), 40.f);
  std::vector<Eigen::Vector3d> const trocar{Eigen::Vector3d(-400.0, 240.0, 1.0)};  // left of the view
  auto const relaxed = InstrumentSegmenter(colourParams()).process(blob(cv::Scalar(90, 95, 126)), trocar);
  auto const ordinary = InstrumentSegmenter(colourParams()).process(blob(cv::Scalar(100, 104, 123)), trocar);
  ASSERT_FALSE(relaxed.seeds.empty());
  EXPECT_GT(relaxed.seeds[0].mean_value, 40.f);
  EXPECT_EQ(relaxed.strip_searches, 0);
  ASSERT_FALSE(ordinary.seeds.empty());
  EXPECT_LE(ordinary.seeds[0].mean_value, 40.f);
  EXPECT_GE(ordinary.strip_searches, 1);
  EXPECT_TRUE(relaxed.contours.empty());
  EXPECT_TRUE(ordinary.contours.empty());
}

// A refused seed whose border run is missing for a frame (a run near the seed threshold
// flickers in a video) keeps its memory: when the run is back, its region is only claimed again,
// not searched in full (no strip search) until a search is due. Unless the run came back of
// another width: something entered there (a shaft entering where the blob was is found at once).
TEST(Segmentation, ARefusedSeedMissingForAFrameKeepsItsMemory) {
  auto blob = [](int half_height) {
    cv::Mat im(480, 640, CV_8UC3, cv::Scalar(60, 70, 170));
    cv::ellipse(im, {0, 240}, {120, half_height}, 0.0, 0.0, 360.0, cv::Scalar(100, 104, 123), -1, cv::LINE_AA);
    return im;
  };
  cv::Mat const tissue(480, 640, CV_8UC3, cv::Scalar(60, 70, 170));
  InstrumentSegmenter seg(colourParams());
  auto const first = seg.process(blob(70));
  ASSERT_FALSE(first.seeds.empty());
  EXPECT_GE(first.strip_searches, 1);
  EXPECT_TRUE(first.contours.empty());
  EXPECT_TRUE(seg.process(tissue).seeds.empty());
  auto const back = seg.process(blob(70));
  ASSERT_FALSE(back.seeds.empty());
  EXPECT_EQ(back.strip_searches, 0);
  EXPECT_FALSE(back.regions.empty());  // claimed again
  EXPECT_TRUE(back.contours.empty());
  // Missing again, then back twice as wide: searched in full.
  seg.process(tissue);
  EXPECT_GE(seg.process(blob(140)).strip_searches, 1);
  // Missing, then a shaft enters where the blob was: found in that frame.
  seg.process(blob(70));
  seg.process(tissue);
  auto const shaft = seg.process(greyBarOnTissue({-10.0, 240.0}, {420.0, 220.0}));
  EXPECT_EQ(shaft.contours.size(), 1u);
}

// A refused seed that keeps giving no shaft is searched in full less and less often: every
// full_search_every (5) frames, then the interval doubles per failed search up to
// full_search_max_every. Its region, grown again at its level to claim it, must keep its area:
// a blob that grows (its border run unchanged) is searched in full at once.
TEST(Segmentation, ARefusedSeedIsSearchedInFullLessAndLessOften) {
  auto blob = [](int half_length) {
    cv::Mat im(480, 640, CV_8UC3, cv::Scalar(60, 70, 170));
    cv::ellipse(im, {0, 240}, {half_length, 70}, 0.0, 0.0, 360.0, cv::Scalar(100, 104, 123), -1, cv::LINE_AA);
    return im;
  };
  auto searchedAt = [&](SegmentationParams const& p, int frames, int grown_from = -1) {
    InstrumentSegmenter seg(p);
    std::vector<int> at;
    for (int k = 0; k < frames; ++k) {
      auto const r = seg.process(blob(k >= grown_from && grown_from >= 0 ? 240 : 120));
      EXPECT_TRUE(r.contours.empty());
      if (r.full_searches > 0) at.push_back(k);
    }
    return at;
  };
  SegmentationParams every5 = colourParams();
  every5.full_search_max_every = 5;
  EXPECT_EQ(searchedAt(every5, 40), (std::vector<int>{0, 5, 10, 15, 20, 25, 30, 35}));
  SegmentationParams const backing_off = colourParams();  // full_search_max_every 20
  EXPECT_EQ(searchedAt(backing_off, 40), (std::vector<int>{0, 5, 15, 35}));
  // Twice as long inward from frame 22 (its run along the border unchanged): searched at once, and
  // refused again, it backs off further.
  EXPECT_EQ(searchedAt(backing_off, 45, 22), (std::vector<int>{0, 5, 15, 22, 42}));
}

// The hard rendered scene through the pipeline, frames 200-283: in frame 283 the left
// instrument's jaws touch the right shaft's lower side. The right shaft is found with both lines
// within 1 px of the truth. (With the jaws drawn with fillConvexPoly, its region seen again had a
// re-sought candidate on the touching jaws' edge, 1.85x wider at the tip, which only
// resought_max_widening refused; with their exact coverage no frame of the clean or hard scene,
// 0-600, gives one: that bound is not exercised by a rendered frame now.)
TEST(Segmentation, TheHardScenesShaftIsFoundWhereAnotherInstrumentsJawsTouchIt) {
  HardScene hard;
  double best = 1e9;
  hard.throughPipeline(colourPipelineParams(), 200, 283, [&](int k, std::vector<SyntheticView> const& views, PipelineOutput const& out) {
    if (k < 283) return;
    ApparentContour const& truth = views[1].truth;  // the right shaft
    EXPECT_GT(truth.entry_px.x(), 630.0);
    for (auto const& c : out.segmentation.contours) best = std::min(best, lineErrorOverItsExtent(c, truth));
  });
  EXPECT_LT(best, 1.0);
}


// duplicatesAShaft(), exact geometry: a shaft 40 px wide along y = 240 from x = 0 to 400. A
// contour inside its strip (entry and tip within 20 px of its axis) is a second detection of it
// at 6 deg (hard scene frame 299's stub) or 10 deg off; not one beside it (a width away), nor one
// crossing it at 30 deg, nor one inside the strip's width at one end only.
TEST(Segmentation, ASecondDetectionInsideAShaftsStripIsADuplicate) {
  std::vector<ApparentContour> const found{bandContour({0, 240}, {400, 240}, 20)};
  double const t6 = std::tan(6.0 * M_PI / 180.0), t10 = std::tan(10.0 * M_PI / 180.0);
  EXPECT_TRUE(duplicatesAShaft(bandContour({0, 244}, {190, 244 - 190 * t6}, 18), found));
  EXPECT_TRUE(duplicatesAShaft(bandContour({0, 248}, {100, 248 - 100 * t10}, 18), found));
  EXPECT_FALSE(duplicatesAShaft(bandContour({0, 280}, {400, 280}, 20), found));  // side by side
  EXPECT_FALSE(duplicatesAShaft(bandContour({100, 300}, {300, 300 - 200 * std::tan(M_PI / 6)}, 18), found));  // crossing
  EXPECT_FALSE(duplicatesAShaft(bandContour({0, 244}, {300, 244 - 300 * t6}, 18), found));  // leaves the strip
}

// narrowerDuplicates(), exact geometry: a shaft 80 px wide along y = 240 and a strip 30 px wide
// inside it along its upper edge (the strip between an edge and a printed label). The strip is
// the duplicate whichever was found first; the whole shaft never is. A shaft beside another, or
// crossing it, is no duplicate; of two equal detections the later one is.
TEST(Segmentation, AStripInsideAWiderShaftIsTheDuplicateInEitherOrder) {
  // shaftWidthAt(): the width at the foot of the point on the axis, wherever the point lies.
  ApparentContour cone;  // lines from (0, 200) to (400, 220) and (0, 300) to (400, 280): 100 -> 60 px
  cone.lines = {*lineThrough({400, 220}, {0, 200}), *lineThrough({0, 300}, {400, 280})};
  cone.entry_px = {0, 250};
  cone.tip_px = {400, 250};
  EXPECT_NEAR(shaftWidthAt(cone, {0, 250}), 100.0 * std::cos(std::atan(0.05)), 1e-9);
  EXPECT_NEAR(shaftWidthAt(cone, {200, 250}), shaftWidthAt(cone, {200, 180}), 1e-9);
  EXPECT_NEAR(shaftWidthAt(cone, {400, 250}), 60.0 * std::cos(std::atan(0.05)), 1e-9);
  ApparentContour const whole = bandContour({0, 240}, {400, 240}, 40), strip = bandContour({0, 260}, {300, 258}, 15);
  EXPECT_EQ(narrowerDuplicates({whole, strip}), (std::vector<std::size_t>{1}));
  EXPECT_EQ(narrowerDuplicates({strip, whole}), (std::vector<std::size_t>{0}));
  EXPECT_EQ(narrowerDuplicates({whole, whole}), (std::vector<std::size_t>{1}));
  EXPECT_TRUE(narrowerDuplicates({whole, bandContour({0, 330}, {400, 330}, 40)}).empty());  // side by side
  EXPECT_TRUE(narrowerDuplicates({bandContour({100, 300}, {300, 300 - 200 * std::tan(M_PI / 6)}, 15), whole}).empty());  // crossing
  // Three: a strip inside the whole shaft and a shaft beside them; only the strip goes.
  EXPECT_EQ(narrowerDuplicates({strip, bandContour({0, 400}, {400, 420}, 30), whole}), (std::vector<std::size_t>{0}));
}

// overlappingDuplicates(), exact geometry: a shaft 80 px wide along y = 240 from x = 0 to 250
// (quadrilateral area 20000 px^2) and a wedge from the border to x = 300 between a line across
// the shaft (y = 210 + x / 6) and a tissue edge below it (y = 290 + x / 10): area 21000, of
// which 12292 lie in the shaft, 0.43 of the union (in-vivo OP2/img_34: 0.47). Of the two the one
// whose lines fit worse goes, in either order; a shaft beside or crossing another stays, and of
// three bands each overlapping the next (0.45 of the union; the first and the last 0.14) only
// the middle one goes.
TEST(Segmentation, OfTwoOverlappingContoursTheWorseFitIsTheDuplicate) {
  ApparentContour whole = bandContour({0, 240}, {250, 240}, 40);
  whole.residual_px = 0.32;
  ApparentContour wedge;
  wedge.lines = {*lineThrough({0, 210}, {300, 260}), *lineThrough({0, 290}, {300, 320})};
  wedge.entry_px = {0, 250};
  wedge.tip_px = {300, 290};
  wedge.residual_px = 0.56;
  EXPECT_EQ(overlappingDuplicates({whole, wedge}), (std::vector<std::size_t>{1}));
  EXPECT_EQ(overlappingDuplicates({wedge, whole}), (std::vector<std::size_t>{0}));
  wedge.residual_px = 0.2;  // the better fit is kept, whichever it is
  EXPECT_EQ(overlappingDuplicates({whole, wedge}), (std::vector<std::size_t>{0}));
  EXPECT_EQ(overlappingDuplicates({whole, whole}), (std::vector<std::size_t>{1}));  // equal: the later goes
  // A wider wedge: the tissue edge 30 px lower (area 30000, 12292 in the shaft: 0.33 of the union,
  // just under kMaxShaftOverlap).
  ApparentContour low = wedge;
  low.lines[1] = *lineThrough({0, 320}, {300, 350});
  EXPECT_TRUE(overlappingDuplicates({whole, low}).empty());
  EXPECT_TRUE(overlappingDuplicates({whole, bandContour({0, 330}, {400, 330}, 40)}).empty());  // side by side
  // Crossing at 30 deg, 30 px wide, 57 % of its area over the whole shaft: 0.17 of the union.
  EXPECT_TRUE(overlappingDuplicates({bandContour({100, 300}, {300, 300 - 200 * std::tan(M_PI / 6)}, 15), whole}).empty());
  ApparentContour a = bandContour({0, 240}, {400, 240}, 40), b = bandContour({0, 270}, {400, 270}, 40),
                  c = bandContour({0, 300}, {400, 300}, 40);
  a.residual_px = 0.2;
  b.residual_px = 0.3;
  c.residual_px = 0.4;
  EXPECT_EQ(overlappingDuplicates({c, b, a}), (std::vector<std::size_t>{1}));
  EXPECT_TRUE(overlappingDuplicates({}).empty());
}
