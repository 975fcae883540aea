// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// A shaft mask as pairs of straight sides (mask_line_pairs.h) on exact masks: strips drawn from
// their two lines, anti-aliased so that p = 1/2 lies on the lines.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "endo_guidance/perception/image_reduction.h"
#include "endo_guidance/perception/mask_line_pairs.h"

using namespace endo_guidance::perception;

namespace {

constexpr int kW = 320, kH = 240;

// A strip of `width` px about the axis from a to b (b its closed end, a beyond the image when it
// enters there): its two lines, normals into the strip.
struct Strip {
  Eigen::Vector2d a, b;
  double width;
  Eigen::Vector2d u() const { return (b - a).normalized(); }
  Eigen::Vector2d n() const { return {-u().y(), u().x()}; }
  // Signed distance inside (> 0) of x from each side and from the closed end.
  double inside(Eigen::Vector2d const& x) const {
    double const across = 0.5 * width - std::abs(n().dot(x - a)), along = u().dot(b - x);
    return std::min(across, along);
  }
  Eigen::Vector3d line(int k) const {  // k = 0: the side at -n, normal +n; k = 1: at +n, normal -n
    Eigen::Vector2d const nk = k == 0 ? n() : Eigen::Vector2d(-n());
    Eigen::Vector2d const on = a - nk * 0.5 * width;
    return {nk.x(), nk.y(), -nk.dot(on)};
  }
};

// p = clamp(1/2 + signed distance inside the union of the strips, 0, 1), less the cut-outs.
cv::Mat draw(std::vector<Strip> const& strips, std::vector<cv::Rect> const& cuts = {}) {
  cv::Mat p(kH, kW, CV_32F);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      double d = -1e9;
      for (auto const& s : strips) d = std::max(d, s.inside(Eigen::Vector2d(x, y)));
      p.at<float>(y, x) = static_cast<float>(std::clamp(0.5 + d, 0.0, 1.0));
    }
  for (auto const& c : cuts) p(c).setTo(0.0f);
  return p;
}

FieldOfView fullView() { return detectFieldOfView(cv::Mat(kH, kW, CV_8UC3, cv::Scalar(60, 80, 200))); }

// Whether the pair's two lines are the strip's two lines: each within tol_px of one of them at
// both of the given stations along the axis, and facing the same way.
bool pairIsStrip(MaskLinePair const& p, Strip const& s, std::initializer_list<double> stations, double tol_px) {
  for (int k = 0; k < 2; ++k) {
    bool matched = false;
    for (int j = 0; j < 2 && !matched; ++j) {
      Eigen::Vector3d const l = s.line(j);
      if (p.sides[k].line.head<2>().dot(l.head<2>()) < std::cos(2.0 * M_PI / 180.0)) continue;
      matched = true;
      for (double t : stations) {
        Eigen::Vector2d const on = s.a + s.u() * t - l.head<2>() * (l.head<2>().dot(s.a + s.u() * t) + l.z());
        matched = matched && std::abs(p.sides[k].line.dot(on.homogeneous())) <= tol_px;
      }
    }
    if (!matched) return false;
  }
  return true;
}

}  // namespace

TEST(MaskLinePairs, AStripEnteringFromTheBorderIsOnePairOnItsSides) {
  Strip const s{{-20.0, 94.0}, {200.0, 160.0}, 24.0};
  FieldOfView const fov = fullView();
  auto const pairs = findMaskLinePairs(draw({s}), fov, 2, ContourLinesParams{});
  ASSERT_EQ(pairs.size(), 1u);
  EXPECT_TRUE(pairIsStrip(pairs[0], s, {60.0, 180.0}, 0.25));
  EXPECT_NEAR(pairs[0].width, 24.0, 1.5);
  EXPECT_LE(pairs[0].entry.x(), 8.0);  // the entry at the view's left edge
  EXPECT_NEAR((pairs[0].far - s.b).norm(), 0.0, 10.0);  // the far end where the sides end
  // The contour fit's input at full resolution: the same lines through toFullRes() of their points.
  SideFit const f = sideFitOf(pairs[0], 2);
  for (int k = 0; k < 2; ++k) {
    for (auto const& q : pairs[0].sides[k].points)
      EXPECT_NEAR(f.lines[k].dot(toFullRes(q, 2).homogeneous()), 2.0 * pairs[0].sides[k].line.dot(q.homogeneous()), 1e-9);
    EXPECT_GT(f.lines[k].dot(toFullRes(0.5 * (s.a + s.b), 2).homogeneous()), 0.0);  // the shaft on the positive side
  }
  cv::Mat mask;
  cv::compare(draw({s}), 0.5, mask, cv::CMP_GE);
  auto const region = regionOf(pairs[0], mask);
  ASSERT_TRUE(region);
  EXPECT_NEAR(region->area, cv::countNonZero(mask), 0.05 * cv::countNonZero(mask));  // the whole strip
}

namespace {
// Two strips in one mask: two pairs, each on one strip's sides within 1 px at the two stations.
void expectTwoStrips(Strip const& a, std::initializer_list<double> at_a, Strip const& b, std::initializer_list<double> at_b) {
  auto const pairs = findMaskLinePairs(draw({a, b}), fullView(), 2, ContourLinesParams{});
  ASSERT_EQ(pairs.size(), 2u);
  bool const first_is_a = pairIsStrip(pairs[0], a, at_a, 1.0);
  EXPECT_TRUE(pairIsStrip(pairs[first_is_a ? 0 : 1], a, at_a, 1.0));
  EXPECT_TRUE(pairIsStrip(pairs[first_is_a ? 1 : 0], b, at_b, 1.0));
}
}  // namespace

TEST(MaskLinePairs, ShaftsTouchingAtTheirTipsArePairedApart) {
  // One mask component of two shafts in a V: each keeps its own pair of sides.
  expectTwoStrips({{-20.0, 60.0}, {170.0, 130.0}, 22.0}, {40.0, 120.0}, {{250.0, 260.0}, {165.0, 128.0}, 26.0}, {40.0, 110.0});
}

TEST(MaskLinePairs, CrossingShaftsAreTwoPairs) {
  expectTwoStrips({{-20.0, 40.0}, {300.0, 200.0}, 20.0}, {60.0, 300.0}, {{340.0, 30.0}, {60.0, 230.0}, 24.0}, {60.0, 280.0});
}

TEST(MaskLinePairs, AShaftBrokenByAThinOccluderIsOnePair) {
  // A horizontal strip cut across by an 8 px gap (a suture, a thin jaw): two components, one shaft.
  Strip const s{{-20.0, 120.0}, {260.0, 120.0}, 28.0};
  auto const pairs = findMaskLinePairs(draw({s}, {cv::Rect(120, 0, 8, kH)}), fullView(), 2, ContourLinesParams{});
  ASSERT_EQ(pairs.size(), 1u);
  EXPECT_TRUE(pairIsStrip(pairs[0], s, {40.0, 250.0}, 1.0));
  EXPECT_NEAR(pairs[0].far.x(), 260.0, 10.0);  // beyond the gap
}

TEST(MaskLinePairs, NothingFromAnEmptyOrThinMask) {
  ContourLinesParams const p;
  EXPECT_TRUE(findMaskLinePairs(cv::Mat::zeros(kH, kW, CV_32F), fullView(), 2, p).empty());
  // Narrower than min_width_px (8 px at full resolution, 4 here): a crease, not a shaft.
  Strip const thin{{-20.0, 120.0}, {200.0, 100.0}, 3.0};
  EXPECT_TRUE(findMaskLinePairs(draw({thin}), fullView(), 2, p).empty());
}

namespace {
// A wedge entering from the left: its sides through (0, y0 -+ w0 / 2) and (x1, y1 -+ w1 / 2), closed
// at x = x1; anti-aliased as draw().
cv::Mat wedge(double y0, double w0, double x1, double y1, double w1, std::array<Eigen::Vector3d, 2>& lines) {
  for (int k = 0; k < 2; ++k) {
    double const s = k == 0 ? -0.5 : 0.5;
    Eigen::Vector3d l = Eigen::Vector3d(0.0, y0 + s * w0, 1.0).cross(Eigen::Vector3d(x1, y1 + s * w1, 1.0));
    l /= l.head<2>().norm();
    if (l.dot(Eigen::Vector3d(0.5 * x1, 0.5 * (y0 + y1), 1.0)) < 0.0) l = -l;  // positive inside
    lines[k] = l;
  }
  cv::Mat p(kH, kW, CV_32F);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < kW; ++x) {
      double const d = std::min({lines[0].dot(Eigen::Vector3d(x, y, 1)), lines[1].dot(Eigen::Vector3d(x, y, 1)), x1 - x});
      p.at<float>(y, x) = static_cast<float>(std::clamp(0.5 + d, 0.0, 1.0));
    }
  return p;
}

// Whether each of the pair's sides is one of `lines` within tol_px at x = 20 and x = 120.
bool pairOnLines(MaskLinePair const& p, std::array<Eigen::Vector3d, 2> const& lines, double tol_px) {
  for (auto const& side : p.sides) {
    bool matched = false;
    for (auto const& l : lines) {
      if (side.line.head<2>().dot(l.head<2>()) < std::cos(1.0 * M_PI / 180.0)) continue;
      bool near = true;
      for (double x : {20.0, 120.0}) {
        double const y = -(l.x() * x + l.z()) / l.y();  // on l
        near = near && std::abs(side.line.dot(Eigen::Vector3d(x, y, 1.0))) <= tol_px;
      }
      matched = matched || near;
    }
    if (!matched) return false;
  }
  return true;
}
}  // namespace

TEST(MaskLinePairs, ATaperingMaskIsOnePairOnItsSides) {
  // A shaft near the lens narrows fast toward its tip: 70 px wide at the border, 20 px at
  // x = 150, its sides 19 deg apart (max_angle_deg 20 would not pair them as two Hough sides
  // had they been 21 deg apart; a part of the mask on its own is paired up to 35 deg).
  ContourLinesParams p;
  p.max_angle_deg = 10.0;
  std::array<Eigen::Vector3d, 2> lines;
  cv::Mat const m = wedge(120.0, 70.0, 150.0, 110.0, 20.0, lines);
  auto const pairs = findMaskLinePairs(m, fullView(), 2, p);
  ASSERT_EQ(pairs.size(), 1u);
  EXPECT_TRUE(pairOnLines(pairs[0], lines, 0.3));
  EXPECT_LE(pairs[0].entry.x(), 8.0);
  // Sides 53 deg apart are a corner of something, not a shaft.
  EXPECT_TRUE(findMaskLinePairs(wedge(120.0, 150.0, 150.0, 120.0, 6.0, lines), fullView(), 2, p).empty());
}

TEST(MaskLinePairs, AShaftCutLengthwiseByTheBorderKeepsTheSidesItShows) {
  // Entering at the bottom-left corner, 44 px wide: the left and the bottom edge each cut one of
  // its sides short; both sides are still its lines.
  Strip const s{{-40.0, 300.0}, {170.0, 110.0}, 44.0};
  auto const pairs = findMaskLinePairs(draw({s}), fullView(), 2, ContourLinesParams{});
  ASSERT_EQ(pairs.size(), 1u);
  EXPECT_TRUE(pairIsStrip(pairs[0], s, {120.0, 240.0}, 0.3));
  EXPECT_GE(depthAt(fullView(), pairs[0].far), 40.0);  // the far end is the tip, inside the view
}

TEST(MaskLinePairs, AStubEnteringObliquelyAcrossTheBorderIsPairedUpToIt) {
  // A shaft stub 50 px wide entering across the right edge at 30 deg, its jaws (the instrument,
  // not shaft) from x = 280 on in: the edge and the jaws cut each side to 46 px, 29 px apart
  // along the axis. Where the two face each other (17 px) is under half their distance, as a
  // blob's sides; but the view cut them, not the shaft: they are its pair, each up to the edge.
  Eigen::Vector2d const out(std::cos(30.0 * M_PI / 180.0), -std::sin(30.0 * M_PI / 180.0));
  Eigen::Vector2d const b(250.0, 150.0);
  Strip const s{b + 150.0 * out, b, 50.0};
  cv::Mat const instrument = draw({s});
  cv::Mat const shaft = draw({s}, {cv::Rect(0, 0, 280, kH)});
  auto const pairs = findMaskLinePairs(shaft, fullView(), 2, ContourLinesParams{}, instrument);
  ASSERT_EQ(pairs.size(), 1u);
  EXPECT_TRUE(pairIsStrip(pairs[0], s, {90.0, 130.0}, 0.3));
  EXPECT_GE(pairs[0].entry.x(), kW - 9.0);  // the entry at the right edge
  for (int k = 0; k < 2; ++k) {  // each side's points run on to the edge
    double reach = 0.0;
    for (auto const& q : pairs[0].sides[k].points) reach = std::max(reach, q.x());
    EXPECT_GE(reach, kW - 12.0) << "side " << k;
  }
}

TEST(MaskLinePairs, WhereTheInstrumentGoesOnTheShaftsOutlineIsNoSide) {
  // The shaft class along y 98-122 from the left edge to x = 200; its jaws (instrument, not
  // shaft) lie along its lower side from x = 100 on. That stretch of the shaft's outline is the
  // shaft-jaws boundary: with the instrument's probability beyond, no side point lies there.
  Strip const s{{-20.0, 110.0}, {200.0, 110.0}, 24.0};
  cv::Mat const shaft = draw({s});
  cv::Mat instrument = shaft.clone();
  instrument(cv::Rect(100, 110, 100, 40)).setTo(1.0f);
  auto const with = findMaskLinePairs(shaft, fullView(), 2, ContourLinesParams{}, instrument);
  ASSERT_EQ(with.size(), 1u);
  EXPECT_TRUE(pairIsStrip(with[0], s, {20.0, 90.0}, 0.3));
  for (auto const& side : with[0].sides)
    for (auto const& q : side.points)
      if (q.y() > 110.0) {
        EXPECT_LT(q.x(), 100.0);
      }
  // Without it, the lower side runs on along the jaws.
  auto const without = findMaskLinePairs(shaft, fullView(), 2, ContourLinesParams{});
  ASSERT_EQ(without.size(), 1u);
  double reach = 0.0;
  for (auto const& side : without[0].sides)
    for (auto const& q : side.points)
      if (q.y() > 110.0) reach = std::max(reach, q.x());
  EXPECT_GT(reach, 150.0);
}

TEST(MaskLinePairs, AShaftAcrossTheViewEntersAtItsWiderEnd) {
  // Through the whole view, left edge to right edge, 60 px wide at one and 30 px at the other:
  // the wider end is the nearer to the lens, the trocar's side (a shaft narrows toward its tip).
  std::array<Eigen::Vector3d, 2> lines;
  cv::Mat const wide_left = wedge(120.0, 60.0, kW + 40.0, 115.0, 26.0, lines);
  auto const pairs = findMaskLinePairs(wide_left, fullView(), 2, ContourLinesParams{});
  ASSERT_EQ(pairs.size(), 1u);
  EXPECT_LE(pairs[0].entry.x(), 8.0);
  cv::Mat wide_right;
  cv::flip(wide_left, wide_right, 1);
  auto const mirrored = findMaskLinePairs(wide_right, fullView(), 2, ContourLinesParams{});
  ASSERT_EQ(mirrored.size(), 1u);
  EXPECT_GE(mirrored[0].entry.x(), kW - 9.0);
}

TEST(MaskLinePairs, AnOutlineTheNetworkDoesNotCallASideIsNone) {
  // A shaft 24 px wide from the left edge to x = 150, then a head 44 px wide to x = 230 (a
  // stapler's, in the instrument's mask). The network's side map holds the shaft's two sides
  // only: the head's outline gives no side, and the one pair is the shaft's.
  Strip const shaft{{-20.0, 110.0}, {150.0, 110.0}, 24.0};
  Strip const head{{-20.0, 110.0}, {230.0, 110.0}, 44.0};
  cv::Mat instrument = draw({head});
  draw({shaft})(cv::Rect(0, 0, 150, kH)).copyTo(instrument(cv::Rect(0, 0, 150, kH)));
  cv::Mat sides = cv::Mat::zeros(kH, kW, CV_32F);
  for (int y = 0; y < kH; ++y)
    for (int x = 0; x < 150; ++x)
      if (std::abs(std::abs(y - 110.0) - 12.0) <= 2.0) sides.at<float>(y, x) = 1.0f;
  auto const with = findMaskLinePairs(instrument, fullView(), 2, ContourLinesParams{}, cv::Mat(), sides);
  ASSERT_EQ(with.size(), 1u);
  EXPECT_TRUE(pairIsStrip(with[0], shaft, {20.0, 120.0}, 0.3));
  for (auto const& side : with[0].sides)
    for (auto const& q : side.points) EXPECT_LT(q.x(), 152.0);
  // Without it, the head's outline is a pair of its own.
  auto const without = findMaskLinePairs(instrument, fullView(), 2, ContourLinesParams{});
  EXPECT_TRUE(std::any_of(without.begin(), without.end(), [&](MaskLinePair const& p) { return pairIsStrip(p, head, {180.0, 220.0}, 0.5); }));
  // A side map that holds no side: no pair.
  EXPECT_TRUE(findMaskLinePairs(instrument, fullView(), 2, ContourLinesParams{}, cv::Mat(), cv::Mat::zeros(kH, kW, CV_32F)).empty());
  // A sheath of the shaft's width beyond the side map (the dataset labels it jaws): the sides run
  // on along it, their points as far as the outline stays on their lines.
  Strip const sheathed{{-20.0, 110.0}, {230.0, 110.0}, 24.0};
  auto const on = findMaskLinePairs(draw({sheathed}), fullView(), 2, ContourLinesParams{}, cv::Mat(), sides);
  ASSERT_EQ(on.size(), 1u);
  EXPECT_TRUE(pairIsStrip(on[0], sheathed, {20.0, 200.0}, 0.3));
  for (auto const& side : on[0].sides) {
    double reach = 0.0;
    for (auto const& q : side.points) reach = std::max(reach, q.x());
    EXPECT_GT(reach, 220.0);
  }
}
