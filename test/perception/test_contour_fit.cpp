// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <algorithm>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <random>

#include "endo_guidance/geometry/cylinder_pose.h"
#include "endo_guidance/perception/colour_feature.h"
#include "endo_guidance/perception/contour_fit.h"
#include "endo_guidance/perception/rectification.h"
#include "endo_guidance/perception/segmentation.h"
#include "endo_guidance/sim/scene_renderer.h"

#include "colour_params.h"

using namespace endo_guidance::perception;
using namespace endo_guidance::geometry;
using namespace endo_guidance::sim;
using endo_guidance::test::colourParams;

TEST(ContourLines, LMedSSurvivesOutliers) {
  std::mt19937_64 rng(1);
  std::uniform_real_distribution<double> U(0, 100);
  std::vector<Eigen::Vector2d> pts;
  for (int i = 0; i < 60; ++i) pts.emplace_back(i, 0.5 * i + 3.0);  // y = 0.5 x + 3
  for (int i = 0; i < 40; ++i) pts.emplace_back(U(rng), U(rng));
  auto const l = fitLineLMedS(pts, 200, 3);
  ASSERT_TRUE(l);
  Eigen::Vector3d const truth = Eigen::Vector3d(0.5, -1.0, 3.0) / std::hypot(0.5, 1.0);
  EXPECT_LT(std::min((l->line - truth).norm(), (l->line + truth).norm()), 1e-9);
  EXPECT_GE(l->inliers.size(), 60u);
  EXPECT_LE(l->inliers.size(), 66u);
}

TEST(ContourLines, SubpixelEdgeOfAnAntiAliasedStep) {
  // Red tissue left of a grey band whose edge is the exact line x = 40.3 + 0.1 y (coverage
  // rendered by area), as the renderer does.
  cv::Mat img(100, 100, CV_8UC3);
  ImageLine const edge = *normalizeLine(Eigen::Vector3d(1.0, -0.1, -40.3));  // positive: shaft side
  for (int y = 0; y < 100; ++y)
    for (int x = 0; x < 100; ++x) {
      double const s = edge.dot(Eigen::Vector3d(x, y, 1.0));
      double const cov = std::clamp(0.5 + s, 0.0, 1.0);
      cv::Vec3d const tissue(60, 70, 170), grey(130, 130, 134);
      cv::Vec3d const c = tissue * (1 - cov) + grey * cov;
      img.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uchar>(c[0]), cv::saturate_cast<uchar>(c[1]), cv::saturate_cast<uchar>(c[2]));
    }
  ContourLinesParams p;
  ImageLine const start = *normalizeLine(Eigen::Vector3d(1.0, -0.1, -43.0));  // 2.7 px off
  // The final, narrow window (+-3.5 px) cannot centre on an edge 2.7 px away: every profile is
  // refused rather than biased. The wide first pass can, and the narrow one then refines.
  EXPECT_FALSE(refineLineSubpixel(img, start, 5.0, 95.0, p));
  ContourLinesParams wide = p;
  wide.refine_halfwidth_px = p.coarse_halfwidth_px;
  auto const r0 = refineLineSubpixel(img, start, 5.0, 95.0, wide);
  ASSERT_TRUE(r0);
  auto const r = refineLineSubpixel(img, r0->line, 5.0, 95.0, p);
  ASSERT_TRUE(r);
  // Distance between the lines at y = 10 and y = 90.
  for (double y : {10.0, 90.0}) {
    double const x = -(r->line.y() * y + r->line.z()) / r->line.x();
    EXPECT_NEAR(edge.dot(Eigen::Vector3d(x, y, 1.0)), 0.0, 0.03) << "y " << y;
  }
  EXPECT_GT(r->line.head<2>().dot(edge.head<2>()), 0.99);  // orientation kept
  EXPECT_LT(r->residual_px, 0.05);
  EXPECT_GT(r->covariance.trace(), 0.0);
  // The covariance: the residuals' part is tiny on this clean step; the systematic floor gives
  // each end of the line a standard deviation of line_sigma_floor_px across it.
  for (double floor : {0.0, 0.25}) {
    ContourLinesParams pf = p;
    pf.line_sigma_floor_px = floor;
    auto const rf = refineLineSubpixel(img, r0->line, 5.0, 95.0, pf);
    ASSERT_TRUE(rf);
    for (double y : {5.0, 95.0}) {
      Eigen::Vector3d const end(-(rf->line.y() * y + rf->line.z()) / rf->line.x(), y, 1.0);
      double const sd = std::sqrt(end.dot(rf->covariance * end));  // of the line's distance at the end
      if (floor > 0.0) EXPECT_NEAR(sd, floor, 0.03) << "y " << y;
      else EXPECT_LT(sd, 0.03) << "y " << y;
    }
  }
  // A flat image has no edge.
  cv::Mat flat(100, 100, CV_8UC3, cv::Scalar(60, 70, 170));
  EXPECT_FALSE(refineLineSubpixel(flat, start, 5.0, 95.0, p));
}

// A short stub's side: the edge x = 40.3 + 0.1 y over y < 40, tissue on both sides beyond, and
// 45 px further on a jaw's edge 3.5 px inside the line (y 84-90). From a least-squares start the
// few jaw points tilt the line by their leverage and the biweight keeps them (an axis degrees
// off on rendered stubs); the line must stay on the shaft's edge.
TEST(ContourLines, AFewEdgePointsFarAlongTheLineDoNotTiltIt) {
  cv::Mat img(100, 100, CV_8UC3);
  ImageLine const edge = *normalizeLine(Eigen::Vector3d(1.0, -0.1, -40.3));  // positive: shaft side
  ImageLine const jaw = *normalizeLine(Eigen::Vector3d(1.0, -0.1, -43.8));
  for (int y = 0; y < 100; ++y)
    for (int x = 0; x < 100; ++x) {
      double const s = y < 40 ? edge.dot(Eigen::Vector3d(x, y, 1.0)) : y >= 84 && y <= 90 ? jaw.dot(Eigen::Vector3d(x, y, 1.0)) : -10.0;
      double const cov = std::clamp(0.5 + s, 0.0, 1.0);
      cv::Vec3d const tissue(60, 70, 170), grey(130, 130, 134);
      cv::Vec3d const c = tissue * (1 - cov) + grey * cov;
      img.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uchar>(c[0]), cv::saturate_cast<uchar>(c[1]), cv::saturate_cast<uchar>(c[2]));
    }
  ContourLinesParams const wide = widePass(ContourLinesParams());
  auto const r = refineLineSubpixel(img, edge, 2.0, 97.0, wide);
  ASSERT_TRUE(r);
  for (double y : {2.0, 40.0, 90.0}) {
    double const x = -(r->line.y() * y + r->line.z()) / r->line.x();
    EXPECT_NEAR(edge.dot(Eigen::Vector3d(x, y, 1.0)), 0.0, 0.1) << "y " << y;
  }
}

// The step above with textured tissue (its chroma varies by up to 12 units from pixel to pixel)
// beside flat metal: the whole +-2.5 px window takes the texture's descents on the tissue side
// and drops its ascents (only descents weigh), which moves every edge point outward; the edge's
// own slope lobe takes in only the texture next to the edge (half the bias; in the rendered
// clean scene the lines' error fell from 0.013 / 0.039 px, median / p95, to 0.007 / 0.017).
TEST(ContourLines, SubpixelEdgeIsNotPulledByTheTissueTexture) {
  cv::Mat img(100, 100, CV_8UC3);
  ImageLine const edge = *normalizeLine(Eigen::Vector3d(1.0, -0.1, -40.3));  // positive: shaft side
  cv::Vec3d const grey(130, 130, 134);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  for (int y = 0; y < 100; ++y)
    for (int x = 0; x < 100; ++x) {
      double const s = edge.dot(Eigen::Vector3d(x, y, 1.0));
      double const cov = std::clamp(0.5 + s, 0.0, 1.0);
      double const t = U(rng);
      cv::Vec3d const tissue(60 - 4 * t, 70 - 4 * t, 170 + 8 * t);  // chroma 110 +- 12
      cv::Vec3d const c = tissue * (1 - cov) + grey * cov;
      img.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uchar>(c[0]), cv::saturate_cast<uchar>(c[1]), cv::saturate_cast<uchar>(c[2]));
    }
  ImageLine const start = *normalizeLine(Eigen::Vector3d(1.0, -0.1, -40.8));
  auto offset = [&](ContourLinesParams const& p) {  // of the refined line from the edge, mean of y = 10 and 90
    auto const r = refineLineSubpixel(img, start, 5.0, 95.0, p);
    if (!r) return 1e9;
    double sum = 0.0;
    for (double y : {10.0, 90.0}) {
      double const x = -(r->line.y() * y + r->line.z()) / r->line.x();
      sum += 0.5 * edge.dot(Eigen::Vector3d(x, y, 1.0));
    }
    return sum;
  };
  ContourLinesParams p;
  double const lobe = offset(p);
  p.edge_lobe_floor = -1.0;  // the whole window
  double const window = offset(p);
  EXPECT_LT(window, -0.04);  // outward (measured -0.052)
  EXPECT_LT(std::abs(lobe), 0.6 * std::abs(window)) << "lobe " << lobe << " window " << window;  // (measured -0.025)
}

// A shaft as chromatic as the tissue beside it (a grey shaft on grey fat, darker by 50 levels):
// the chroma has no edge there, the colour along sideColourDirection() has, found as exactly as
// in the chroma. The direction points from the shaft's colour to the tissue's.
TEST(ContourLines, SubpixelEdgeAlongTheSidesColourDirection) {
  cv::Mat img(100, 100, CV_8UC3);
  ImageLine const edge = *normalizeLine(Eigen::Vector3d(1.0, -0.1, -40.3));  // positive: shaft side
  cv::Vec3d const tissue(150, 160, 175), shaft(100, 110, 125);  // chroma 25 both
  for (int y = 0; y < 100; ++y)
    for (int x = 0; x < 100; ++x) {
      double const cov = std::clamp(0.5 + edge.dot(Eigen::Vector3d(x, y, 1.0)), 0.0, 1.0);
      cv::Vec3d const c = tissue * (1 - cov) + shaft * cov;
      img.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uchar>(c[0]), cv::saturate_cast<uchar>(c[1]), cv::saturate_cast<uchar>(c[2]));
    }
  ImageLine const start = *normalizeLine(Eigen::Vector3d(1.0, -0.1, -42.0));  // the mask's side, 1.7 px in
  ContourLinesParams p;
  ContourLinesParams wide = widePass(p);
  EXPECT_FALSE(refineLineSubpixel(img, start, 5.0, 95.0, wide));
  auto const dir = sideColourDirection(img, start, 5.0, 95.0, 4.0, 5.0);
  ASSERT_TRUE(dir);
  EXPECT_NEAR((*dir - Eigen::Vector3f(1, 1, 1).normalized()).norm(), 0.0, 1e-6);
  auto const r0 = refineLineSubpixel(img, start, 5.0, 95.0, wide, &*dir);
  ASSERT_TRUE(r0);
  auto const r = refineLineSubpixel(img, r0->line, 5.0, 95.0, p, &*dir);
  ASSERT_TRUE(r);
  for (double y : {10.0, 90.0}) {
    double const x = -(r->line.y() * y + r->line.z()) / r->line.x();
    EXPECT_NEAR(edge.dot(Eigen::Vector3d(x, y, 1.0)), 0.0, 0.02) << "y " << y;
  }
  EXPECT_GT(r->line.head<2>().dot(edge.head<2>()), 0.99);  // (the shaft on its positive side)
  // The direction reversed (a shaft brighter than the tissue, as taken) has no descent into it.
  ColourDirection const reversed = -*dir;
  EXPECT_FALSE(refineLineSubpixel(img, r->line, 5.0, 95.0, p, &reversed));
  // Uniform colour: no direction.
  cv::Mat const flat(100, 100, CV_8UC3, cv::Scalar(150, 160, 175));
  EXPECT_FALSE(sideColourDirection(flat, start, 5.0, 95.0, 4.0, 5.0));
}

// edgeChannel(): the chroma max - min, exactly.
TEST(ContourLines, EdgeChannelIsTheChroma) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> U(0.f, 255.f);
  for (int i = 0; i < 1000; ++i) {
    float const b = U(rng), g = U(rng), r = U(rng);
    EXPECT_EQ(edgeChannel(b, g, r), ColourFeature::chroma(b, g, r));
  }
}

// The profiles' fast edge-channel samplers (SIMD, channels in the lanes) and the reference one
// (one sample at a time) are the same bilinear chroma, sample for sample: on random colours,
// along random profiles, some reaching the image's last two columns (where the fast ones take
// the reference path). A lane mixed up (the 4th byte loaded is the next pixel's blue) changes them.
TEST(ContourLines, FastChromaSamplerMatchesTheReferenceOne) {
  cv::Mat img(80, 120, CV_8UC3);
  cv::randu(img, 0, 256);
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  // Both fast samplers: eight samples per step where the CPU has AVX2 (profiles of 25: three
  // steps and an overlapping last one), one (SSE2) without it or with OpenCV's optimisations off.
  for (bool optimised : {true, false}) {
    cv::setUseOptimized(optimised);
    int compared = 0;
    for (int k = 0; k < 500; ++k) {
      int const count = 1 + static_cast<int>(u(rng) * 40);
      Eigen::Vector2d const d = 0.5 * Eigen::Vector2d(std::cos(6.3 * u(rng)), std::sin(6.3 * u(rng))).normalized();
      Eigen::Vector2d const a(1.0 + u(rng) * 117.0, 1.0 + u(rng) * 77.0);
      Eigen::Vector2d const b = a + (count - 1) * d;
      if (!(std::min(a.x(), b.x()) >= 0.0 && std::min(a.y(), b.y()) >= 0.0 && std::max(a.x(), b.x()) < img.cols - 1 &&
            std::max(a.y(), b.y()) < img.rows - 1))
        continue;  // (the samplers' contract: every sample inside the image)
      std::vector<float> fast(static_cast<std::size_t>(count)), ref(static_cast<std::size_t>(count));
      sampleEdgeChannel(img, a, d, count, fast.data());
      sampleEdgeChannel(img, a, d, count, ref.data(), true);
      ASSERT_EQ(fast, ref) << "profile " << k << " optimised " << optimised;
      ++compared;
    }
    EXPECT_GT(compared, 100);
  }
  cv::setUseOptimized(true);
}

// refineContour()'s wide pass reuses the profiles scoreSides() took (every third of its own):
// the contour is the same, bit for bit, as without them; and they are used (moved, they move it).
TEST(ContourLines, ScoredProfilesAreReusedExactly) {
  SyntheticScene scene(defaultInstruments());
  SceneRenderer renderer(640, 480, RenderOptions{});
  cv::Mat const img = renderer.render(scene.frame(60), 60);
  InstrumentSegmenter seg(colourParams());
  SegmentationResult const res = seg.process(img);
  int checked = 0;
  for (std::size_t i = 0; i < res.regions.size(); ++i) {
    if (res.region_status[i] != ContourRejection::kNone) continue;
    ContourLinesParams const p;
    SideFit const fit = fitSides(res.regions[i], seg.fieldOfView(), res.scale, p);
    if (fit.rejection != ContourRejection::kNone) continue;
    SideFit scored = fit;
    ASSERT_GT(scoreSides(scored, img, p), 0.0);
    for (auto const& pe : scored.scored) {
      EXPECT_EQ(pe.step, p.score_step_px);
      EXPECT_GT(pe.edges.size(), 10u);
    }
    ContourFit const a = refineContour(scored, res.regions[i], seg.fieldOfView(), img, res.scale, p);
    ContourFit const b = refineContour(fit, res.regions[i], seg.fieldOfView(), img, res.scale, p);
    ASSERT_TRUE(a.contour && b.contour);
    for (int k = 0; k < 2; ++k) EXPECT_EQ(a.contour->lines[k], b.contour->lines[k]) << "region " << i << " line " << k;
    EXPECT_EQ(a.edge_points, b.edge_points);
    // Moved 3 px, the reused edges pull the wide pass's line: the result changes.
    SideFit moved = scored;
    for (auto& pe : moved.scored)
      for (auto& q : pe.edges)
        if (q) *q += Eigen::Vector2d(3.0, 3.0);
    ContourFit const c = refineContour(moved, res.regions[i], seg.fieldOfView(), img, res.scale, p);
    EXPECT_TRUE(!c.contour || c.contour->lines[0] != a.contour->lines[0] || c.contour->lines[1] != a.contour->lines[1]);
    // A side whose line changed after the scoring takes none of them: as if never scored.
    SideFit changed = scored, changed_fresh = fit;
    for (SideFit* f : {&changed, &changed_fresh}) f->lines[0].z() += 0.5;
    ContourFit const d = refineContour(changed, res.regions[i], seg.fieldOfView(), img, res.scale, p);
    ContourFit const e = refineContour(changed_fresh, res.regions[i], seg.fieldOfView(), img, res.scale, p);
    ASSERT_EQ(d.contour.has_value(), e.contour.has_value());
    if (d.contour) {
      for (int k = 0; k < 2; ++k) EXPECT_EQ(d.contour->lines[k], e.contour->lines[k]);
    }
    ++checked;
  }
  EXPECT_GE(checked, 2);
}

TEST(ContourLines, RenderedShaftMatchesTruthAndBlobIsRejected) {
  SyntheticScene scene(defaultInstruments());
  RenderOptions ro;
  ro.specular = false;
  SceneRenderer renderer(640, 480, ro);
  // Frame 60: three separate shafts (see test_segmentation for whole sequences).
  auto const views = scene.frame(60);
  InstrumentSegmenter seg(colourParams());
  auto const res = seg.process(renderer.render(views, 60));
  int matched = 0;
  for (auto const& v : views)
    for (auto const& c : res.contours) {
      double e = 0.0;
      for (int k = 0; k < 2; ++k)
        for (Eigen::Vector2d const& q : {v.truth.entry_px, v.truth.tip_px}) {
          Eigen::Vector2d const f = q - v.truth.lines[k].head<2>() * v.truth.lines[k].dot(Eigen::Vector3d(q.x(), q.y(), 1.0));
          e = std::max(e, std::abs(c.lines[k].dot(Eigen::Vector3d(f.x(), f.y(), 1.0))));
        }
      if (e < 0.25) ++matched;  // both lines within 0.25 px over the whole visible shaft
    }
  EXPECT_GE(matched, 2);
  // A round blob on the border is not a shaft.
  cv::Mat img(240, 320, CV_8UC3, cv::Scalar(60, 70, 170));
  cv::circle(img, {160, 239}, 60, cv::Scalar(140, 140, 140), -1, cv::LINE_AA);
  EXPECT_TRUE(InstrumentSegmenter(colourParams()).process(img).contours.empty());
}

TEST(ContourLines, RectifiedContourOfDistortedEdgesIsTheStraightLine) {
  // Edge points sampled on two straight lines of the rectified camera, distorted with a strong
  // barrel distortion (plumb_bob k1 = -0.3, k2 = 0.1), must come back as those lines.
  cv::Matx33d const K(500, 0, 319.5, 0, 500, 239.5, 0, 0, 1);
  cv::Vec<double, 5> const D(-0.3, 0.1, 0.001, -0.001, 0.0);
  ApparentContour truth;
  truth.lines = {*lineThrough({20, 60}, {400, 300}), *lineThrough({400, 330}, {20, 90})};  // shaft between
  truth.entry_px = {20, 75};
  truth.tip_px = {400, 315};
  Eigen::Vector3d const mid(210, 195, 1);
  for (auto& l : truth.lines)
    if (l.dot(mid) < 0) l = -l;  // the shaft on the positive side
  auto distort = [&](Eigen::Vector2d const& p) {
    double const x = (p.x() - K(0, 2)) / K(0, 0), y = (p.y() - K(1, 2)) / K(1, 1), r2 = x * x + y * y;
    double const rad = 1 + D[0] * r2 + D[1] * r2 * r2;
    double const xd = x * rad + 2 * D[2] * x * y + D[3] * (r2 + 2 * x * x), yd = y * rad + D[2] * (r2 + 2 * y * y) + 2 * D[3] * x * y;
    return Eigen::Vector2d(K(0, 0) * xd + K(0, 2), K(1, 1) * yd + K(1, 2));
  };
  auto rectify = [&](Eigen::Vector2d const& p) {
    std::vector<cv::Point2d> in{{p.x(), p.y()}}, out;
    cv::undistortPoints(in, out, K, D, cv::noArray(), K, cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 100, 1e-12));
    return Eigen::Vector2d(out[0].x, out[0].y);
  };
  std::array<std::vector<Eigen::Vector2d>, 2> edges;
  ApparentContour distorted = truth;
  for (int s = 0; s < 2; ++s) {
    Eigen::Vector2d const a = footOnLine(truth.lines[s], truth.entry_px), b = footOnLine(truth.lines[s], truth.tip_px);
    for (int i = 0; i <= 60; ++i) edges[s].push_back(distort(a + (b - a) * (i / 60.0)));
    // The distorted fit: the chord of the curved edge (what the segmentation sees).
    distorted.lines[s] = *lineThrough(edges[s].front(), edges[s].back());
    if (distorted.lines[s].head<2>().dot(truth.lines[s].head<2>()) < 0) distorted.lines[s] = -distorted.lines[s];
  }
  distorted.entry_px = distort(truth.entry_px);
  distorted.tip_px = distort(truth.tip_px);
  // Without correction the lines are visibly wrong (the test can fail).
  double off = 0.0;
  for (int s = 0; s < 2; ++s) off = std::max(off, std::abs(distorted.lines[s].dot(Eigen::Vector3d(truth.tip_px.x(), truth.tip_px.y(), 1)) -
                                                            truth.lines[s].dot(Eigen::Vector3d(truth.tip_px.x(), truth.tip_px.y(), 1))));
  EXPECT_GT(off, 0.3);
  auto const r = rectifyContour(distorted, edges, rectify);
  ASSERT_TRUE(r);
  for (int s = 0; s < 2; ++s) {
    EXPECT_LT((r->lines[s] - truth.lines[s]).norm(), 1e-5) << s;
    EXPECT_LT(r->line_residual_px[s], 1e-3);
  }
  EXPECT_LT((r->entry_px - truth.entry_px).norm(), 1e-3);
  EXPECT_LT((r->tip_px - truth.tip_px).norm(), 1e-3);
  // Too few points: refused, not guessed.
  std::array<std::vector<Eigen::Vector2d>, 2> few{std::vector<Eigen::Vector2d>(edges[0].begin(), edges[0].begin() + 3), edges[1]};
  EXPECT_FALSE(rectifyContour(distorted, few, rectify));
}

// A strip between two vertical lines, x in [100, 140], from the bottom border (entry) up to
// y = 60 (tip), on red tissue; `fill` paints its inside.
namespace {
ApparentContour verticalStrip() {
  ApparentContour c;
  c.lines = {ImageLine(1.0, 0.0, -100.0), ImageLine(-1.0, 0.0, 140.0)};  // normals into the strip
  c.entry_px = Eigen::Vector2d(120.0, 239.0);
  c.tip_px = Eigen::Vector2d(120.0, 60.0);
  return c;
}
}  // namespace

TEST(ContourLines, GlareBetweenTheLinesIsNotAShaft) {
  ContourLinesParams const p;  // max_glare_fraction 0.5
  ApparentContour const c = verticalStrip();
  cv::Mat img(240, 320, CV_8UC3, cv::Scalar(60, 70, 170));  // BGR: red tissue
  // A grey shaft with one highlight streak along it (a sixth of its width): a shaft.
  cv::rectangle(img, cv::Point(100, 0), cv::Point(140, 239), cv::Scalar(110, 110, 110), cv::FILLED);
  cv::rectangle(img, cv::Point(117, 0), cv::Point(123, 239), cv::Scalar(250, 250, 250), cv::FILLED);
  AcrossSamples s = acrossContour(img, c);
  EXPECT_EQ(s.inside.size(), 39u * 3u);
  EXPECT_EQ(s.outside[0].size(), 39u);
  EXPECT_EQ(s.outside[1].size(), 39u);
  EXPECT_EQ(s.glare, 39);  // the middle samples only
  EXPECT_NEAR(s.outside[0].front(), 110.f, 1e-3);  // chroma of the tissue beside the left line
  EXPECT_FALSE(mostlyGlare(img, c, p));
  // A white reflection filling the strip: glare.
  cv::rectangle(img, cv::Point(100, 0), cv::Point(140, 239), cv::Scalar(245, 250, 252), cv::FILLED);
  s = acrossContour(img, c);
  EXPECT_EQ(s.glare, 39 * 3);
  EXPECT_TRUE(mostlyGlare(img, c, p));
  // Bright but coloured (pale pink tissue, chroma >= 30) is not glare; nor is white on half the
  // samples or fewer.
  cv::rectangle(img, cv::Point(100, 0), cv::Point(140, 239), cv::Scalar(200, 205, 245), cv::FILLED);
  EXPECT_EQ(acrossContour(img, c).glare, 0);
  EXPECT_FALSE(mostlyGlare(img, c, p));
  cv::rectangle(img, cv::Point(100, 0), cv::Point(140, 239), cv::Scalar(110, 110, 110), cv::FILLED);
  cv::rectangle(img, cv::Point(100, 160), cv::Point(140, 239), cv::Scalar(250, 250, 250), cv::FILLED);  // toward the entry
  s = acrossContour(img, c);
  EXPECT_GT(s.glare, 0);
  EXPECT_LE(s.glare, static_cast<int>(0.5 * s.inside.size()));
  EXPECT_FALSE(mostlyGlare(img, c, p));
  ContourLinesParams strict = p;
  strict.max_glare_fraction = 0.3;
  EXPECT_TRUE(mostlyGlare(img, c, strict));
  // Samples off the image are left out (a strip reaching past the border).
  ApparentContour off = c;
  off.tip_px = Eigen::Vector2d(120.0, -100.0);
  EXPECT_LT(acrossContour(img, off).inside.size(), 39u * 3u);
}

// Grey shaft right of the exact line x = 40.3 + 0.1 y on red tissue (area coverage), over rows
// y0..y1 only (tissue elsewhere); `offset` shifts the edge by that many px for rows >= y_kink.
namespace {
cv::Mat stepImage(int y0, int y1, double offset = 0.0, int y_kink = 1000) {
  cv::Mat img(200, 100, CV_8UC3, cv::Scalar(60, 70, 170));
  for (int y = y0; y <= y1; ++y)
    for (int x = 0; x < 100; ++x) {
      double const s = x - (40.3 + 0.1 * y) - (y >= y_kink ? offset : 0.0);
      double const cov = std::clamp(0.5 + s, 0.0, 1.0);
      cv::Vec3d const c = cv::Vec3d(60, 70, 170) * (1 - cov) + cv::Vec3d(130, 130, 134) * cov;
      img.at<cv::Vec3b>(y, x) = cv::Vec3b(cv::saturate_cast<uchar>(c[0]), cv::saturate_cast<uchar>(c[1]), cv::saturate_cast<uchar>(c[2]));
    }
  return img;
}
}  // namespace

TEST(ContourLines, RefinedLineIsFollowedAlongItsEdge) {
  ContourLinesParams const p;
  ImageLine const edge = *normalizeLine(Eigen::Vector3d(1.0, -0.1, -40.3));
  Eigen::Vector2d const d(-edge.y(), edge.x());  // t grows with y
  auto tAt = [&](double y) { return d.dot(Eigen::Vector2d(40.3 + 0.1 * y, y)); };
  // The edge runs over rows 5..194; the region side only gave rows 60..90. Followed, the line's
  // points cover the whole edge (each end within a few profiles).
  cv::Mat const img = stepImage(5, 194);
  auto const r = refineLineSubpixel(img, edge, tAt(60), tAt(90), p);
  ASSERT_TRUE(r);
  auto const x = extendLineSubpixel(img, *r, tAt(60), tAt(90), -1e9, 1e9, p);
  ASSERT_TRUE(x);
  double lo = 1e9, hi = -1e9;
  for (auto const& q : x->inliers) {
    lo = std::min(lo, q.y());
    hi = std::max(hi, q.y());
  }
  EXPECT_LT(lo, 12.0);
  EXPECT_GT(hi, 187.0);
  EXPECT_GT(x->points, 3 * r->points);
  for (double y : {5.0, 194.0}) EXPECT_NEAR(x->line.dot(Eigen::Vector3d(40.3 + 0.1 * y, y, 1.0)), 0.0, 0.03) << "y " << y;
  EXPECT_GT(x->line.head<2>().dot(r->line.head<2>()), 0.99);  // orientation kept
  // The limits are kept: only toward larger t, up to row 120.
  auto const up = extendLineSubpixel(img, *r, tAt(60), tAt(90), tAt(60), tAt(120), p);
  ASSERT_TRUE(up);
  for (auto const& q : up->inliers) {
    EXPECT_GE(q.y(), 58.0);
    EXPECT_LE(q.y(), 121.0);
  }
  // A gap longer than extend_max_misses profiles ends the edge: the part beyond is not
  // followed (30 rows with 10 misses allowed; 90 rows with the default 40); a gap of 30 rows
  // is crossed with the default, one of 12 rows with 10.
  ContourLinesParams p10 = p;
  p10.extend_max_misses = 10;
  cv::Scalar const tissue(60, 70, 170);
  cv::Mat gap = stepImage(5, 194);
  cv::rectangle(gap, cv::Point(0, 100), cv::Point(99, 129), tissue, cv::FILLED);
  auto const g = extendLineSubpixel(gap, *r, tAt(60), tAt(90), -1e9, 1e9, p10);
  ASSERT_TRUE(g);
  for (auto const& q : g->inliers) EXPECT_LT(q.y(), 101.0);
  auto const g30 = extendLineSubpixel(gap, *r, tAt(60), tAt(90), -1e9, 1e9, p);
  ASSERT_TRUE(g30);
  double hi30 = 0.0;
  for (auto const& q : g30->inliers) hi30 = std::max(hi30, q.y());
  EXPECT_GT(hi30, 187.0);
  cv::Mat far_gap = stepImage(5, 194);
  cv::rectangle(far_gap, cv::Point(0, 100), cv::Point(99, 189), tissue, cv::FILLED);
  auto const g90 = extendLineSubpixel(far_gap, *r, tAt(60), tAt(90), -1e9, 1e9, p);
  ASSERT_TRUE(g90);
  for (auto const& q : g90->inliers) EXPECT_LT(q.y(), 101.0);
  // Beyond a gap, the edge must hold over 4 profiles in a row: a 5-row piece of it (2-3
  // profiles) between two gaps is not taken, a 12-row piece is.
  for (int piece : {5, 12}) {
    cv::Mat pieces = stepImage(5, 194);
    cv::rectangle(pieces, cv::Point(0, 100), cv::Point(99, 129), tissue, cv::FILLED);
    cv::rectangle(pieces, cv::Point(0, 130 + piece), cv::Point(99, 199), tissue, cv::FILLED);
    auto const gp = extendLineSubpixel(pieces, *r, tAt(60), tAt(90), -1e9, 1e9, p);
    ASSERT_TRUE(gp);
    double hip = 0.0;
    for (auto const& q : gp->inliers) hip = std::max(hip, q.y());
    if (piece == 5) EXPECT_LT(hip, 101.0);
    else EXPECT_GT(hip, 135.0);
  }
  gap = stepImage(5, 194);
  cv::rectangle(gap, cv::Point(0, 100), cv::Point(99, 111), tissue, cv::FILLED);
  auto const g2 = extendLineSubpixel(gap, *r, tAt(60), tAt(90), -1e9, 1e9, p10);
  ASSERT_TRUE(g2);
  double hi2 = 0.0;
  for (auto const& q : g2->inliers) hi2 = std::max(hi2, q.y());
  EXPECT_GT(hi2, 187.0);
  // An edge that steps aside by 2 px (another edge in line: jaws, a touching blob) is not
  // followed past the step, and the line stays the first edge's.
  cv::Mat const kink = stepImage(5, 194, 2.0, 110);
  auto const k = extendLineSubpixel(kink, *r, tAt(60), tAt(90), -1e9, 1e9, p);
  ASSERT_TRUE(k);
  for (auto const& q : k->inliers) EXPECT_LT(q.y(), 112.0);
  for (double y : {5.0, 105.0}) EXPECT_NEAR(k->line.dot(Eigen::Vector3d(40.3 + 0.1 * y, y, 1.0)), 0.0, 0.03) << "y " << y;
  // Not followed at all (0 misses allowed) or no edge beyond: nothing to add.
  ContourLinesParams off = p;
  off.extend_max_misses = 0;
  EXPECT_FALSE(extendLineSubpixel(img, *r, tAt(60), tAt(90), -1e9, 1e9, off));
  cv::Mat const only = stepImage(60, 90);
  EXPECT_FALSE(extendLineSubpixel(only, *r, tAt(60), tAt(90), -1e9, 1e9, p));
}

TEST(ContourLines, AShaftMergedWithGauzeAtItsEntryIsFoundBesideItsStraightSide) {
  // The rendered scene with the gauze blob, frame 60: the bottom shaft's region merges with the
  // gauze near its entry, so that one side is not a straight line from the entry; that side is
  // the stretch of the boundary parallel to the other (SideFit::parallel).
  SyntheticSceneOptions so;
  SyntheticScene scene(defaultInstruments(), so);
  RenderOptions ro;
  ro.membranes = true;
  ro.gauze = true;
  SceneRenderer renderer(so.width, so.height, ro);
  auto const views = scene.frame(60);
  cv::Mat const img = renderer.render(views, 60);
  ApparentContour const& truth = views[0].truth;  // the bottom shaft, entering at the bottom border
  ASSERT_GT(truth.entry_px.y(), 470.0);
  auto found = [&](SegmentationParams const& sp) {
    InstrumentSegmenter seg(sp);
    auto const res = seg.process(img);
    for (auto const& c : res.contours) {
      double e = 0.0;
      for (int k = 0; k < 2; ++k)
        for (Eigen::Vector2d const& q : {truth.entry_px, truth.tip_px}) {
          Eigen::Vector2d const f = footOnLine(truth.lines[k], q);
          e = std::max(e, std::abs(c.lines[k].dot(f.homogeneous())));
        }
      if (e < 1.0) return true;  // both lines within 1 px over the whole shaft
    }
    return false;
  };
  SegmentationParams sp = colourParams();
  sp.strip.enabled = false;  // the region alone
  EXPECT_TRUE(found(sp));
  sp.contours.min_parallel_side_ratio = 0.0;  // no parallel side: the merged region is refused
  EXPECT_FALSE(found(sp));
}

TEST(ContourLines, AShortShaftsSideEndsWhereItsLongerJawBends) {
  // A shaft seen over 20 px from the left border, then its upper jaw, open by 12 deg, 50 px long
  // (the black_circular scene near frame 176): the upper boundary holds more points of the jaw
  // than of the shaft. The side followed from the entry must be the shaft's (horizontal), not
  // the jaw's nor a line between the two.
  cv::Mat bgr(240, 320, CV_8UC3, cv::Scalar(60, 70, 170));
  FieldOfView const fov = detectFieldOfView(bgr);
  cv::Mat feature(bgr.size(), CV_8U, cv::Scalar(200));
  double const a = 12.0 * M_PI / 180.0, len = 50.0;
  cv::Point2d const j(20.0, 100.0);  // the upper side's bend
  std::vector<cv::Point> const body{{0, 100}, {20, 100}, {20 + static_cast<int>(len), 118}, {0, 118}};
  std::vector<cv::Point> const jaw{j, cv::Point2d(j.x + len * std::cos(a), j.y - len * std::sin(a)),
                                   cv::Point2d(j.x + len * std::cos(a) + 8.0 * std::sin(a), j.y - len * std::sin(a) + 8.0 * std::cos(a)),
                                   cv::Point2d(j.x + 8.0 * std::sin(a), j.y + 8.0 * std::cos(a))};
  cv::fillConvexPoly(feature, body, cv::Scalar(10));
  cv::fillConvexPoly(feature, jaw, cv::Scalar(10));
  RegionGrower grower;
  grower.reset(feature, fov);
  auto const region = grower.grow({3, 109}, 30);
  ASSERT_TRUE(region);
  SideFit const fit = fitSides(*region, fov, 1, ContourLinesParams{});
  ASSERT_EQ(fit.rejection, ContourRejection::kNone) << toString(fit.rejection);
  int upper = -1;
  for (int s = 0; s < 2; ++s)
    if (!fit.points[s].empty() && fit.points[s].front().y() < 109.0) upper = s;
  ASSERT_GE(upper, 0);
  // Horizontal through y = 100 (the boundary pixels of the row), within 3 deg and 0.5 px: at
  // most the jaw's first few px, still within the 1 px tolerance of the shaft's line (the jaw is
  // at 12 deg; without the cut the side is the jaw's: 10.4 deg).
  Eigen::Vector3d const& l = fit.lines[upper];
  EXPECT_LT(std::abs(l.x()), std::sin(3.0 * M_PI / 180.0)) << l.transpose();
  EXPECT_NEAR(-l.z() / l.y(), 100.0, 0.5);
  for (auto const& q : fit.points[upper]) EXPECT_LE(q.x(), j.x + 8.0);
}

TEST(ContourLines, TheParallelSideIsBesideTheOtherNotOnATouchingInstrument) {
  // The rendered hard scene, frame 20: the left shaft's region holds the gauze blob at its entry
  // and, at 24, the right shaft touching its tip. Its upper boundary runs along the gauze, the
  // left shaft's upper edge, then the right shaft's (near-parallel too, and longer). The side
  // taken beside the lower one must be the left shaft's own upper edge: before, the longer
  // edge beyond the tip was picked and the pair refused as not parallel.
  SyntheticSceneOptions so;
  so.breathing_amplitude = 0.002;
  SyntheticScene scene(defaultInstruments(), so);
  SceneRenderer renderer(so.width, so.height, hardRenderOptions());
  auto const views = scene.frame(20);
  cv::Mat const img = renderer.render(views, 20);
  ApparentContour const& truth = views[0].truth;  // the left shaft, entering at the bottom
  // The segmenter's own filtered feature and field of view (processing scale 2) for this frame.
  InstrumentSegmenter seg(colourParams());
  seg.process(img);
  FieldOfView const& fov = seg.fieldOfView();
  RegionGrower grower;
  grower.reset(seg.feature(), fov);
  auto const region = grower.grow({46, 236}, 24);  // the seed under the gauze
  ASSERT_TRUE(region);
  ContourLinesParams p;
  SideFit const fit = fitSides(*region, fov, 2, p);
  ASSERT_EQ(fit.rejection, ContourRejection::kNone) << toString(fit.rejection);
  EXPECT_TRUE(fit.parallel);
  EXPECT_TRUE(fit.merged);
  // Each side within 2 deg of one of the true contour lines, one per line.
  auto angle = [](Eigen::Vector3d const& a, Eigen::Vector3d const& b) {
    return std::acos(std::min(1.0, std::abs(a.head<2>().normalized().dot(b.head<2>().normalized())))) * 180.0 / M_PI;
  };
  int const k = angle(fit.lines[0], truth.lines[0]) < angle(fit.lines[0], truth.lines[1]) ? 0 : 1;
  EXPECT_LT(angle(fit.lines[0], truth.lines[k]), 2.0);
  EXPECT_LT(angle(fit.lines[1], truth.lines[1 - k]), 2.0);
  p.min_parallel_side_ratio = 0.0;  // without the parallel side: refused
  EXPECT_NE(fitSides(*region, fov, 2, p).rejection, ContourRejection::kNone);
}

namespace {
// A horizontal shaft entering from the left border of a 320x240 feature image (rows 100..130,
// up to column 200), with low-feature blobs merged with it near the entry: one below it that
// reaches the bottom border (gauze) and, optionally, one across its upper side.
struct MergedShaft {
  cv::Mat feature;
  FieldOfView fov;
  std::optional<Region> region;
};
MergedShaft mergedShaft(bool upper_blob, bool touching_band = false) {
  MergedShaft m;
  cv::Mat const bgr(240, 320, CV_8UC3, cv::Scalar(60, 70, 170));
  m.fov = detectFieldOfView(bgr);
  m.feature = cv::Mat(bgr.size(), CV_8U, cv::Scalar(200));
  cv::rectangle(m.feature, cv::Rect(0, 100, 201, 31), cv::Scalar(10), cv::FILLED);
  cv::circle(m.feature, cv::Point(50, 200), 75, cv::Scalar(12), cv::FILLED);  // below, to the bottom border
  if (upper_blob) cv::circle(m.feature, cv::Point(60, 95), 20, cv::Scalar(12), cv::FILLED);
  if (touching_band) {  // another instrument from the right border, touching the shaft's upper side near its tip
    std::vector<cv::Point> const band{{170, 100}, {195, 100}, {319, 70}, {319, 45}};
    cv::fillConvexPoly(m.feature, band, cv::Scalar(12));
  }
  RegionGrower grower;
  grower.reset(m.feature, m.fov);
  m.region = grower.grow({3, 115}, 30);
  return m;
}
// Whether the fit's lines are the shaft's sides (rows 100 and 130), within 1 deg and 0.5 px.
bool onTheShaftsSides(SideFit const& fit) {
  if (fit.rejection != ContourRejection::kNone) return false;
  bool rows[2] = {false, false};
  for (auto const& l : fit.lines) {
    if (std::abs(l.x()) > std::sin(M_PI / 180.0)) return false;
    double const y = -(l.x() * 150.0 + l.z()) / l.y();
    for (int k = 0; k < 2; ++k) rows[k] = rows[k] || std::abs(y - (k ? 130.0 : 100.0)) < 0.5;
  }
  return rows[0] && rows[1];
}
}  // namespace

TEST(ContourLines, SidesSoughtAgainAsTheStraightStretchesBeyondBlobsOnBothSides) {
  // Blobs across both sides near the entry, the lower one reaching the border: neither side is
  // straight from the entry. Sought again as the best facing pair of straight stretches of the
  // whole boundary (SideSearch::kStretchPair), the sides are the shaft's beyond the blobs.
  // Also with another instrument touching the shaft near its tip and reaching the right border
  // (the hard scene's frames 276-298): the shaft's lower side beyond the blob then lies on the
  // piece of the boundary between the right and bottom border runs, on neither chain that
  // leaves the entry; the stretches are sought on every piece of the boundary.
  for (bool touching : {false, true}) {
    SCOPED_TRACE(touching ? "another instrument touching the tip" : "blobs only");
    auto const m = mergedShaft(true, touching);
    ASSERT_TRUE(m.region);
    ContourLinesParams const p;
    EXPECT_FALSE(onTheShaftsSides(fitSides(*m.region, m.fov, 1, p)));
    SideFit const fit = fitSides(*m.region, m.fov, 1, p, SideSearch::kStretchPair);
    ASSERT_EQ(fit.rejection, ContourRejection::kNone) << toString(fit.rejection);
    EXPECT_TRUE(fit.parallel);
    EXPECT_TRUE(fit.merged);
    EXPECT_TRUE(onTheShaftsSides(fit));
    // Each side from its stretch beyond the blobs only (the upper blob ends at column 80, the
    // lower one at 125).
    for (auto const& side : fit.points)
      for (auto const& q : side) EXPECT_GE(q.x(), 78.0);
  }
}

// The straight-stretch searches (straightRun(): the points within 1 px of each sampled line,
// counted four at a time with AVX2, or one at a time without it or with OpenCV's optimisations
// off) give the same sides, bit for bit, in both paths: on the boundaries of the two merged
// shafts above, with the stretches already taken out of the sequence (straightStretches()) and
// without (parallelSide()).
TEST(ContourLines, StraightStretchSearchIsTheSameInEveryPath) {
  for (bool both : {false, true}) {
    auto const m = mergedShaft(both, both);
    ASSERT_TRUE(m.region);
    ContourLinesParams const p;
    for (SideSearch s : {SideSearch::kParallelFirst, SideSearch::kParallelSecond, SideSearch::kStretchPair}) {
      cv::setUseOptimized(true);
      SideFit const a = fitSides(*m.region, m.fov, 1, p, s);
      cv::setUseOptimized(false);
      SideFit const b = fitSides(*m.region, m.fov, 1, p, s);
      cv::setUseOptimized(true);
      ASSERT_EQ(a.rejection, b.rejection);
      for (int k = 0; k < 2; ++k) {
        EXPECT_EQ(a.lines[k], b.lines[k]) << k;
        EXPECT_EQ(a.points[k], b.points[k]) << k;
      }
    }
  }
  cv::setUseOptimized(true);
}

// fitSidesEach(): the searches on one region, sharing its chains and the sides followed from the
// entry, give each what fitSides() gives alone (the merged shafts above, every search, in two
// orders; a region too small for two sides is refused for each search); also when the shared
// part is taken from a fitSides() of the region (as a re-seek after the first search does).
TEST(ContourLines, SidesSoughtEachWayAtOnceAreTheSameAsOneByOne) {
  std::vector<SideSearch> const all{SideSearch::kFromEntry, SideSearch::kParallelFirst, SideSearch::kParallelSecond,
                                    SideSearch::kStretchPair};
  ContourLinesParams const p;
  for (bool both : {false, true}) {
    auto const m = mergedShaft(both, both);
    ASSERT_TRUE(m.region);
    for (bool reversed : {false, true}) {
      std::vector<SideSearch> order = all;
      if (reversed) std::reverse(order.begin(), order.end());
      SideFit const first = fitSides(*m.region, m.fov, 2, p);
      ASSERT_TRUE(first.chains);
      for (SideFit const* fitted : {static_cast<SideFit const*>(nullptr), &first}) {
        std::vector<SideFit> const each = fitSidesEach(*m.region, m.fov, 2, p, order, fitted);
        ASSERT_EQ(each.size(), order.size());
        int found = 0;
        for (std::size_t i = 0; i < order.size(); ++i) {
          SideFit const one = fitSides(*m.region, m.fov, 2, p, order[i]);
          ASSERT_EQ(each[i].rejection, one.rejection) << i;
          EXPECT_EQ(each[i].parallel, one.parallel) << i;
          EXPECT_EQ(each[i].merged, one.merged) << i;
          for (int k = 0; k < 2; ++k) {
            EXPECT_EQ(each[i].lines[k], one.lines[k]) << i;
            EXPECT_EQ(each[i].points[k], one.points[k]) << i;
          }
          if (fitted) {
            EXPECT_EQ(each[i].chains, first.chains) << i;  // taken, not computed again
          }
          found += one.rejection == ContourRejection::kNone;
        }
        EXPECT_GE(found, 1);
      }
    }
  }
  Region tiny;
  tiny.boundary = {{0, 0}, {1, 0}, {1, 1}};
  FieldOfView fov;
  for (SideFit const& f : fitSidesEach(tiny, fov, 1, p, all)) EXPECT_EQ(f.rejection, ContourRejection::kTooFewPoints);
  SideFit const refused = fitSides(tiny, fov, 1, p);  // (refused before anything is computed: no chains)
  EXPECT_FALSE(refused.chains);
  for (SideFit const& f : fitSidesEach(tiny, fov, 1, p, all, &refused)) EXPECT_EQ(f.rejection, ContourRejection::kTooFewPoints);
}

TEST(ContourLines, ASideSoughtAgainBeyondABlobThatReachesTheBorder) {
  // Only the lower blob: the upper side is straight from the entry, the lower chain runs around
  // the blob to the bottom border and ends there; the shaft's lower side beyond the blob is on
  // the other chain, after the upper side's end. Sought again as the stretch parallel to the
  // upper side (kParallelFirst or kParallelSecond, whichever chain is the lower one), it is found
  // there; from the entry (kFromEntry) it is not.
  auto const m = mergedShaft(false);
  ASSERT_TRUE(m.region);
  ContourLinesParams const p;
  EXPECT_FALSE(onTheShaftsSides(fitSides(*m.region, m.fov, 1, p)));
  int found = 0;
  for (SideSearch s : {SideSearch::kParallelFirst, SideSearch::kParallelSecond}) {
    SideFit const fit = fitSides(*m.region, m.fov, 1, p, s);
    if (!onTheShaftsSides(fit)) continue;
    ++found;
    EXPECT_TRUE(fit.parallel);
  }
  EXPECT_EQ(found, 1);
}

// A shaft entering through a corner of the view: its axis meets the bottom border at 20 deg
// (sine 0.34) and its upper line crosses the right border squarely. With a minimum entry sine of
// 0.5 it is still found: a contour line crosses a border steeply. The same shaft moved left, so
// that its axis and both lines cross the bottom border at 20 deg, is refused: it runs along the
// border.
TEST(ContourLines, AShaftEnteringThroughACornerEntersTheView) {
  double const a = 20.0 * M_PI / 180.0, half = 30.0 / std::cos(a);  // 60 px wide
  auto render = [&](double x_bottom) {  // the axis meets the bottom row at x_bottom
    cv::Mat img(480, 640, CV_8UC3, cv::Scalar(60, 70, 170));
    cv::RNG(5).fill(img, cv::RNG::NORMAL, cv::Scalar(60, 70, 170), cv::Scalar(4, 4, 4));
    auto y = [&](double x, double off) { return 479.0 - std::tan(a) * (x_bottom - x) + off; };
    double const x0 = x_bottom - 350.0, x1 = x_bottom + 200.0;  // tip, and far outside the view
    std::vector<cv::Point> poly;
    for (auto const& [x, off] : {std::pair{x0, -half}, std::pair{x1, -half}, std::pair{x1, half}, std::pair{x0, half}})
      poly.emplace_back(static_cast<int>(std::lround(x * 16)), static_cast<int>(std::lround(y(x, off) * 16)));
    cv::fillConvexPoly(img, poly, cv::Scalar(140, 140, 142), cv::LINE_AA, 4);
    return img;
  };
  SegmentationParams sp = colourParams();
  sp.contours.min_entry_sine = 0.5;
  auto found = [&](cv::Mat const& img, SegmentationParams const& p) {
    auto const res = InstrumentSegmenter(p).process(img);
    for (auto const& c : res.contours)
      if (std::abs(std::atan2(c.tip_px.y() - c.entry_px.y(), c.tip_px.x() - c.entry_px.x()) - (-M_PI + a)) < 0.05) return true;
    return false;
  };
  cv::Mat const corner = render(600.0);
  EXPECT_TRUE(found(corner, sp));
  cv::Mat const bottom = render(420.0);
  EXPECT_FALSE(found(bottom, sp));
  EXPECT_TRUE(found(bottom, SegmentationParams())) << "not found at the default entry sine either: no test";
}
