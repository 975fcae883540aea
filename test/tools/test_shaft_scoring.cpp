// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The strict scoring (shaft_scoring.h) on masks drawn with exactly known sides.
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>

#include "shaft_scoring.h"

using namespace endo_guidance;
using tools::kFoundPx;

namespace {

// A horizontal shaft mask from x = 0 to x = 400, rows [y0, y1] inclusive, jaws beyond x = 400.
struct Scene {
  cv::Mat shaft = cv::Mat::zeros(480, 640, CV_8U), jaws = cv::Mat::zeros(480, 640, CV_8U);
  Scene(int y0, int y1) {
    shaft(cv::Rect(0, y0, 400, y1 - y0 + 1)) = 255;
    jaws(cv::Rect(400, y0 - 10, 60, y1 - y0 + 21)) = 255;
  }
};

// A contour with horizontal lines at rows ya and yb (oriented toward the shaft between them).
geometry::ApparentContour contour(double ya, double yb) {
  geometry::ApparentContour c;
  c.lines[0] = geometry::ImageLine(0.0, 1.0, -ya);   // v - ya >= 0 below ya
  c.lines[1] = geometry::ImageLine(0.0, -1.0, yb);   // yb - v >= 0 above yb
  c.entry_px = {0.0, 0.5 * (ya + yb)};
  c.tip_px = {400.0, 0.5 * (ya + yb)};
  return c;
}

}  // namespace

TEST(ShaftScoring, SidesExcludeTheImageBorderAndTheJaws) {
  Scene s(200, 239);
  tools::MaskShaft const m = tools::maskShaft(s.shaft, s.jaws);
  ASSERT_FALSE(m.sides[0].empty());
  ASSERT_FALSE(m.sides[1].empty());
  for (auto const& side : m.sides)
    for (auto const& q : side) {
      EXPECT_GE(q.x(), tools::kMaskMarginPx);  // not at the image border
      EXPECT_LT(q.x(), 400 - tools::kMaskMarginPx - 1 + 1e-9);  // not within 4 px of the jaws
    }
  // The two sides are the top and bottom rows (the ends across the shaft are near the jaws or the border).
  double const top = tools::sideMedianPx(m.sides[0], geometry::ImageLine(0, 1, -200));
  double const bottom = tools::sideMedianPx(m.sides[1], geometry::ImageLine(0, 1, -239));
  EXPECT_TRUE((top == 0.0 && bottom == 0.0) ||
              (tools::sideMedianPx(m.sides[1], geometry::ImageLine(0, 1, -200)) == 0.0 &&
               tools::sideMedianPx(m.sides[0], geometry::ImageLine(0, 1, -239)) == 0.0));
}

TEST(ShaftScoring, FoundAtEachThresholdAndFalseBeyondTheLast) {
  Scene s(200, 239);
  std::vector<tools::MaskShaft> const shafts{tools::maskShaft(s.shaft, s.jaws)};
  // Lines 1 px off on one side: found at 2, 5 and 10 px.
  auto r = tools::scoreStrict(shafts, {contour(201.0, 239.0)});
  EXPECT_EQ(r.found, (std::array<int, 3>{1, 1, 1}));
  EXPECT_EQ(r.false_detections, 0);
  ASSERT_EQ(r.side_median_px.size(), 2u);
  EXPECT_NEAR(std::max(r.side_median_px[0], r.side_median_px[1]), 1.0, 1e-9);
  // 4 px off: found at 5 and 10 px only; lines given in the other order pair the same way.
  r = tools::scoreStrict(shafts, {contour(239.0, 196.0)});
  EXPECT_EQ(r.found, (std::array<int, 3>{0, 1, 1}));
  // 12 px off (a strip inside the shaft): not found, and false.
  r = tools::scoreStrict(shafts, {contour(212.0, 239.0)});
  EXPECT_EQ(r.found, (std::array<int, 3>{0, 0, 0}));
  EXPECT_EQ(r.false_detections, 1);
  EXPECT_EQ(r.match[0], -1);
}

TEST(ShaftScoring, EachShaftAndDetectionIsUsedOnce) {
  Scene s(200, 239);
  std::vector<tools::MaskShaft> const shafts{tools::maskShaft(s.shaft, s.jaws)};
  // Two detections of one shaft: the closer finds it, the other is false.
  auto const r = tools::scoreStrict(shafts, {contour(203.0, 239.0), contour(200.0, 239.0)});
  EXPECT_EQ(r.found[2], 1);
  EXPECT_EQ(r.false_detections, 1);
  EXPECT_EQ(r.match[0], 1);
  // No detection: the shaft is missed, nothing is false.
  auto const none = tools::scoreStrict(shafts, {});
  EXPECT_EQ(none.found[2], 0);
  EXPECT_EQ(none.false_detections, 0);
  EXPECT_EQ(none.shafts, 1);
}
