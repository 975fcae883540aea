// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The learned shaft detector: model loading (good, missing, corrupt), the committed model's
// output against the training framework's on the same rendered frame, the lines on the frame's
// edges beside a coarse mask's sides, and the detector switch of the segmentation.
#include <gtest/gtest.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <optional>
#include <opencv2/imgproc.hpp>
#include <utility>

#include "endo_guidance/perception/contour_fit.h"
#include "endo_guidance/perception/learned_shaft_detector.h"
#include "endo_guidance/perception/mask_line_pairs.h"
#include "endo_guidance/perception/segmentation.h"
#include "endo_guidance/sim/scene_renderer.h"
#include "endo_guidance/sim/synthetic_scene.h"

#include "colour_params.h"

using namespace endo_guidance::perception;
using namespace endo_guidance::geometry;
using namespace endo_guidance::sim;
namespace fs = std::filesystem;

namespace {

std::string writeFile(std::string const& name, std::string const& text) {
  fs::path const p = fs::temp_directory_path() / ("endo_guidance_test_learned_" + name);
  std::ofstream(p) << text;
  return p.string();
}

// Frame 0 of the clean rendered sequence, as `endo_guidance_synthetic --write-sequence` writes it
// (scripts/train_shaft_net.sh saves the training framework's output on that file).
struct CleanFrame {
  SyntheticSceneOptions options = [] {
    SyntheticSceneOptions o;
    o.line_noise_px = 0.5;
    o.breathing_amplitude = 0.002;
    o.seed = 42;
    return o;
  }();
  SyntheticScene scene{defaultInstruments(), options};
  std::vector<SyntheticView> views = scene.frame(0);
  cv::Mat image = SceneRenderer(options.width, options.height).render(views, 0);
};

std::string expectThrowMessage(std::string const& path) {
  try {
    ShaftNet net(path);
  } catch (std::runtime_error const& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(LearnedShaftDetector, MissingOrCorruptModelIsAClearErrorAtConstruction) {
  EXPECT_NE(expectThrowMessage("/nonexistent/shaft_net.yaml").find("no such file"), std::string::npos);
  // Not YAML at all.
  EXPECT_NE(expectThrowMessage(writeFile("text.yaml", "this is { not yaml")).find("shaft model"), std::string::npos);
  // YAML without the input size.
  std::string const no_size = writeFile("nosize.yaml", "%YAML:1.0\n---\nmodel: x.onnx\nclasses: [background, shaft]\n");
  EXPECT_NE(expectThrowMessage(no_size).find("width"), std::string::npos);
  // Its ONNX file missing, then corrupt.
  std::string const yaml = "%YAML:1.0\n---\nmodel: endo_guidance_test_learned_bad.onnx\nwidth: 160\nheight: 128\n"
                           "mean: 127.5\nscale: 0.0078431373\nclasses: [background, shaft, jaws]\n";
  fs::remove(fs::temp_directory_path() / "endo_guidance_test_learned_bad.onnx");
  std::string const path = writeFile("bad.yaml", yaml);
  EXPECT_NE(expectThrowMessage(path).find("missing"), std::string::npos);
  writeFile("bad.onnx", std::string(4096, '\x7f'));
  EXPECT_NE(expectThrowMessage(path).find("cannot load"), std::string::npos);
  // A side channel that is not the one after the classes'; the committed model's ONNX file with
  // its side channel left out of the YAML, or named where it gives none.
  std::string const committed_onnx = (fs::path(defaultShaftModel()).parent_path() / "shaft_net.onnx").string();
  std::string const classes = "%YAML:1.0\n---\nmodel: " + committed_onnx + "\nwidth: 160\nheight: 128\nmean: 127.5\n"
                              "scale: 0.0078431373\nclasses: [background, shaft, jaws]\n";
  EXPECT_NE(expectThrowMessage(writeFile("side1.yaml", classes + "side: 1\n")).find("'side'"), std::string::npos);
  bool const sides = ShaftNet(defaultShaftModel()).hasSides();
  EXPECT_NE(expectThrowMessage(writeFile("side3.yaml", classes + (sides ? "" : "side: 3\n"))).find(sides ? "not 3 x height" : "not 4 x height"),
            std::string::npos);
  // The segmentation refuses the learned detector without a model, and keeps its parameters.
  SegmentationParams sp;
  sp.detector = SegmentationParams::Detector::kLearned;
  sp.learned.model = "/nonexistent/shaft_net.yaml";
  EXPECT_THROW(InstrumentSegmenter{sp}, std::runtime_error);
  InstrumentSegmenter seg(endo_guidance::test::colourParams());
  EXPECT_THROW(seg.setParams(sp), std::runtime_error);
  EXPECT_EQ(seg.params().detector, SegmentationParams::Detector::kColour);
}

TEST(LearnedShaftDetector, CommittedModelGivesTheTrainingFrameworksOutput) {
  ShaftNet net(defaultShaftModel());  // committed: its absence is a failure, not a skip
  ASSERT_EQ(net.classes().size(), 3u);
  cv::FileStorage ref(fs::path(defaultShaftModel()).parent_path() / "shaft_net_reference.yml.gz", cv::FileStorage::READ);
  ASSERT_TRUE(ref.isOpened()) << "models/shaft_net_reference.yml.gz is missing";
  CleanFrame f;
  // The same frame as the reference's (else the renderer changed, and the reference must be made again).
  ASSERT_NEAR(cv::sum(f.image)[0] + cv::sum(f.image)[1] + cv::sum(f.image)[2], static_cast<double>(ref["frame_sum"]), 0.5);
  cv::Mat const out = net.logits(f.image);
  ASSERT_EQ(out.dims, 4);
  ASSERT_EQ(out.size[0], 1);
  std::vector<std::string> outputs = net.classes();  // (as the reference names them)
  if (net.hasSides()) outputs.push_back("side");
  ASSERT_EQ(out.size[1], static_cast<int>(outputs.size()));
  ASSERT_EQ(out.size[2], net.inputSize().height);
  ASSERT_EQ(out.size[3], net.inputSize().width);
  int const n = net.inputSize().area();
  double worst = 0.0, range = 0.0;
  for (int c = 0; c < out.size[1]; ++c) {
    cv::Mat expected;
    ref[outputs[static_cast<std::size_t>(c)]] >> expected;
    ASSERT_EQ(expected.size(), net.inputSize());
    cv::Mat const got(net.inputSize(), CV_32F, const_cast<float*>(out.ptr<float>()) + c * n);
    worst = std::max(worst, cv::norm(got, expected, cv::NORM_INF));
    double lo, hi;
    cv::minMaxLoc(expected, &lo, &hi);
    range = std::max(range, hi - lo);
  }
  EXPECT_LT(worst, 1e-3 * std::max(1.0, range)) << "OpenCV's output differs from PyTorch's by " << worst;
  // The probability: in [0, 1], at the input size, high on the rendered shafts.
  ShaftProbabilities const probs = net.probabilities(f.image);
  cv::Mat const& p = probs.shaft;
  ASSERT_EQ(p.size(), net.inputSize());
  double lo, hi;
  cv::minMaxLoc(p, &lo, &hi);
  EXPECT_GE(lo, 0.0);
  EXPECT_LE(hi, 1.0);
  int on = 0, total = 0;
  double const sx = static_cast<double>(p.cols) / f.image.cols, sy = static_cast<double>(p.rows) / f.image.rows;
  for (auto const& v : f.views) {  // the middle of each shaft's axis
    Eigen::Vector2d const m = 0.5 * (v.truth.entry_px + v.truth.tip_px);
    cv::Point const q(static_cast<int>(m.x() * sx), static_cast<int>(m.y() * sy));
    if (!cv::Rect(0, 0, p.cols, p.rows).contains(q)) continue;
    ++total;
    on += p.at<float>(q) > 0.5f;
    if (!probs.side.empty()) {  // the side map: low inside, high on the silhouette line beside it
      EXPECT_LT(probs.side.at<float>(q), 0.5f);
      Eigen::Vector2d const e = footOnLine(v.truth.lines[0], m);
      cv::Rect const near(static_cast<int>(e.x() * sx) - 1, static_cast<int>(e.y() * sy) - 1, 3, 3);
      double side = 0.0;
      cv::minMaxLoc(probs.side(near & cv::Rect(0, 0, p.cols, p.rows)), nullptr, &side);
      EXPECT_GE(side, 0.5);
    }
  }
  ASSERT_GE(total, 2);
  EXPECT_EQ(on, total);
}

TEST(LearnedShaftDetector, TheLinesAreTheFramesEdgesBesideTheMasksSides) {
  // A grey shaft entering from the left on red tissue, 640 x 480: rows 200-239 from x = 0 to 399,
  // its edges at y = 199.5 and 239.5. The mask (processing scale, half) is 3 px too wide each
  // side, as a coarse network's.
  cv::Mat bgr(480, 640, CV_8UC3, cv::Scalar(60, 80, 200));
  bgr(cv::Rect(0, 200, 400, 40)).setTo(cv::Scalar(128, 128, 128));
  cv::Mat half;
  cv::resize(bgr, half, cv::Size(320, 240), 0, 0, cv::INTER_AREA);
  FieldOfView const fov = detectFieldOfView(half);
  cv::Mat prob = cv::Mat::zeros(240, 320, CV_32F), mask;
  cv::rectangle(prob, cv::Rect(0, 98, 200, 24), cv::Scalar(1.0), cv::FILLED);  // rows 98-121: y 195.5-243.5 at full scale
  cv::compare(prob, 0.5, mask, cv::CMP_GE);
  ContourLinesParams const cp;
  auto const pairs = findMaskLinePairs(prob, fov, 2, cp);
  ASSERT_EQ(pairs.size(), 1u);
  SideFit const sides = sideFitOf(pairs[0], 2);
  auto const region = regionOf(pairs[0], mask);
  ASSERT_TRUE(region);
  ContourFit const fit = refineContour(sides, *region, fov, bgr, 2, cp);
  ASSERT_TRUE(fit.contour) << toString(fit.rejection);
  for (double y : {199.5, 239.5}) {  // each true edge is one of the lines, at both ends of the shaft
    double best = 1e9;
    for (auto const& l : fit.contour->lines)
      best = std::min(best, std::max(std::abs(l.dot(Eigen::Vector3d(40, y, 1))), std::abs(l.dot(Eigen::Vector3d(360, y, 1)))));
    EXPECT_LT(best, 0.2) << "edge at y = " << y;
  }
  EXPECT_LE(fit.contour->entry_px.x(), 16.0);  // entering at the left border
  EXPECT_NEAR(fit.contour->tip_px.x(), 399.5, 6.0);
  // The same mask on a frame with no edges there: refused, saying why (no line on the mask's own sides).
  cv::Mat const flat(480, 640, CV_8UC3, cv::Scalar(60, 80, 200));
  ContourFit const none = refineContour(sides, *region, fov, flat, 2, cp);
  EXPECT_FALSE(none.contour);
  EXPECT_NE(none.rejection, ContourRejection::kNone);
}

// The stage after the network (shaftsOfProbability()) on a grey shaft over greyish fat of the
// same chroma, brighter by 60 levels: the chroma has no edge beside the mask's sides, the colour
// direction across each side has; both lines on the true edges.
TEST(LearnedShaftDetector, ASideAsGreyAsTheTissueIsFoundAlongItsColourDirection) {
  cv::Mat bgr(480, 640, CV_8UC3, cv::Scalar(150, 165, 185));  // chroma 35
  bgr(cv::Rect(0, 200, 400, 40)).setTo(cv::Scalar(90, 105, 125));  // chroma 35
  cv::Mat half;
  cv::resize(bgr, half, cv::Size(320, 240), 0, 0, cv::INTER_AREA);
  FieldOfView const fov = detectFieldOfView(half);
  cv::Mat prob = cv::Mat::zeros(240, 320, CV_32F);
  cv::rectangle(prob, cv::Rect(0, 98, 200, 24), cv::Scalar(1.0), cv::FILLED);  // 3 px too wide each side (full scale)
  std::vector<Eigen::Vector3d> const no_trocars;
  DetectionFrame const frame{bgr, half, fov, static_cast<double>(cv::countNonZero(fov.mask)), 2, no_trocars, 1};
  SegmentationParams const sp;
  cv::Mat labels;
  SegmentationResult const r = shaftsOfProbability(frame, {prob, prob}, sp, labels);
  ASSERT_EQ(r.contours.size(), 1u) << (r.region_status.empty() ? "no pair" : toString(r.region_status[0]));
  for (double y : {199.5, 239.5}) {
    double best = 1e9;
    for (auto const& l : r.contours[0].lines)
      best = std::min(best, std::max(std::abs(l.dot(Eigen::Vector3d(40, y, 1))), std::abs(l.dot(Eigen::Vector3d(360, y, 1)))));
    EXPECT_LT(best, 0.2) << "edge at y = " << y;
  }
  EXPECT_GT(cv::countNonZero(labels), 0);
  // The same mask over a frame of one colour: nothing, and no line on the mask's own sides.
  cv::Mat const flat(480, 640, CV_8UC3, cv::Scalar(150, 165, 185));
  cv::Mat flat_half;
  cv::resize(flat, flat_half, cv::Size(320, 240), 0, 0, cv::INTER_AREA);
  DetectionFrame const none{flat, flat_half, fov, frame.fov_area, 2, no_trocars, 1};
  EXPECT_TRUE(shaftsOfProbability(none, {prob, prob}, sp, labels).contours.empty());
}

namespace {

// A grey shaft on red tissue, rows 200-239 from the left border, on grey tissue below it (no edge
// either way along its lower side), and `fold` filled red: the stage after the network fed a mask
// of it 4 px too wide each side (half scale, rows 98-121: y 195.5-243.5). Its one contour, or none.
std::optional<ApparentContour> greyBelowContour(std::vector<cv::Point> const& fold = {}) {
  cv::Mat bgr(480, 640, CV_8UC3, cv::Scalar(60, 80, 200));
  bgr(cv::Rect(0, 200, 640, 280)).setTo(cv::Scalar(128, 128, 128));
  if (!fold.empty()) cv::fillPoly(bgr, std::vector<std::vector<cv::Point>>{fold}, cv::Scalar(60, 80, 200), cv::LINE_AA);
  cv::Mat half;
  cv::resize(bgr, half, cv::Size(320, 240), 0, 0, cv::INTER_AREA);
  FieldOfView const fov = detectFieldOfView(half);
  cv::Mat prob = cv::Mat::zeros(240, 320, CV_32F);
  cv::rectangle(prob, cv::Rect(0, 98, 200, 24), cv::Scalar(1.0), cv::FILLED);
  std::vector<Eigen::Vector3d> const no_trocars;
  DetectionFrame const frame{bgr, half, fov, static_cast<double>(cv::countNonZero(fov.mask)), 2, no_trocars, 1};
  cv::Mat labels;
  SegmentationResult const r = shaftsOfProbability(frame, {prob, prob}, SegmentationParams{}, labels);
  EXPECT_EQ(r.contours.size(), 1u) << (r.region_status.empty() ? "no pair" : toString(r.region_status[0]));
  if (r.contours.size() != 1u) return std::nullopt;
  return r.contours[0];
}

// A line's distance to the row y at both ends of the shaft (x = 40 and 360).
double offRow(Eigen::Vector3d const& l, double y) {
  return std::max(std::abs(l.dot(Eigen::Vector3d(40, y, 1))), std::abs(l.dot(Eigen::Vector3d(360, y, 1))));
}

// Its line's standard deviation at the shaft's middle, from its covariance.
double sigmaAtMiddle(ApparentContour const& c, int k) {
  Eigen::Vector3d const mid(200.0, 220.0, 1.0);
  return std::sqrt(mid.dot(c.line_covariances[k] * mid));
}

}  // namespace

// One side with no edge in the frame either way (the tissue below the shaft as grey as it is): the
// contour keeps the mask's side there, with a covariance as wide as a mask's outline error, and
// its other line on the frame's edge; with no edge on either side it is refused (above).
TEST(LearnedShaftDetector, ASideWithoutFrameEdgesIsTheMasksSideWithItsError) {
  auto const c = greyBelowContour();
  ASSERT_TRUE(c);
  int const edge = offRow(c->lines[0], 199.5) < offRow(c->lines[1], 199.5) ? 0 : 1;
  EXPECT_LT(offRow(c->lines[edge], 199.5), 0.2);      // on the frame's edge
  EXPECT_LT(offRow(c->lines[1 - edge], 243.5), 1.0);  // the mask's side (4 px below the true edge)
  EXPECT_LT(sigmaAtMiddle(*c, edge), 0.5);
  EXPECT_GT(sigmaAtMiddle(*c, 1 - edge), 2.0);  // worth what a mask's outline is: a few px
  EXPECT_TRUE(std::isfinite(sigmaAtMiddle(*c, 1 - edge)));
}

// The same, with a fold of red tissue below the shaft that meets the mask's side near the tip and
// runs 24 px away from it at the entry: the frame's edge beside the side is the fold's there, not
// the shaft's. The mask's side is kept (the mask is within its error of the shaft's edge, the fold
// is not), not the fold's line.
TEST(LearnedShaftDetector, AFrameEdgeBeyondTheMasksErrorIsNotTheSide) {
  auto const c = greyBelowContour({{0, 270}, {400, 246}, {640, 246}, {640, 480}, {0, 480}});
  ASSERT_TRUE(c);
  int const edge = offRow(c->lines[0], 199.5) < offRow(c->lines[1], 199.5) ? 0 : 1;
  EXPECT_LT(offRow(c->lines[edge], 199.5), 0.2);
  EXPECT_LT(offRow(c->lines[1 - edge], 243.5), 1.0);  // the mask's side, not the fold
  EXPECT_GT(sigmaAtMiddle(*c, 1 - edge), 2.0);
}

// A grey shaft entering from the left on red tissue (640 x 480, edges at y = 199.5 and 239.5,
// x from 0 to 399), or another 640 x 480 frame, and the stage after the network fed masks of it at
// the processing scale (half).
struct StubFrame {
  static cv::Mat greyShaft() {
    cv::Mat m(480, 640, CV_8UC3, cv::Scalar(60, 80, 200));
    m(cv::Rect(0, 200, 400, 40)).setTo(cv::Scalar(128, 128, 128));
    return m;
  }
  explicit StubFrame(cv::Mat image = greyShaft()) : bgr(std::move(image)) {}
  // (after a change to bgr: its half again, in place, so that `frame` still refers to both)
  void reduce() { cv::resize(bgr, half, half.size(), 0, 0, cv::INTER_AREA); }
  cv::Mat bgr;
  cv::Mat half = [this] {
    cv::Mat h;
    cv::resize(bgr, h, cv::Size(320, 240), 0, 0, cv::INTER_AREA);
    return h;
  }();
  FieldOfView fov = detectFieldOfView(half);
  std::vector<Eigen::Vector3d> no_trocars;
  DetectionFrame frame{bgr, half, fov, static_cast<double>(cv::countNonZero(fov.mask)), 2, no_trocars, 1};
  // A mask over the shaft's strip from x = x0 to x1 (processing px), 3 px too wide each side.
  static cv::Mat strip(int x0, int x1) {
    cv::Mat p = cv::Mat::zeros(240, 320, CV_32F);
    if (x1 > x0) cv::rectangle(p, cv::Rect(x0, 98, x1 - x0, 24), cv::Scalar(1.0), cv::FILLED);
    return p;
  }
  // Whether both true edges are lines of contour c (within 0.2 px at both ends of the shaft).
  static bool onTheEdges(ApparentContour const& c) {
    for (double y : {199.5, 239.5}) {
      double best = 1e9;
      for (auto const& l : c.lines)
        best = std::min(best, std::max(std::abs(l.dot(Eigen::Vector3d(40, y, 1))), std::abs(l.dot(Eigen::Vector3d(360, y, 1)))));
      if (best > 0.2) return false;
    }
    return true;
  }
};

// The dataset's shaft class is often a stub between the view's border and an insulated sheath of
// the same width (labelled jaws): too short to pair alone, found with the instrument's mask.
TEST(LearnedShaftDetector, AShaftStubIsFoundAlongTheInstrumentBeyondIt) {  // (and the tip is the jaws' end)
  StubFrame const f;
  SegmentationParams const sp;
  cv::Mat labels;
  ShaftProbabilities const stub{StubFrame::strip(0, 14), StubFrame::strip(0, 200)};
  SegmentationResult const r = shaftsOfProbability(f.frame, stub, sp, labels);
  ASSERT_EQ(r.contours.size(), 1u);
  EXPECT_TRUE(StubFrame::onTheEdges(r.contours[0]));
  EXPECT_NEAR(r.contours[0].tip_px.x(), 399.5, 6.0);
  // The shaft class alone gives nothing there.
  EXPECT_TRUE(shaftsOfProbability(f.frame, {stub.shaft, stub.shaft}, sp, labels).contours.empty());
  // A shaft class that ends before the jaws: the tip is the instrument's end, the jaws' (the servo's tip).
  ShaftProbabilities const jaws{StubFrame::strip(0, 150), StubFrame::strip(0, 200)};
  SegmentationResult const j = shaftsOfProbability(f.frame, jaws, sp, labels);
  ASSERT_EQ(j.contours.size(), 1u);
  EXPECT_TRUE(StubFrame::onTheEdges(j.contours[0]));
  EXPECT_NEAR(j.contours[0].tip_px.x(), 399.5, 6.0);
  // A whole shaft in both masks is one shaft, not two.
  ShaftProbabilities const whole{StubFrame::strip(0, 200), StubFrame::strip(0, 200)};
  SegmentationResult const w = shaftsOfProbability(f.frame, whole, sp, labels);
  ASSERT_EQ(w.contours.size(), 1u);
  EXPECT_TRUE(StubFrame::onTheEdges(w.contours[0]));
}

// A tool's head entering the view with no shaft class where it enters (a stapler's head; the
// shaft class only at its far end) is not a shaft: refused, saying why.
TEST(LearnedShaftDetector, AnInstrumentWithoutShaftWhereItEntersIsRefused) {
  StubFrame const f;
  SegmentationParams const sp;
  cv::Mat labels;
  for (cv::Mat const& shaft : {StubFrame::strip(0, 0), StubFrame::strip(170, 200)}) {
    SegmentationResult const r = shaftsOfProbability(f.frame, {shaft, StubFrame::strip(0, 200)}, sp, labels);
    EXPECT_TRUE(r.contours.empty());
    EXPECT_NE(std::find(r.region_status.begin(), r.region_status.end(), ContourRejection::kNotShaftAtEntry), r.region_status.end());
  }
}

// A black shaft with metal jaws on red tissue (640 x 480): the shaft x 0-359, rows 200-239; the
// upper jaw to x = 399 (its end, the tip, at 399.5), the lower to 389. The coarse mask (processing
// scale, half) ends 10 px into the jaws, 30 px short of the tip, as a network's at 160 x 128 does.
cv::Mat blackShaftWithJaws() {
  cv::Mat m(480, 640, CV_8UC3, cv::Scalar(60, 80, 200));
  m(cv::Rect(0, 200, 360, 40)).setTo(cv::Scalar(40, 40, 40));
  m(cv::Rect(360, 200, 40, 13)).setTo(cv::Scalar(175, 175, 180));
  m(cv::Rect(360, 227, 30, 13)).setTo(cv::Scalar(175, 175, 180));
  return m;
}

// The tip is located on the frame: the jaws' end, not the coarse mask's (the servo's tip).
TEST(LearnedShaftDetector, TheTipIsTheJawsEndOnTheFrame) {
  StubFrame f(blackShaftWithJaws());
  SegmentationParams const sp;
  cv::Mat labels;
  cv::Mat const mask = StubFrame::strip(0, 185);
  SegmentationResult const r = shaftsOfProbability(f.frame, {mask, mask}, sp, labels);
  ASSERT_EQ(r.contours.size(), 1u);
  EXPECT_NEAR(r.contours[0].tip_px.x(), 399.5, 0.5);  // (the mask's own end: 370)
  EXPECT_NEAR(r.contours[0].tip_px.y(), 219.5, 0.5);  // on the image axis
  // Another tool's jaw 2 px beyond, joined to these jaws in the coarse mask: the frame parts them.
  f.bgr(cv::Rect(402, 190, 60, 20)).setTo(cv::Scalar(175, 175, 180));
  f.reduce();
  cv::Mat joined = mask.clone();
  cv::rectangle(joined, cv::Rect(185, 94, 47, 20), cv::Scalar(1.0), cv::FILLED);
  SegmentationResult const j = shaftsOfProbability(f.frame, {mask, joined}, sp, labels);
  ASSERT_EQ(j.contours.size(), 1u);
  EXPECT_NEAR(j.contours[0].tip_px.x(), 399.5, 0.5);
  // The shaft's colour running on past the jaws' reach (2.5 widths): no end seen, the mask's tip stands.
  f.bgr(cv::Rect(360, 190, 240, 50)).setTo(cv::Scalar(60, 80, 200));
  f.bgr(cv::Rect(360, 200, 240, 40)).setTo(cv::Scalar(40, 40, 40));
  f.reduce();
  SegmentationResult const n = shaftsOfProbability(f.frame, {mask, mask}, sp, labels);
  ASSERT_EQ(n.contours.size(), 1u);
  EXPECT_NEAR(n.contours[0].tip_px.x(), 369.5, 2.5);
}

TEST(LearnedShaftDetector, DetectorSwitchFindsTheRenderedShafts) {
  CleanFrame f;
  for (auto const d : {SegmentationParams::Detector::kColour, SegmentationParams::Detector::kLearned}) {
    SegmentationParams sp;
    sp.detector = d;
    InstrumentSegmenter seg(sp);
    SegmentationResult const r = seg.process(f.image);
    // Every rendered shaft found, its lines within 1 px of the truth at its entry and tip.
    int found = 0;
    for (auto const& v : f.views) {
      for (auto const& c : r.contours) {
        double worst = 0.0;
        for (int k = 0; k < 2; ++k)
          for (auto const& q : {v.truth.entry_px, v.truth.tip_px})
            worst = std::max(worst, std::abs(c.lines[static_cast<std::size_t>(k)].dot(footOnLine(v.truth.lines[static_cast<std::size_t>(k)], q).homogeneous())));
        if (worst < 1.0) {
          ++found;
          break;
        }
      }
    }
    EXPECT_EQ(found, static_cast<int>(f.views.size())) << (d == SegmentationParams::Detector::kLearned ? "learned" : "colour");
    EXPECT_EQ(r.contours.size(), f.views.size());
  }
}
