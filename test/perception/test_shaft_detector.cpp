// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The shaft-detector seam (shaft_detector.h): a new detector plugs into the segmentation and the
// one contour fit without touching either (here one proposing the renderer's exact shaft
// labels), the detector switch, a copied stream carrying its state over, and the duplicates'
// removal keeping each detector's per-contour data aligned.
#include <gtest/gtest.h>

#include <memory>
#include <opencv2/imgproc.hpp>
#include <stdexcept>

#include "endo_guidance/perception/colour_shaft_detector.h"
#include "endo_guidance/perception/contour_fit.h"
#include "endo_guidance/perception/learned_shaft_detector.h"
#include "endo_guidance/perception/mask_line_pairs.h"
#include "endo_guidance/perception/segmentation.h"
#include "endo_guidance/sim/scene_renderer.h"
#include "endo_guidance/sim/synthetic_scene.h"

#include "colour_params.h"
#include "contour_test_util.h"

using namespace endo_guidance::perception;
using namespace endo_guidance::geometry;
using namespace endo_guidance::sim;
using endo_guidance::test::bandContour;
using endo_guidance::test::colourParams;
using endo_guidance::test::lineErrorOverItsExtent;

namespace {

// Proposes the renderer's exact shaft labels (set per frame) as pairs of straight sides
// (findMaskLinePairs()), each through the shared contour fit (refineContour()).
class ExactLabelDetector final : public ShaftDetector {
 public:
  explicit ExactLabelDetector(SegmentationParams const& p) : params_(p) {}
  std::unique_ptr<ShaftDetector> clone() const override { return std::make_unique<ExactLabelDetector>(*this); }
  SegmentationResult detect(DetectionFrame const& frame) override {
    ++calls;
    SegmentationResult res;
    res.scale = frame.scale;
    cv::Mat shaft;
    cv::resize(labels_full == 1, shaft, frame.fov.mask.size(), 0, 0, cv::INTER_NEAREST);
    shaft.convertTo(feature_, CV_32F, 1.0 / 255.0);
    for (MaskLinePair const& pair : findMaskLinePairs(feature_, frame.fov, frame.scale, params_.contours)) {
      auto region = regionOf(pair, shaft);
      if (!region) continue;
      res.regions.push_back(std::move(*region));
      ContourFit const f = refineContour(sideFitOf(pair, frame.scale), res.regions.back(), frame.fov, frame.bgr, frame.scale, params_.contours);
      res.region_status.push_back(f.rejection);
      if (!f.contour) continue;
      res.contours.push_back(onImageAxis(*f.contour));
      res.edges.push_back(f.edges);
      res.contour_regions.push_back(res.regions.size() - 1);
    }
    std::vector<std::size_t> keys;
    removeDuplicateShafts(res, keys);
    return res;
  }
  bool followable() const override { return false; }
  void setParams(SegmentationParams const& p) override { params_ = p; }
  void reset() override {}
  cv::Mat const& feature() const override { return feature_; }
  cv::Mat const& labels() const override { return labels_; }

  cv::Mat labels_full;  // the frame's exact labels (SceneRenderer::render)
  int calls = 0;

 private:
  SegmentationParams params_;
  cv::Mat feature_, labels_;
};

}  // namespace

// A detector written outside the core, proposing the exact labels: every rendered shaft found by
// the shared fit, each line within 0.5 px of the true apparent contour (the fit on the frame's
// own edges, not on the labels' pixels), and the segmentation's result is the detector's.
TEST(ShaftDetectorSeam, ADetectorFromOutsideTheCoreGoesThroughTheContourFit) {
  SyntheticScene scene(defaultInstruments());
  SceneRenderer renderer(640, 480);
  SegmentationParams const sp;
  auto owned = std::make_unique<ExactLabelDetector>(sp);
  ExactLabelDetector* det = owned.get();
  InstrumentSegmenter seg(sp, std::move(owned));
  int visible = 0, found = 0;
  for (int k = 0; k < 20; ++k) {
    auto const views = scene.frame(k);
    cv::Mat const bgr = renderer.render(views, k, &det->labels_full);
    SegmentationResult const res = seg.process(bgr);
    EXPECT_EQ(res.contours.size(), res.edges.size());
    EXPECT_EQ(res.contours.size(), res.contour_regions.size());
    for (auto const& v : views) {
      ++visible;
      double best = 1e9;
      for (auto const& c : res.contours) best = std::min(best, lineErrorOverItsExtent(c, v.truth));
      if (best < 0.5) ++found;
    }
  }
  EXPECT_EQ(det->calls, 20);
  EXPECT_GT(visible, 30);
  EXPECT_GE(found, visible * 95 / 100) << found << " of " << visible;
  EXPECT_THROW(InstrumentSegmenter(sp, nullptr), std::invalid_argument);
}

// makeShaftDetector() makes the kind params.detector names, or says why it cannot. The default
// is the learned detector: it finds more of the shafts of surgeries neither method saw
// (docs/accuracy.md).
TEST(ShaftDetectorSeam, TheDetectorSwitchMakesEachKind) {
  SegmentationParams sp;
  EXPECT_EQ(sp.detector, SegmentationParams::Detector::kLearned);
  EXPECT_NE(dynamic_cast<LearnedShaftDetector*>(makeShaftDetector(sp).get()), nullptr);
  sp.detector = SegmentationParams::Detector::kColour;
  EXPECT_NE(dynamic_cast<ColourShaftDetector*>(makeShaftDetector(sp).get()), nullptr);
  sp.detector = SegmentationParams::Detector::kLearned;
  sp.learned.model = "/nonexistent/shaft_net.yaml";
  EXPECT_THROW(makeShaftDetector(sp), std::runtime_error);
}

// A copied segmenter carries the stream over: the colour detector's memory of earlier frames
// (the next frame gives the original's result, not a fresh segmenter's), independent of the
// original afterwards.
TEST(ShaftDetectorSeam, ACopyCarriesTheStreamsStateOver) {
  SyntheticSceneOptions so;
  so.breathing_amplitude = 0.002;
  SyntheticScene scene(defaultInstruments(), so);
  SceneRenderer renderer(so.width, so.height, hardRenderOptions());
  InstrumentSegmenter seg(colourParams());
  for (int k = 0; k < 30; ++k) seg.process(renderer.render(scene.frame(k), k));
  InstrumentSegmenter copy = seg;
  cv::Mat const next = renderer.render(scene.frame(30), 30);
  SegmentationResult const a = copy.process(next);
  for (int k = 31; k < 35; ++k) copy.process(renderer.render(scene.frame(k), k));  // (the original does not see these)
  SegmentationResult const b = seg.process(next);
  SegmentationResult const fresh = InstrumentSegmenter(colourParams()).process(next);
  ASSERT_EQ(a.contours.size(), b.contours.size());
  for (std::size_t i = 0; i < a.contours.size(); ++i) EXPECT_EQ(a.contours[i].lines, b.contours[i].lines) << i;
  EXPECT_EQ(a.full_searches, b.full_searches);
  // The memory matters here: a fresh segmenter searches every seed in full.
  EXPECT_GT(fresh.full_searches, a.full_searches);
}

// removeDuplicateShafts(): a strip inside a wider shaft (narrowerDuplicates()) and a wedge
// between that shaft's edge and a tissue edge, fitting worse (overlappingDuplicates()), go with
// their edges, regions and the detector's keys; their regions are marked duplicates.
TEST(ShaftDetectorSeam, RemovingDuplicatesKeepsThePerContourDataAligned) {
  SegmentationResult res;
  ApparentContour whole = bandContour({0, 240}, {250, 240}, 40), strip = bandContour({0, 260}, {200, 258}, 15),
                  other = bandContour({0, 400}, {400, 420}, 30), wedge;
  whole.residual_px = other.residual_px = 0.32;
  wedge.lines = {*lineThrough({0, 210}, {300, 260}), *lineThrough({0, 290}, {300, 320})};
  wedge.entry_px = {0, 250};
  wedge.tip_px = {300, 290};
  wedge.residual_px = 0.56;
  res.contours = {strip, whole, wedge, other};
  res.edges.resize(4);
  for (int i = 0; i < 4; ++i) res.edges[i][0].assign(i + 1, Eigen::Vector2d::Zero());
  res.regions.resize(5);
  res.region_status.assign(5, ContourRejection::kNone);
  res.contour_regions = {4, 0, 2, 3};
  std::vector<std::size_t> keys{40, 41, 42, 43};
  removeDuplicateShafts(res, keys);
  ASSERT_EQ(res.contours.size(), 2u);
  EXPECT_EQ(res.contours[0].lines, whole.lines);
  EXPECT_EQ(res.contours[1].lines, other.lines);
  EXPECT_EQ(res.edges[0][0].size(), 2u);
  EXPECT_EQ(res.edges[1][0].size(), 4u);
  EXPECT_EQ(res.contour_regions, (std::vector<std::size_t>{0, 3}));
  EXPECT_EQ(keys, (std::vector<std::size_t>{41, 43}));
  EXPECT_EQ(res.region_status, (std::vector<ContourRejection>{ContourRejection::kNone, ContourRejection::kNone,
                                                               ContourRejection::kDuplicate, ContourRejection::kNone,
                                                               ContourRejection::kDuplicate}));
}
