// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>
#include <random>

#include "endo_guidance/core/contour_lines.h"
#include "endo_guidance/core/cylinder_pose.h"
#include "endo_guidance/core/scene_renderer.h"
#include "endo_guidance/core/segmentation.h"

using namespace endo_guidance;

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
  // A flat image has no edge.
  cv::Mat flat(100, 100, CV_8UC3, cv::Scalar(60, 70, 170));
  EXPECT_FALSE(refineLineSubpixel(flat, start, 5.0, 95.0, p));
}

TEST(ContourLines, RenderedShaftMatchesTruthAndBlobIsRejected) {
  SyntheticScene scene(defaultInstruments());
  RenderOptions ro;
  ro.specular = false;
  SceneRenderer renderer(640, 480, ro);
  // Frame 60: three separate shafts (see test_segmentation for whole sequences).
  auto const views = scene.frame(60);
  InstrumentSegmenter seg;
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
  EXPECT_TRUE(InstrumentSegmenter().process(img).contours.empty());
}
