// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The renderer of the simulator, the tests and the bags draws the exact cylinder: the edges found
// in its images (sub-pixel, chroma) lie on the projected true contour lines (ViSP-checked
// projectCylinder), for random instrument poses, metal and black shafts, 640x480 and 720x576.
#include <gtest/gtest.h>

#include <random>

#include "endo_guidance/perception/contour_fit.h"
#include "endo_guidance/sim/scene_renderer.h"
#include "endo_guidance/sim/synthetic_scene.h"

using namespace endo_guidance::perception;
using namespace endo_guidance::geometry;
using namespace endo_guidance::sim;

namespace {
void checkRenderer(int width, int height, bool black, double* worst, int* lines) {
  std::mt19937_64 rng(width + black);
  std::uniform_real_distribution<double> U(-1.0, 1.0);
  Eigen::Matrix3d const K = (Eigen::Matrix3d() << 550, 0, (width - 1) / 2.0, 0, 550, (height - 1) / 2.0, 0, 0, 1).finished();
  RenderOptions ro;
  ro.black_shafts = black;
  ro.specular = false;  // the highlight stripe is inside the shaft, but keep the edge profile clean
  SceneRenderer renderer(width, height, ro);
  ContourLinesParams p;
  for (int n = 0; n < 40; ++n) {
    Eigen::Vector3d const trocar(0.12 * U(rng), 0.12 * U(rng), 0.02 + 0.01 * U(rng));
    Eigen::Vector3d const tip(0.03 * U(rng), 0.025 * U(rng), 0.12 + 0.03 * U(rng));
    auto const v = viewOfInstrument(K, width, height, trocar, tip, 0.004);
    if (!v) continue;
    cv::Mat const img = renderer.render({*v}, n);
    for (int s = 0; s < 2; ++s) {
      ImageLine const& l = v->truth.lines[s];
      Eigen::Vector2d const d(-l.y(), l.x());
      double t0 = d.dot(footOnLine(l, v->truth.entry_px)), t1 = d.dot(footOnLine(l, v->truth.tip_px));
      if (t0 > t1) std::swap(t0, t1);
      // Stay clear of the image border and of the tip (jaws).
      auto const r = refineLineSubpixel(img, l, t0 + 10.0, t1 - 25.0, p);
      if (!r) continue;
      for (auto const& q : r->inliers) *worst = std::max(*worst, std::abs(l.dot(Eigen::Vector3d(q.x(), q.y(), 1.0))));
      ++*lines;
    }
  }
}
}  // namespace

TEST(SceneRenderer, EdgesLieOnTheProjectedTrueCylinder) {
  for (bool black : {false, true})
    for (auto const& [w, h] : {std::pair{640, 480}, std::pair{720, 576}}) {
      double worst = 0.0;
      int lines = 0;
      checkRenderer(w, h, black, &worst, &lines);
      std::printf("[ renderer ] %dx%d %s shafts: %d contour lines, worst edge point %.3f px from the true line\n", w, h,
                  black ? "black" : "metal", lines, worst);
      EXPECT_GT(lines, 30);
      EXPECT_LT(worst, 0.5);
    }
}

// The training labels: shaft on each shaft's axis, jaws just beyond its tip, background away from
// every instrument, nothing outside a circular view; the image itself unchanged by asking for them.
TEST(SceneRenderer, LabelsMarkShaftsJawsAndBackground) {
  SyntheticSceneOptions const so;
  SyntheticScene scene(defaultInstruments(), so);
  RenderOptions o;
  o.circular_fov = true;
  SceneRenderer const r(so.width, so.height, o);
  auto const views = scene.frame(10);
  ASSERT_GE(views.size(), 2u);
  cv::Mat labels;
  cv::Mat const with = r.render(views, 10, &labels);
  EXPECT_EQ(cv::norm(with, r.render(views, 10), cv::NORM_INF), 0.0);
  ASSERT_EQ(labels.type(), CV_8U);
  ASSERT_EQ(labels.size(), with.size());
  int shaft = 0, jaws = 0;
  for (auto const& v : views) {
    Eigen::Vector2d const d = (v.truth.tip_px - v.truth.entry_px).normalized();
    Eigen::Vector2d const mid = v.truth.tip_px - 30.0 * d;
    if (r.fieldOfView().at<float>(cv::Point(mid.x(), mid.y())) > 0.9f) shaft += labels.at<std::uint8_t>(cv::Point(mid.x(), mid.y())) == 1;
    cv::Rect const near_tip = cv::Rect(static_cast<int>(v.truth.tip_px.x()) - 15, static_cast<int>(v.truth.tip_px.y()) - 15, 31, 31) &
                              cv::Rect(0, 0, labels.cols, labels.rows);
    jaws += cv::countNonZero(labels(near_tip) == 2) >= 10;  // the jaws' wedges about the tip
  }
  EXPECT_GE(shaft, 2);
  EXPECT_GE(jaws, 2);
  EXPECT_EQ(labels.at<std::uint8_t>(0, 0), 0);  // outside the circular view
  EXPECT_EQ(cv::countNonZero(labels > 2), 0);
  EXPECT_LT(cv::countNonZero(labels), labels.total() / 2);
}
