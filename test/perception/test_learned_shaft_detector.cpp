// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The learned shaft detector: model loading (good, missing, corrupt), the committed model's
// output against the training framework's on the same rendered frame, the contour on the sides
// of an exact mask, and the detector switch of the segmentation.
#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <opencv2/imgproc.hpp>

#include "endo_guidance/perception/learned_shaft_detector.h"
#include "endo_guidance/perception/segmentation.h"
#include "endo_guidance/sim/scene_renderer.h"
#include "endo_guidance/sim/synthetic_scene.h"

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
  // The segmentation refuses the learned detector without a model, and keeps its parameters.
  SegmentationParams sp;
  sp.detector = SegmentationParams::Detector::kLearned;
  sp.learned.model = "/nonexistent/shaft_net.yaml";
  EXPECT_THROW(InstrumentSegmenter{sp}, std::runtime_error);
  InstrumentSegmenter seg;
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
  ASSERT_EQ(out.size[1], 3);
  ASSERT_EQ(out.size[2], net.inputSize().height);
  ASSERT_EQ(out.size[3], net.inputSize().width);
  int const n = net.inputSize().area();
  double worst = 0.0, range = 0.0;
  for (int c = 0; c < 3; ++c) {
    cv::Mat expected;
    ref[net.classes()[static_cast<std::size_t>(c)]] >> expected;
    ASSERT_EQ(expected.size(), net.inputSize());
    cv::Mat const got(net.inputSize(), CV_32F, const_cast<float*>(out.ptr<float>()) + c * n);
    worst = std::max(worst, cv::norm(got, expected, cv::NORM_INF));
    double lo, hi;
    cv::minMaxLoc(expected, &lo, &hi);
    range = std::max(range, hi - lo);
  }
  EXPECT_LT(worst, 1e-3 * std::max(1.0, range)) << "OpenCV's output differs from PyTorch's by " << worst;
  // The probability: in [0, 1], at the input size, high on the rendered shafts.
  cv::Mat const p = net.shaftProbability(f.image);
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
  }
  ASSERT_GE(total, 2);
  EXPECT_EQ(on, total);
}

TEST(LearnedShaftDetector, ContourOnTheSidesOfAnExactMask) {
  // A strip entering from the left border of a 320 x 240 view, 20 px wide, to x = 200.
  cv::Mat bgr(240, 320, CV_8UC3, cv::Scalar(60, 80, 200));
  FieldOfView const fov = detectFieldOfView(bgr);
  cv::Mat half = cv::Mat::zeros(120, 160, CV_32F), prob;  // at half the view's size, as a network's
  cv::rectangle(half, cv::Rect(0, 50, 100, 10), cv::Scalar(1.0), cv::FILLED);
  cv::resize(half, prob, fov.mask.size(), 0, 0, cv::INTER_LINEAR);
  ContourLinesParams cp;
  auto const pairs = findMaskLinePairs(prob, fov, 2, cp);
  ASSERT_EQ(pairs.size(), 1u);
  SideFit const s = sideFitOf(pairs[0], 2);  // processing -> full resolution: x2
  for (int k = 0; k < 2; ++k) {
    EXPECT_NEAR(std::abs(s.lines[k].y()), 1.0, 1e-3);  // horizontal
    // The shaft (its middle row, 2 x 110 px at full resolution) on the positive side.
    EXPECT_GT(s.lines[k].dot(Eigen::Vector3d(100, 219.5, 1)), 0.0);
  }
  EXPECT_LE(s.entry.x(), 16.0);  // the entry on the left border
  double const y0 = -s.lines[0].z() / s.lines[0].y(), y1 = -s.lines[1].z() / s.lines[1].y();
  EXPECT_NEAR(std::abs(y1 - y0), 2.0 * 19.0, 3.0);  // the boundary rows, 19 processing px apart
  cv::Mat mask;
  cv::compare(prob, 0.5, mask, cv::CMP_GE);
  auto const region = regionOf(pairs[0], mask);
  ASSERT_TRUE(region);
  // The contour on the mask's sides: both lines, ordered, the shaft between them, the checks passed.
  ContourFit const fit = maskContour(s, *region, 2, cp, 1.0);
  ASSERT_TRUE(fit.contour) << toString(fit.rejection);
  Eigen::Vector3d const inside(100, 219.5, 1);
  EXPECT_GT(fit.contour->lines[0].dot(inside), 0.0);
  EXPECT_GT(fit.contour->lines[1].dot(inside), 0.0);
  EXPECT_NEAR(fit.contour->entry_px.y(), 219.5, 3.0);
  EXPECT_NEAR(fit.contour->tip_px.x(), 2 * 199 + 0.5, 4.0);  // the strip's end
  EXPECT_GT(fit.contour->line_covariances[0].trace(), 0.0);
  EXPECT_EQ(fit.edges[0].size() + fit.edges[1].size(), static_cast<std::size_t>(fit.edge_points));
  // Too thin to be a shaft: refused, saying why.
  ContourLinesParams wide = cp;
  wide.min_width_px = 60.0;
  EXPECT_EQ(maskContour(s, *region, 2, wide, 1.0).rejection, ContourRejection::kTooThin);
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
