// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The OpenCV baseline (endo_guidance_eval_synthetic --baseline) finds the shafts of the
// clean rendered scene with its lines on the true contours, finds none on tissue alone, and
// refuses a frame of the wrong type: the comparison it feeds is a comparison with a working
// baseline.
#include <gtest/gtest.h>

#include <opencv2/core.hpp>

#include "endo_guidance/sim/scene_renderer.h"
#include "endo_guidance/sim/synthetic_scene.h"
#include "hough_baseline.h"

using namespace endo_guidance::geometry;
using namespace endo_guidance::sim;
using endo_guidance::tools::detectShaftsHough;

namespace {
// Largest distance of the true line's ends (feet of entry and tip) to the estimated line.
double lineError(ImageLine const& est, ImageLine const& truth, ApparentContour const& t) {
  auto foot = [&](Eigen::Vector2d const& q) { return footOnLine(truth, q).homogeneous().eval(); };
  return std::max(std::abs(est.dot(foot(t.entry_px))), std::abs(est.dot(foot(t.tip_px))));
}
}  // namespace

TEST(HoughBaseline, FindsTheCleanSceneShaftsOnTheirTrueLines) {
  SyntheticSceneOptions so;
  SyntheticScene scene(defaultInstruments(), so);
  SceneRenderer renderer(so.width, so.height);
  int shafts = 0, found = 0;
  double worst = 0.0;
  for (int k = 0; k < 300; k += 30) {
    auto const views = scene.frame(k);
    auto const found_contours = detectShaftsHough(renderer.render(views, k));
    for (auto const& v : views) {
      ++shafts;
      ImageLine const ta = imageAxis(v.truth);
      for (auto const& c : found_contours) {
        Eigen::Vector2d const m = 0.5 * (c.entry_px + c.tip_px);
        if (std::abs(ta.head<2>().dot(imageAxis(c).head<2>())) < std::cos(5.0 * M_PI / 180.0) ||
            std::abs(ta.dot(m.homogeneous())) > 12.0)
          continue;
        ++found;
        for (int s = 0; s < 2; ++s) worst = std::max(worst, lineError(c.lines[s], v.truth.lines[s], v.truth));
        // Oriented like the pipeline's contours: normals toward the shaft.
        EXPECT_GT(c.lines[0].dot(m.homogeneous()), 0.0);
        EXPECT_GT(c.lines[1].dot(m.homogeneous()), 0.0);
        break;
      }
    }
  }
  std::printf("[ baseline ] %d of %d shafts found, worst line end %.3f px from the truth\n", found, shafts, found > 0 ? worst : -1.0);
  EXPECT_GE(found, 0.85 * shafts);
  EXPECT_LT(worst, 1.0);
}

TEST(HoughBaseline, NoShaftOnTissueAlone) {
  SceneRenderer renderer(640, 480);
  EXPECT_TRUE(detectShaftsHough(renderer.render({}, 0)).empty());
}

TEST(HoughBaseline, RefusesAFrameThatIsNotBgr) {
  EXPECT_THROW(detectShaftsHough(cv::Mat::zeros(480, 640, CV_8UC1)), cv::Exception);
}
