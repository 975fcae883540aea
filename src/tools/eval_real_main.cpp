// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
//
// endo_guidance_eval_real: accuracy of the segmentation on the shared real data (never copied
// into the repository), with either detector (--detector). Skips, saying so, when the data folder
// is absent (exit 77: ctest's SKIP_RETURN_CODE).
//
//   in-vivo stills (EndoVis'15 rigid, OP1-OP3, 120 images 640x480, --sites): the strict scoring
//   (shaft_scoring.h) per operation, and beside it the earlier count: shaft recall (half of a
//   detection's strip on the mask), false shafts per image, the mask boundary's distance to the lines.
//   robotic sequences (EndoVis'15 robotic, 720x576): the strict scoring against the mask videos
//   and the annotated axes (both points within 40 px); image-axis error against the annotated
//   shaft axes (ShaftPoint -> EndPoint) on the annotated frames; the insertion points the
//   pipeline discovers; and per annotated tool, its trocar's image as the common point of its
//   annotated and of its detected image axes, and its 3-D trocar from its detections' axes
//   (conditioning, elongation, stability over 4-s blocks). No intrinsics are published: assumed.
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <map>
#include <optional>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>
#include <sstream>
#include <string>
#include <tuple>

#include "endo_guidance/geometry/insertion_point.h"
#include "endo_guidance/geometry/insertion_point_image.h"
#include "endo_guidance/geometry/insertion_point_tracker.h"
#include "endo_guidance/io/yaml_config.h"
#include "endo_guidance/pipeline/pipeline.h"
#include "hough_baseline.h"
#include "shaft_scoring.h"
#include "tool_util.h"
#include "endo_guidance/perception/learned_shaft_detector.h"
#include "endo_guidance/perception/segmentation.h"

namespace fs = std::filesystem;
using namespace endo_guidance::perception;
using namespace endo_guidance::geometry;
using namespace endo_guidance::pipeline;
namespace io = endo_guidance::io;

namespace {

using endo_guidance::tools::detectShaftsHough;
using endo_guidance::tools::percentile;
using endo_guidance::tools::kFoundPx;
using endo_guidance::tools::MaskShaft;
using endo_guidance::tools::maskShaft;
using endo_guidance::tools::scoreStrict;
using endo_guidance::tools::StrictScore;

// The quadrilateral between the two contour lines from the entry to the tip (shaftQuad()), in
// whole pixels.
std::vector<cv::Point> shaftPolygon(ApparentContour const& c) {
  std::vector<cv::Point> poly;
  for (Eigen::Vector2d const& f : shaftQuad(c, c.entry_px, c.tip_px))
    poly.emplace_back(static_cast<int>(std::lround(f.x())), static_cast<int>(std::lround(f.y())));
  return poly;
}

struct InvivoStats {
  int images = 0, shafts = 0, found = 0, detections = 0, false_shafts = 0;
  // Shafts found (half of a detection's strip on the mask) whose closest detection's lines are
  // within kCloseLinePx[k] of the mask's sides (median): the detections that are usable, not
  // only on the shaft (a strip between a print band and one edge is found, 25 px off).
  static constexpr std::array<double, 3> kCloseLinePx{2.0, 5.0, 10.0};
  std::array<int, 3> found_close{};
  std::vector<double> line_median_px;      // per detection matched to a shaft: median distance of the mask's sides
  std::vector<double> line_median_all_px;  // ... of its whole boundary near the lines (ends across the shaft too)
  std::vector<double> all_dist_px;
  std::map<std::string, int> misses;
};

bool verbose = false;
constexpr int kSkipped = 77;            // exit status when the data is absent (ctest SKIP_RETURN_CODE)
constexpr int kStrictMinPx = 300;        // in-vivo: a mask shaft is an instance with this much class 160
constexpr int kStrictRoboticMinPx = 500; // robotic: one shaft per connected component of this much
bool baseline = false;  // --baseline: the Canny + Hough baseline instead of the segmentation (in-vivo stills)
bool annotated_mask = false;  // --annotated-mask: the learned detector's stage fed the annotated masks (stills; the videos' annotated frames)

// The learned detector's stage after its network (shaftsOfProbability()) fed the annotated
// shaft and instrument (shaft or jaws) masks, reduced to the network's input size and back as the
// network's output is: what the line stage makes of a perfect mask, the ceiling of any network at
// that size. With a model that gives the shaft's sides, they are the annotated ones, as the
// training labels them (train_shaft_net.py's side_band()).
class AnnotatedMaskDetector final : public ShaftDetector {
 public:
  AnnotatedMaskDetector(SegmentationParams const& p, ShaftNet const& net)
      : params_(p), net_size_(net.inputSize()), sides_(net.hasSides()) {}
  /// The annotated classes (CV_8U, full resolution): 160 shaft, 70 jaws.
  void setClasses(cv::Mat const& cls) { classes_ = cls; }
  std::unique_ptr<ShaftDetector> clone() const override { return std::make_unique<AnnotatedMaskDetector>(*this); }
  SegmentationResult detect(DetectionFrame const& frame) override {
    ShaftProbabilities p{asNetwork(classes_ == 160, frame), asNetwork((classes_ == 160) | (classes_ == 70), frame)};
    if (sides_) p.side = sideBand(frame);
    p.shaft.convertTo(feature_, CV_8U, -255.0, 255.0);
    return shaftsOfProbability(frame, p, params_, labels_);
  }
  bool followable() const override { return true; }
  void setParams(SegmentationParams const& p) override { params_ = p; }
  void reset() override {}
  cv::Mat const& feature() const override { return feature_; }
  cv::Mat const& labels() const override { return labels_; }

 private:
  cv::Mat asNetwork(cv::Mat const& mask, DetectionFrame const& frame) const {  // at the network's size and back
    cv::Mat small, p;
    cv::resize(mask, small, net_size_, 0, 0, cv::INTER_AREA);
    small.convertTo(small, CV_32F, 1.0 / 255.0);
    cv::resize(small, p, frame.fov.mask.size(), 0, 0, cv::INTER_LINEAR);
    return p;
  }
  // The pixels on either side of a shaft / background boundary at the network's size (the view's
  // black edge ends the labels, not the shaft: no side there), at the processing size.
  cv::Mat sideBand(DetectionFrame const& frame) const {
    cv::Mat small, near_shaft, near_background, grey, dark, band, p;
    cv::resize(classes_, small, net_size_, 0, 0, cv::INTER_NEAREST);
    cv::Mat const shaft = small == 160, background = small == 0, k = cv::Mat::ones(3, 3, CV_8U);
    cv::dilate(shaft, near_shaft, k);
    cv::dilate(background, near_background, k);
    band = (near_shaft & background) | (near_background & shaft);
    std::vector<cv::Mat> ch;
    cv::split(frame.bgr, ch);
    cv::max(ch[0], ch[1], grey);
    cv::max(grey, ch[2], grey);
    cv::dilate(grey < 15, dark, cv::Mat::ones(9, 9, CV_8U));
    cv::resize(dark, dark, net_size_, 0, 0, cv::INTER_NEAREST);
    band.setTo(0, dark);
    band.convertTo(band, CV_32F, 1.0 / 255.0);
    cv::resize(band, p, frame.fov.mask.size(), 0, 0, cv::INTER_LINEAR);
    return p;
  }
  SegmentationParams params_;
  cv::Size net_size_;
  bool sides_;
  cv::Mat classes_, feature_, labels_;
};

struct InvivoChecks {
  double min_found = -1.0, max_line_px = -1.0, max_false_per_image = -1.0;
  double min_strict_found = -1.0, max_strict_false_per_image = -1.0;  // strict scoring (shaft_scoring.h), at 10 px
};

// The strict scoring's summary lines for one set of frames.
void printStrict(char const* what, StrictScore const& s, int frames, char const* per) {
  std::printf("  %s: %d shafts, found", what, s.shafts);
  for (std::size_t k = 0; k < kFoundPx.size(); ++k)
    std::printf("%s %.1f %% (<= %.0f px)", k ? "," : "", 100.0 * s.found[k] / std::max(1, s.shafts), kFoundPx[k]);
  std::printf("; %d false = %.3f per %s; side median to its line: median %.2f px, p90 %.2f px\n", s.false_detections,
              static_cast<double>(s.false_detections) / std::max(1, frames), per, percentile(s.side_median_px, 0.5),
              percentile(s.side_median_px, 0.9));
}

// The network's shaft and instrument (shaft or jaws) masks at p >= 1/2 as the learned detector
// sees them (resized bilinearly to the processing size), brought to the frame's size.
struct NetworkMasks {
  cv::Mat shaft, instrument;
  NetworkMasks(ShaftProbabilities const& p, cv::Size processing, cv::Size frame)
      : shaft(atFrame(p.shaft, processing, frame)), instrument(atFrame(p.instrument, processing, frame)) {}
  /// The share of a mask's pixels that each covers (shaft, instrument).
  std::pair<double, double> cover(cv::Mat const& m) const {
    double const n = cv::countNonZero(m);
    return {cv::countNonZero(m & shaft) / n, cv::countNonZero(m & instrument) / n};
  }

 private:
  static cv::Mat atFrame(cv::Mat const& probability, cv::Size processing, cv::Size frame) {
    cv::Mat at_processing, mask;
    cv::resize(probability, at_processing, processing, 0, 0, cv::INTER_LINEAR);
    cv::resize(at_processing >= 0.5, mask, frame, 0, 0, cv::INTER_NEAREST);
    return mask;
  }
};

// Each pixel of the annotated mask's outline inside `valid`: its distance (px) to the network
// mask's outline (the outlines less the image's border).
void outlineDistances(cv::Mat const& annotated, cv::Mat const& network, cv::Mat const& valid, std::vector<double>& out) {
  auto outline = [](cv::Mat const& m) {
    cv::Mat e;
    cv::erode(m, e, cv::Mat());
    return cv::Mat(m & ~e);
  };
  cv::Mat dist;
  cv::distanceTransform(~outline(network), dist, cv::DIST_L2, cv::DIST_MASK_PRECISE);
  cv::Mat const a = outline(annotated) & valid;
  for (int y = 0; y < a.rows; ++y)
    for (int x = 0; x < a.cols; ++x)
      if (a.at<std::uint8_t>(y, x)) out.push_back(dist.at<float>(y, x));
}

// Returns false when a requested regression bound is violated.
bool evalInvivo(fs::path const& root, std::string const& overlay_dir, SegmentationParams const& sp, int min_area,
                InvivoChecks const& chk, std::vector<std::string> const& sites) {
  InvivoStats st;
  std::map<std::string, StrictScore> strict;  // per operation
  std::map<std::string, int> strict_images;
  std::map<std::string, int> covered;  // per operation: mask shafts the network covers (learned detector)
  std::map<std::string, int> covered_instrument;  // ... as shaft or jaws: a miss of the instrument, or of its class
  std::map<std::string, std::vector<double>> outline_px;  // ... the annotated instruments' outline: distance to the network's
  std::map<std::string, int> line_findable;  // per operation (--annotated-mask): found by a line fitted to each side
  std::vector<fs::path> files;
  for (std::string const& op : sites) {
    fs::path const raw = root / op / "Raw";
    if (!fs::exists(raw)) continue;
    for (auto const& e : fs::directory_iterator(raw)) files.push_back(e.path());
  }
  std::sort(files.begin(), files.end());
  AnnotatedMaskDetector* oracle = nullptr;
  InstrumentSegmenter seg = [&] {
    if (!annotated_mask) return InstrumentSegmenter(sp);
    auto d = std::make_unique<AnnotatedMaskDetector>(sp, ShaftNet(sp.learned.model));
    oracle = d.get();
    return InstrumentSegmenter(sp, std::move(d));
  }();
  // The learned detector's network once more, for its instrument mask (a diagnostic only).
  std::unique_ptr<ShaftNet> net;
  if (sp.detector == SegmentationParams::Detector::kLearned && !annotated_mask) net = std::make_unique<ShaftNet>(sp.learned.model);
  for (auto const& f : files) {
    cv::Mat const im = cv::imread(f.string(), cv::IMREAD_COLOR);
    std::string name = f.filename().string();
    std::string const base = name.substr(0, name.find("_raw"));
    cv::Mat const cls = cv::imread((f.parent_path().parent_path() / "Masks" / (base + "_class.png")).string(), cv::IMREAD_GRAYSCALE);
    cv::Mat const ins = cv::imread((f.parent_path().parent_path() / "Masks" / (base + "_instrument.png")).string(), cv::IMREAD_GRAYSCALE);
    if (im.empty() || cls.empty() || ins.empty()) {
      std::fprintf(stderr, "skipping %s: unreadable image or masks\n", f.c_str());
      continue;
    }
    ++st.images;
    seg.reset();  // stills: no temporal state
    if (oracle) oracle->setClasses(cls);
    SegmentationResult r = seg.process(im);
    if (baseline) {
      r.contours = detectShaftsHough(im);
      r.regions.clear();
      r.region_status.clear();
      r.seeds.clear();
    }
    // The field of view at full resolution, less 3 px at its edge.
    cv::Mat inner_fov;
    cv::resize(seg.fieldOfView().mask, inner_fov, im.size(), 0, 0, cv::INTER_NEAREST);
    cv::erode(inner_fov, inner_fov, cv::getStructuringElement(cv::MORPH_RECT, cv::Size(7, 7)), cv::Point(-1, -1), 1,
              cv::BORDER_CONSTANT, cv::Scalar(255));
    // Instances: shaft pixels (class 160) of each instrument id.
    std::map<int, cv::Mat> shafts, whole;
    std::map<int, std::pair<cv::Mat, cv::Mat>> mask_normal;  // per instance: x and y gradient of its smoothed shaft mask
    for (int y = 0; y < ins.rows; ++y)
      for (int x = 0; x < ins.cols; ++x) {
        int const id = ins.at<std::uint8_t>(y, x);
        if (id == 0) continue;
        if (!whole.count(id)) {
          whole[id] = cv::Mat::zeros(ins.size(), CV_8U);
          shafts[id] = cv::Mat::zeros(ins.size(), CV_8U);
        }
        whole[id].at<std::uint8_t>(y, x) = 255;
        if (cls.at<std::uint8_t>(y, x) == 160) shafts[id].at<std::uint8_t>(y, x) = 255;
      }
    std::vector<int> ids;
    for (auto const& [id, m] : shafts)
      if (cv::countNonZero(m) >= min_area) ids.push_back(id);
    // Strict scoring: every instance with kStrictMinPx of shaft mask, its sides against the lines.
    {
      std::vector<MaskShaft> ms;
      cv::Mat const jaws = cls == 70;
      for (auto const& [id, m] : shafts)
        if (cv::countNonZero(m) >= kStrictMinPx) ms.push_back(maskShaft(m, jaws));
      std::string const op = f.parent_path().parent_path().filename().string();
      StrictScore const sc = scoreStrict(ms, r.contours);
      strict[op] += sc;
      // The learned detector: the mask shafts its network covers (half of their pixels at
      // p >= 1/2), found or not -- what the network gives the contour fit.
      std::vector<std::pair<double, double>> cover;  // per mask shaft (ms): its fraction the network covers, as shaft / instrument
      if (net) {
        NetworkMasks const nm(net->probabilities(im), seg.fieldOfView().mask.size(), im.size());
        outlineDistances((cls == 160) | (cls == 70), nm.instrument, inner_fov, outline_px[op]);
        for (auto const& [id, m] : shafts)
          if (cv::countNonZero(m) >= kStrictMinPx) {
            cover.push_back(nm.cover(m));
            covered[op] += cover.back().first >= 0.5;
            covered_instrument[op] += cover.back().second >= 0.5;
          }
      }
      // The scoring's own ceiling: each side's total least-squares line as the detection's.
      if (oracle)
        for (MaskShaft const& s : ms) {
          if (s.sides[0].empty()) continue;
          auto const l0 = fitLineLS(s.sides[0]), l1 = fitLineLS(s.sides[1]);
          if (!l0 || !l1) continue;
          double const cost = std::max(endo_guidance::tools::sideMedianPx(s.sides[0], *l0), endo_guidance::tools::sideMedianPx(s.sides[1], *l1));
          line_findable[op] += cost <= kFoundPx.back();
        }
      ++strict_images[op];
      if (verbose)
        for (std::size_t i = 0; i < ms.size(); ++i)
          if (sc.match[i] < 0) {
            double best = std::numeric_limits<double>::infinity();
            for (auto const& c : r.contours) best = std::min(best, endo_guidance::tools::findCost(ms[i], c));
            std::printf("  strict miss %s/%s: a shaft of %d px (sides of %zu and %zu px), the nearest detection's larger side median %.1f px",
                        op.c_str(), base.c_str(), ms[i].pixels, ms[i].sides[0].size(), ms[i].sides[1].size(), best);
            if (i < cover.size())
              std::printf("; the network covers %.0f %% of it as shaft, %.0f %% as shaft or jaws", 100.0 * cover[i].first, 100.0 * cover[i].second);
            std::printf("\n");
          }
      if (verbose)  // each false detection, with what the annotation has under its strip
        for (std::size_t d = 0; d < r.contours.size(); ++d) {
          if (std::find(sc.match.begin(), sc.match.end(), static_cast<int>(d)) != sc.match.end()) continue;
          cv::Mat strip = cv::Mat::zeros(im.size(), CV_8U);
          cv::fillConvexPoly(strip, shaftPolygon(r.contours[d]), 255);
          int const n = std::max(1, cv::countNonZero(strip));
          std::printf("  strict false %s/%s: detection %zu, its strip %.0f %% shaft, %.0f %% jaws class\n", op.c_str(), base.c_str(), d,
                      100.0 * cv::countNonZero(strip & (cls == 160)) / n, 100.0 * cv::countNonZero(strip & jaws) / n);
        }
    }
    st.shafts += static_cast<int>(ids.size());
    std::map<int, double> found;  // per shaft found: the smallest line median among its detections
    for (auto const& c : r.contours) {
      ++st.detections;
      cv::Mat det = cv::Mat::zeros(im.size(), CV_8U);
      cv::fillConvexPoly(det, shaftPolygon(c), 255);
      double const area = std::max(1, cv::countNonZero(det));
      int best = -1;
      double bo = 0.0;
      for (auto const& [id, m] : whole) {
        double const o = cv::countNonZero(det & m) / area;
        if (o > bo) {
          bo = o;
          best = id;
        }
      }
      if (best < 0 || bo < 0.5) {
        ++st.false_shafts;
        if (verbose)
          std::printf("  false %s/%s: entry (%.0f %.0f) tip (%.0f %.0f) residual %.2f overlap %.2f\n",
                      f.parent_path().parent_path().filename().c_str(), base.c_str(), c.entry_px.x(), c.entry_px.y(),
                      c.tip_px.x(), c.tip_px.y(), c.residual_px, bo);
        continue;
      }
      if (std::find(ids.begin(), ids.end(), best) == ids.end()) continue;  // a tiny instance: neither
      found.emplace(best, 25.0);  // (25 px: the most a detection counts, below)
      // Boundary of the instance's shaft mask, inside the image and the field of view, between
      // the entry and the tip: each pixel to the nearer contour line. (Where the shaft leaves the
      // view its mask ends on the image border -- the erosion's border counts as mask -- or on
      // the edge of a circular field of view: neither is a side of the shaft.)
      cv::Mat er, bd;
      cv::erode(shafts[best], er, cv::Mat());
      bd = shafts[best] & ~er & inner_fov;
      // The mask's normal (gradient of the smoothed mask), once per instance: a boundary pixel
      // whose normal is within 60 deg of the axis runs across the shaft -- where the annotation
      // ends the shaft class (at the jaws' joint, or at a metal sleeve labelled apart) or where
      // something occludes it -- and is no side of the shaft.
      if (!mask_normal.count(best)) {
        cv::Mat mf, gx, gy;
        shafts[best].convertTo(mf, CV_32F, 1.0 / 255.0);
        cv::GaussianBlur(mf, mf, cv::Size(7, 7), 1.5);
        cv::Sobel(mf, gx, CV_32F, 1, 0);
        cv::Sobel(mf, gy, CV_32F, 0, 1);
        mask_normal[best] = {gx, gy};
      }
      cv::Mat const& ngx = mask_normal[best].first;
      cv::Mat const& ngy = mask_normal[best].second;
      Eigen::Vector2d const ax = (c.tip_px - c.entry_px).normalized();
      double const len = (c.tip_px - c.entry_px).norm();
      std::vector<double> d, signed_d, d_all;
      for (int y = 2; y < bd.rows - 2; ++y)
        for (int x = 2; x < bd.cols - 2; ++x) {
          if (!bd.at<std::uint8_t>(y, x)) continue;
          Eigen::Vector2d const q(x, y);
          double const t = ax.dot(q - c.entry_px);
          if (t < 0.05 * len || t > 0.95 * len) continue;
          Eigen::Vector3d const h(x, y, 1.0);
          double const e0 = c.lines[0].dot(h), e1 = c.lines[1].dot(h);
          double const e = std::min(std::abs(e0), std::abs(e1));
          if (e > 25.0) continue;  // not this shaft's side (jaws, the other end)
          d_all.push_back(e);
          Eigen::Vector2d const g(ngx.at<float>(y, x), ngy.at<float>(y, x));
          if (!(g.norm() > 0.0) || std::abs(g.normalized().dot(ax)) >= 0.5) continue;  // across the shaft
          d.push_back(e);
          signed_d.push_back(std::abs(e0) < std::abs(e1) ? e0 : e1);
        }
      // A detection matched to the shaft with none of the mask's sides within 25 px of its lines
      // (a strip along its edge) counts as 25 px off, not as no measurement.
      st.all_dist_px.insert(st.all_dist_px.end(), d.begin(), d.end());
      st.line_median_all_px.push_back(d_all.empty() ? 25.0 : percentile(d_all, 0.5));
      st.line_median_px.push_back(d.empty() ? 25.0 : percentile(d, 0.5));
      found[best] = std::min(found[best], st.line_median_px.back());
      if (verbose)
        std::printf("  hit %s/%s id %d: line to mask sides median %.2f px (signed, + = mask inside the lines: %.2f; whole boundary %.2f), residual %.2f px, width %.1f px at the entry, %.1f at the tip\n",
                    f.parent_path().parent_path().filename().c_str(), base.c_str(), best, st.line_median_px.back(),
                    signed_d.empty() ? 0.0 : percentile(signed_d, 0.5), st.line_median_all_px.back(), c.residual_px,
                    shaftWidthAt(c, c.entry_px), shaftWidthAt(c, c.tip_px));
    }
    for (int id : ids) st.found += found.count(id) ? 1 : 0;
    for (auto const& [id, line] : found)
      for (std::size_t k = 0; k < InvivoStats::kCloseLinePx.size(); ++k) st.found_close[k] += line <= InvivoStats::kCloseLinePx[k];
    // Why each missed shaft was missed: no seed on it, or the fate of the regions grown from it.
    double const sc = r.scale, so = 0.5 * (r.scale - 1);
    for (int id : ids) {
      if (found.count(id)) continue;
      cv::Mat dil;
      cv::dilate(whole[id], dil, cv::Mat(), {-1, -1}, 12);
      std::string why = baseline ? "not found by the baseline" : "no seed";
      for (std::size_t k = 0; k < r.regions.size(); ++k) {
        // The region (scaled to full resolution) lies mostly on this instrument.
        std::vector<cv::Point> poly;
        for (auto const& q : r.regions[k].boundary)
          poly.emplace_back(static_cast<int>(q.x * sc + so), static_cast<int>(q.y * sc + so));
        cv::Mat rm = cv::Mat::zeros(im.size(), CV_8U);
        cv::fillPoly(rm, std::vector<std::vector<cv::Point>>{poly}, 255);
        double const a = std::max(1, cv::countNonZero(rm));
        if (cv::countNonZero(rm & dil) > 0.3 * a) {
          why = toString(r.region_status[k]);
          if (r.region_status[k] == ContourRejection::kNone) why = "detected but not matched";
          break;
        }
      }
      if (why == "no seed" && !baseline)
        for (auto const& sd : r.seeds) {
          cv::Point const q(static_cast<int>(sd.position.x * sc + so), static_cast<int>(sd.position.y * sc + so));
          if (dil.at<std::uint8_t>(q)) why = "seed without region";
        }
      st.misses[why]++;
      if (verbose) std::printf("  miss %s/%s id %d: %s\n", f.parent_path().parent_path().filename().c_str(), base.c_str(), id, why.c_str());
    }
    if (verbose) {
      std::printf("%s/%s: %zu seeds, %zu regions [", f.parent_path().parent_path().filename().c_str(), base.c_str(),
                  r.seeds.size(), r.regions.size());
      for (std::size_t i = 0; i < r.regions.size(); ++i)
        std::printf("%s(t%d,a%d)%s", toString(r.region_status[i]), r.regions[i].threshold, r.regions[i].area,
                    i + 1 < r.regions.size() ? "; " : "");
      int nf = 0;
      for (int id : ids) nf += found.count(id) ? 1 : 0;
      std::printf("] found %d/%zu\n", nf, ids.size());
    }
    if (!overlay_dir.empty()) {
      cv::Mat ov = im.clone();
      for (int id : ids) {
        std::vector<std::vector<cv::Point>> cs;
        cv::findContours(shafts[id].clone(), cs, cv::RETR_EXTERNAL, cv::CHAIN_APPROX_SIMPLE);
        cv::drawContours(ov, cs, -1, found.count(id) ? cv::Scalar(0, 200, 0) : cv::Scalar(0, 0, 255), 1);
      }
      drawSegmentationOverlay(ov, r);
      fs::create_directories(overlay_dir);
      cv::imwrite((fs::path(overlay_dir) / (f.parent_path().parent_path().filename().string() + "_" + base + ".png")).string(), ov);
    }
  }
  std::printf("in-vivo stills (%s): %d images, %d shafts (>= %d px of shaft mask)\n", root.c_str(), st.images, st.shafts, min_area);
  std::printf("  shafts found      %d / %d = %.1f %%\n", st.found, st.shafts, 100.0 * st.found / std::max(1, st.shafts));
  std::printf("  ... with lines within");
  for (std::size_t k = 0; k < InvivoStats::kCloseLinePx.size(); ++k)
    std::printf("%s %.0f px: %d (%.1f %%)", k ? "," : "", InvivoStats::kCloseLinePx[k], st.found_close[k],
                100.0 * st.found_close[k] / std::max(1, st.shafts));
  std::printf(" (median to the mask's sides, the shaft's closest detection)\n");
  std::printf("  false shafts      %d in %d images = %.3f per image (%d detections)\n", st.false_shafts, st.images,
              static_cast<double>(st.false_shafts) / std::max(1, st.images), st.detections);
  std::printf("  missed shafts by cause:");
  for (auto const& [k, v] : st.misses) std::printf(" [%s: %d]", k.c_str(), v);
  std::printf("\n");
  std::printf("  contour line to the shaft mask's sides: median of per-detection medians (a shaft found twice counts twice) %.2f px, p90 %.2f px; "
              "all side px: median %.2f px, p95 %.2f px\n",
              percentile(st.line_median_px, 0.5), percentile(st.line_median_px, 0.9), percentile(st.all_dist_px, 0.5), percentile(st.all_dist_px, 0.95));
  std::printf("  (to the mask's whole boundary near the lines, its ends across the shaft too: median of per-detection medians %.2f px)\n",
              percentile(st.line_median_all_px, 0.5));
  std::printf("  strict scoring (mask shafts of >= %d px; each side's median distance to its line):\n", kStrictMinPx);
  StrictScore all;
  int all_images = 0;
  for (auto const& [op, sc] : strict) {
    printStrict(op.c_str(), sc, strict_images[op], "image");
    if (net) {
      std::vector<double>& d = outline_px[op];
      std::printf("  %s: the network covers %d of the %d shafts (half of their pixels at p >= 1/2), %d as shaft or jaws; the annotated "
                  "instruments' outline lies %.1f px (median) from its outline, %.0f %% of it beyond 8 px\n", op.c_str(), covered[op],
                  sc.shafts, covered_instrument[op], percentile(d, 0.5),
                  100.0 * static_cast<double>(std::count_if(d.begin(), d.end(), [](double v) { return v > 8.0; })) / std::max<std::size_t>(1, d.size()));
    }
    if (oracle)
      std::printf("  %s: %d of the %d shafts are found by a total least-squares line on each of their sides (the scoring's ceiling)\n",
                  op.c_str(), line_findable[op], sc.shafts);
    all += sc;
    all_images += strict_images[op];
  }
  printStrict("all", all, all_images, "image");
  bool ok = true;
  double const strict_found = static_cast<double>(all.found.back()) / std::max(1, all.shafts);
  double const strict_fpi = static_cast<double>(all.false_detections) / std::max(1, all_images);
  if (chk.min_strict_found >= 0.0 && !(strict_found >= chk.min_strict_found)) ok = false;
  if (chk.max_strict_false_per_image >= 0.0 && !(strict_fpi <= chk.max_strict_false_per_image)) ok = false;
  if (chk.min_strict_found >= 0.0 || chk.max_strict_false_per_image >= 0.0)
    std::printf("  strict regression bounds (found >= %.2f, false/image <= %.3f): %s\n", chk.min_strict_found,
                chk.max_strict_false_per_image, ok ? "met" : "VIOLATED");
  double const found = static_cast<double>(st.found) / std::max(1, st.shafts);
  double const fpi = static_cast<double>(st.false_shafts) / std::max(1, st.images);
  double const line = percentile(st.line_median_px, 0.5);
  bool old_ok = true;
  if (chk.min_found >= 0.0 && !(found >= chk.min_found)) old_ok = false;
  if (chk.max_line_px >= 0.0 && !(line <= chk.max_line_px)) old_ok = false;
  if (chk.max_false_per_image >= 0.0 && !(fpi <= chk.max_false_per_image)) old_ok = false;
  if (chk.min_found >= 0.0 || chk.max_line_px >= 0.0 || chk.max_false_per_image >= 0.0)
    std::printf("  regression bounds (found >= %.2f, line <= %.2f px, false/image <= %.3f): %s\n", chk.min_found,
                chk.max_line_px, chk.max_false_per_image, old_ok ? "met" : "VIOLATED");
  return ok && old_ok;
}

// Each tool's trocar from the axes of its own detections (the annotation says which tool a
// detection is; the pipeline's discovery gets no such help): the robust common point (Eq. (3),
// LMedS) of all of them, how ill-conditioned it is (the angular spread of the axes; the
// estimate's standard deviations along its principal directions, the longest compared with the
// mean axis), and its stability: the same estimate from consecutive blocks of 20 axes (about 4 s
// of video), their RMS deviation from the whole-clip estimate along and across the mean axis.
void reportToolTrocars(std::map<int, std::vector<PluckerLine>> const& tool_axes, std::map<int, std::vector<double>> const& tool_image_deg,
                       Eigen::Matrix3d const& K, cv::Size size) {
  for (auto const& [tool, axes] : tool_axes) {
    double span = 0.0;  // of the annotated image directions (deg)
    if (auto const it = tool_image_deg.find(tool); it != tool_image_deg.end() && !it->second.empty())
      span = *std::max_element(it->second.begin(), it->second.end()) - *std::min_element(it->second.begin(), it->second.end());
    if (axes.size() < 10) {
      std::printf("    tool %d: %zu axes, too few for a trocar\n", tool, axes.size());
      continue;
    }
    InsertionPointEstimate const e = intersectAxesRobust(axes);
    if (!e.ok()) {
      std::printf("    tool %d: %zu axes, no common point (%s)\n", tool, axes.size(), toString(e.status));
      continue;
    }
    // Mean axis direction (sign-aligned) and the estimate's principal directions.
    Eigen::Vector3d dm = Eigen::Vector3d::Zero();
    for (auto const& a : axes) dm += a.direction().dot(axes.front().direction()) < 0.0 ? -a.direction() : a.direction();
    dm.normalize();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(e.covariance);
    Eigen::Vector3d const sd = es.eigenvalues().cwiseMax(0.0).cwiseSqrt();
    double const major_to_axis = std::acos(std::min(1.0, std::abs(es.eigenvectors().col(2).dot(dm)))) * 180.0 / M_PI;
    Eigen::Vector3d const ip = K * e.position;
    Eigen::Vector2d const px = ip.head<2>() / ip.z();
    bool const inside = ip.z() > 0 && px.x() >= 0 && px.y() >= 0 && px.x() < size.width && px.y() < size.height;
    // Blocks of 20 consecutive axes.
    double along2 = 0.0, across2 = 0.0;
    int blocks = 0;
    for (std::size_t b = 0; b + 20 <= axes.size(); b += 20) {
      InsertionPointEstimate const eb = intersectAxesRobust(std::vector<PluckerLine>(axes.begin() + b, axes.begin() + b + 20));
      if (!eb.ok()) continue;
      Eigen::Vector3d const dv = eb.position - e.position;
      along2 += dv.dot(dm) * dv.dot(dm);
      across2 += (dv - dv.dot(dm) * dm).squaredNorm();
      ++blocks;
    }
    std::printf("    tool %d: %zu axes, %zu inliers, rms %.1f mm: (%.0f, %.0f, %.0f) mm, image (%.0f, %.0f)%s; 3-D axes' spread "
                "%.1f deg (annotated image directions span %.1f deg); sd %.1f / %.1f / %.1f mm (%.0f:1, the longest %.0f deg "
                "from the mean axis); %d blocks of 20 axes: RMS %.0f mm along the axis, %.1f mm across\n",
                tool, axes.size(), e.inliers.size(), e.rms_distance * 1e3, e.position.x() * 1e3, e.position.y() * 1e3,
                e.position.z() * 1e3, px.x(), px.y(), inside ? " INSIDE the image" : " outside the image",
                std::asin(std::min(1.0, e.conditioning)) * 180.0 / M_PI, span, sd(2) * 1e3, sd(1) * 1e3, sd(0) * 1e3,
                sd(2) / std::max(sd(1), 1e-9), major_to_axis, blocks, blocks ? std::sqrt(along2 / blocks) * 1e3 : 0.0,
                blocks ? std::sqrt(across2 / blocks) * 1e3 : 0.0);
  }
}

// The robotic mask videos' shafts: each frame's pixels snapped to 0 / 70 / 160, one mask shaft
// per connected component of class 160 with kStrictRoboticMinPx (`components`: their masks).
std::vector<MaskShaft> roboticMaskShafts(std::vector<cv::Mat> const& masks, std::vector<cv::Mat>* components = nullptr) {
  cv::Mat shaft, jaws;
  for (cv::Mat const& m : masks) {
    cv::Mat g;
    cv::cvtColor(m, g, cv::COLOR_BGR2GRAY);
    cv::Mat const s = g >= 115, j = (g >= 35) & (g < 115);  // nearest of {0, 70, 160}
    shaft = shaft.empty() ? s : (shaft | s);
    jaws = jaws.empty() ? j : (jaws | j);
  }
  cv::Mat labels, stats, centroids;
  int const n = cv::connectedComponentsWithStats(shaft, labels, stats, centroids, 8, CV_32S);
  std::vector<MaskShaft> ms;
  for (int k = 1; k < n; ++k)
    if (stats.at<int>(k, cv::CC_STAT_AREA) >= kStrictRoboticMinPx) {
      cv::Mat const c = labels == k;
      ms.push_back(maskShaft(c, jaws));
      if (components) components->push_back(c);
    }
  return ms;
}

// The mask videos' classes combined (CV_8U, full resolution): each pixel snapped to the nearest
// of 0, 70 (head and jaws) and 160 (shaft), the larger where the videos overlap.
cv::Mat roboticClasses(std::vector<cv::Mat> const& masks) {
  cv::Mat out;
  for (cv::Mat const& m : masks) {
    cv::Mat g, c;
    cv::cvtColor(m, g, cv::COLOR_BGR2GRAY);
    c = cv::Mat::zeros(g.size(), CV_8U);
    c.setTo(70, (g >= 35) & (g < 115));
    c.setTo(160, g >= 115);
    out = out.empty() ? c : cv::max(out, c);
  }
  return out;
}

// Annotated axes found: a detection's image axis (bisector of its lines) within kAxisFoundPx of
// both annotated points, each annotation and detection used once (nearest first).
constexpr double kAxisFoundPx = 40.0;
template <typename Ann>
int axesFound(std::vector<Ann> const& annotated, std::vector<ApparentContour> const& detections) {
  std::vector<std::tuple<double, std::size_t, std::size_t>> pairs;
  for (std::size_t i = 0; i < annotated.size(); ++i)
    for (std::size_t j = 0; j < detections.size(); ++j) {
      ImageLine const l = imageAxis(detections[j]);
      double const d = std::max(std::abs(l.dot(annotated[i].a.homogeneous())), std::abs(l.dot(annotated[i].b.homogeneous())));
      if (d <= kAxisFoundPx) pairs.emplace_back(d, i, j);
    }
  std::sort(pairs.begin(), pairs.end());
  std::vector<char> ua(annotated.size()), ud(detections.size());
  int found = 0;
  for (auto const& [d, i, j] : pairs)
    if (!ua[i] && !ud[j]) {
      ua[i] = ud[j] = 1;
      ++found;
    }
  return found;
}

// Regression bounds per robotic sequence (negative: none): the annotated axes found (within
// 20 px) and false detections per frame; the mask shafts found and false per frame (strict, 10 px).
struct RoboticChecks {
  double min_found = -1.0, max_false_per_frame = -1.0;
  double min_strict_found = -1.0, max_strict_false_per_frame = -1.0;
};

// Whether a found fraction and a false rate keep their bounds (a negative bound: none).
bool withinBounds(double found, double min_found, double false_rate, double max_false) {
  return (min_found < 0.0 || found >= min_found) && (max_false < 0.0 || false_rate <= max_false);
}

// Returns false when a requested regression bound (per sequence) is violated.
bool evalRobotic(fs::path const& root, std::string const& overlay_dir, SegmentationParams const& sp, RoboticChecks const& chk) {
  std::ifstream csv(root / "shaft_axis_annotations.csv");
  if (!csv) {
    std::printf("robotic sequences: %s/shaft_axis_annotations.csv absent: skipped\n", root.c_str());
    return true;
  }
  bool ok = true;
  struct Ann { int frame, tool; Eigen::Vector2d a, b; };
  std::map<int, std::vector<Ann>> ann;  // per dataset
  std::string line;
  std::getline(csv, line);
  while (std::getline(csv, line)) {
    std::stringstream ss(line);
    std::string tok;
    std::vector<std::string> t;
    while (std::getline(ss, tok, ',')) t.push_back(tok);
    if (t.size() < 7) continue;
    std::string const digits = t[2].substr(std::min(t[2].size(), t[2].find_first_of("0123456789")));  // "tool1" -> 1
    int const tool = digits.empty() ? 0 : std::stoi(digits);
    ann[std::stoi(t[0])].push_back({std::stoi(t[1]), tool, {std::stod(t[3]), std::stod(t[4])}, {std::stod(t[5]), std::stod(t[6])}});
  }
  for (auto const& [ds, list] : ann) {
    fs::path const video = root / ("Dataset" + std::to_string(ds)) / "Video.avi";
    cv::VideoCapture cap(video.string());
    if (!cap.isOpened()) {
      std::printf("robotic dataset %d: cannot open %s: skipped\n", ds, video.c_str());
      continue;
    }
    // No intrinsics are published for these sequences: assumed pinhole, fx = fy = 700 px at the
    // image centre (about 54 deg horizontal field of view), 8 mm shafts.
    Eigen::Matrix3d K;
    K << 700, 0, 359.5, 0, 700, 287.5, 0, 0, 1;
    PipelineParams pp;
    pp.segmentation = sp;
    pp.radius = 0.004;
    Pipeline pipe(K, cv::Size(720, 576), pp);
    std::vector<double> ang, dist;
    int n = 0, found = 0, frame = 0, dets = 0, frames_annot = 0, false_dets = 0;
    // Mean distance (px) of an annotated axis's two points to an image axis.
    auto offAxis = [](Eigen::Vector3d const& l, Ann const& a) { return 0.5 * (std::abs(l.dot(a.a.homogeneous())) + std::abs(l.dot(a.b.homogeneous()))); };
    // The mask videos (one per instrument in Dataset 1), read in step with the frames.
    std::vector<cv::VideoCapture> mask_caps;
    for (auto const& e : fs::directory_iterator(video.parent_path()))
      if (e.path().filename().string().find("Segmentation.avi") != std::string::npos) mask_caps.emplace_back(e.path().string());
    StrictScore strict;
    int axes_found40 = 0;
    int covered = 0, covered_instrument = 0;  // mask shafts the network covers, as shaft / as shaft or jaws (learned detector)
    std::unique_ptr<ShaftNet> net;
    if (sp.detector == SegmentationParams::Detector::kLearned && !annotated_mask) net = std::make_unique<ShaftNet>(sp.learned.model);
    // --annotated-mask: each annotated frame on its own (no tracking, no pipeline), its mask
    // videos' classes as the network's output.
    AnnotatedMaskDetector* oracle = nullptr;
    std::optional<InstrumentSegmenter> oracle_seg;
    SegmentationResult oracle_result;
    if (annotated_mask) {
      auto d = std::make_unique<AnnotatedMaskDetector>(sp, ShaftNet(sp.learned.model));
      oracle = d.get();
      oracle_seg.emplace(sp, std::move(d));
    }
    cv::Mat im;
    std::map<int, std::vector<Ann>> by_frame;
    for (auto const& a : list) by_frame[a.frame].push_back(a);
    std::map<int, std::vector<Eigen::Vector3d>> trocar_track;  // id -> positions over the second half
    std::map<int, Eigen::Vector3d> trocar_image;
    PipelineOutput out;
    std::vector<PluckerLine> all_axes;
    std::map<int, std::vector<PluckerLine>> tool_axes;  // per annotated tool: the 3-D axes of its detections, in time order
    std::map<int, std::vector<ImageLine>> tool_lines;  // ... and their image axes
    std::vector<cv::Mat> mask_frames(mask_caps.size());
    while (cap.read(im)) {
      if (im.size() != cv::Size(720, 576)) break;
      bool masks_ok = !mask_caps.empty();
      for (std::size_t k = 0; k < mask_caps.size(); ++k) masks_ok = mask_caps[k].read(mask_frames[k]) && masks_ok;
      auto it = by_frame.find(frame);
      if (oracle) {
        if (it == by_frame.end() || !masks_ok) {
          ++frame;
          continue;
        }
        oracle->setClasses(roboticClasses(mask_frames));
        oracle_seg->reset();
        oracle_result = oracle_seg->process(im);
      } else {
        out = pipe.process(im);
      }
      for (auto const& o : out.instruments) all_axes.push_back(o.pose.axis);
      if (frame > 185)
        for (auto const& p : out.insertion_points) {
          trocar_track[p.id].push_back(p.estimate.position);
          trocar_image[p.id] = p.image_point;
        }
      if (it != by_frame.end()) {
        SegmentationResult const& r = oracle ? oracle_result : out.segmentation;
        ++frames_annot;
        dets += static_cast<int>(r.contours.size());
        // A detection whose image axis passes within 20 px of no annotated shaft axis is false.
        for (auto const& c : r.contours) {
          Eigen::Vector3d const l = imageAxis(c);
          bool near = false;
          for (auto const& a : it->second) near = near || offAxis(l, a) < 20.0;
          false_dets += !near;
          if (verbose && !near)
            std::printf("  false ds%d frame %d (%s): entry (%.0f %.0f) tip (%.0f %.0f)\n", ds, frame, r.tracked ? "tracked" : "detected",
                        c.entry_px.x(), c.entry_px.y(), c.tip_px.x(), c.tip_px.y());
        }
        std::vector<MaskShaft> ms;  // (the overlay draws their sides)
        if (masks_ok) {
          std::vector<cv::Mat> components;
          ms = roboticMaskShafts(mask_frames, net ? &components : nullptr);
          StrictScore const sc = scoreStrict(ms, r.contours);
          strict += sc;
          if (verbose) {  // each mask shaft missed and each false detection at 10 px
            for (std::size_t i = 0; i < ms.size(); ++i)
              if (sc.match[i] < 0) {
                double best = std::numeric_limits<double>::infinity();
                for (auto const& c : r.contours) best = std::min(best, endo_guidance::tools::findCost(ms[i], c));
                std::printf("  strict miss ds%d frame %d: a mask shaft of %d px (sides of %zu and %zu px), the nearest detection's "
                            "larger side median %.1f px\n", ds, frame, ms[i].pixels, ms[i].sides[0].size(), ms[i].sides[1].size(), best);
              }
            for (std::size_t d = 0; d < r.contours.size(); ++d)
              if (std::find(sc.match.begin(), sc.match.end(), static_cast<int>(d)) == sc.match.end())
                std::printf("  strict false ds%d frame %d: entry (%.0f %.0f) tip (%.0f %.0f)\n", ds, frame, r.contours[d].entry_px.x(),
                            r.contours[d].entry_px.y(), r.contours[d].tip_px.x(), r.contours[d].tip_px.y());
          }
          if (net) {  // the network's cover of each, as for the stills
            NetworkMasks const nm(net->probabilities(im), cv::Size(im.cols / r.scale, im.rows / r.scale), im.size());
            for (cv::Mat const& m : components) {
              auto const [shaft, instrument] = nm.cover(m);
              covered += shaft >= 0.5;
              covered_instrument += instrument >= 0.5;
            }
          }
        }
        axes_found40 += axesFound(it->second, r.contours);
        for (auto const& a : it->second) {
          ++n;
          Eigen::Vector2d const da = (a.b - a.a).normalized();
          double best = 1e9, ba = 0.0;
          for (auto const& c : r.contours) {
            // Image axis: the bisector of the two contour lines (their normals point inward).
            Eigen::Vector3d const l = imageAxis(c);
            double const e = offAxis(l, a);
            Eigen::Vector2d const dl(-l.y(), l.x());
            double const an = std::acos(std::min(1.0, std::abs(dl.dot(da)))) * 180.0 / M_PI;
            if (e < best) {
              best = e;
              ba = an;
            }
          }
          if (best < 20.0) {
            ++found;
            dist.push_back(best);
            ang.push_back(ba);
            // Its 3-D axis (the reported instrument on that image axis), for this tool's trocar.
            for (auto const& o : out.instruments) {
              ImageLine const l = imageAxis(o.contour);
              if (offAxis(l, a) < 20.0) {
                tool_axes[a.tool].push_back(o.pose.axis);
                tool_lines[a.tool].push_back(l);
                break;
              }
            }
          } else if (verbose) {
            std::printf("  miss ds%d frame %d (%s): annotated axis (%.0f %.0f)-(%.0f %.0f)\n", ds, frame, r.tracked ? "tracked" : "detected",
                        a.a.x(), a.a.y(), a.b.x(), a.b.y());
          }
        }
        if (verbose) {
          std::printf("  ds%d frame %d: %zu regions [", ds, frame, r.regions.size());
          for (std::size_t i = 0; i < r.regions.size() && i < r.region_status.size(); ++i)
            std::printf("%s(a%d)%s", toString(r.region_status[i]), r.regions[i].area, i + 1 < r.regions.size() ? "; " : "");
          std::printf("]\n");
        }
        if (!overlay_dir.empty() && (frames_annot % 10 == 1 || verbose)) {  // (--verbose: every annotated frame)
          cv::Mat ov = im.clone();
          std::vector<Eigen::Vector3d> ti;
          for (auto const& p : out.insertion_points) ti.push_back(p.image_point);
          drawSegmentationOverlay(ov, r, ti);
          for (auto const& a : it->second)
            cv::line(ov, cv::Point(a.a.x(), a.a.y()), cv::Point(a.b.x(), a.b.y()), {0, 0, 255}, 1);
          for (auto const& m : ms)  // the mask shafts' scored sides, as dots
            for (int k = 0; k < 2; ++k)
              for (auto const& q : m.sides[k]) cv::circle(ov, cv::Point(q.x(), q.y()), 0, k ? cv::Scalar(255, 255, 0) : cv::Scalar(0, 255, 255), 1);
          fs::create_directories(overlay_dir);
          cv::imwrite((fs::path(overlay_dir) / ("robotic" + std::to_string(ds) + "_" + std::to_string(frame) + ".png")).string(), ov);
        }
      }
      ++frame;
    }
    std::printf("robotic dataset %d: %d annotated frames, %d annotated shafts, %d found (axis within 20 px) = %.1f %%, "
                "%.2f detections/frame, %.2f false/frame (axis within 20 px of no annotated one)\n", ds, frames_annot, n, found,
                100.0 * found / std::max(1, n), static_cast<double>(dets) / std::max(1, frames_annot),
                static_cast<double>(false_dets) / std::max(1, frames_annot));
    std::printf("  image axis vs annotation: mean point distance median %.2f px p90 %.2f px; angle median %.2f deg p90 %.2f deg\n",
                percentile(dist, 0.5), percentile(dist, 0.9), percentile(ang, 0.5), percentile(ang, 0.9));
    std::printf("  strict: annotated axes found (a detection's image axis within %.0f px of both annotated points) %d / %d = %.1f %%\n",
                kAxisFoundPx, axes_found40, n, 100.0 * axes_found40 / std::max(1, n));
    if (!mask_caps.empty()) printStrict("strict, mask shafts (components of >= 500 px)", strict, frames_annot, "frame");
    if (!mask_caps.empty() && net)
      std::printf("  the network covers %d of the %d mask shafts (half of their pixels at p >= 1/2), %d as shaft or jaws\n", covered,
                  strict.shafts, covered_instrument);
    double const found_frac = static_cast<double>(found) / std::max(1, n);
    double const false_rate = static_cast<double>(false_dets) / std::max(1, frames_annot);
    if (!withinBounds(found_frac, chk.min_found, false_rate, chk.max_false_per_frame)) {
      std::printf("  regression bounds (found >= %.2f, false/frame <= %.3f): VIOLATED\n", chk.min_found, chk.max_false_per_frame);
      ok = false;
    } else if (chk.min_found >= 0.0 || chk.max_false_per_frame >= 0.0) {
      std::printf("  regression bounds (found >= %.2f, false/frame <= %.3f): met\n", chk.min_found, chk.max_false_per_frame);
    }
    if (chk.min_strict_found >= 0.0 || chk.max_strict_false_per_frame >= 0.0) {
      double const strict_found = static_cast<double>(strict.found.back()) / std::max(1, strict.shafts);
      double const strict_false = static_cast<double>(strict.false_detections) / std::max(1, frames_annot);
      bool const met = !mask_caps.empty() && withinBounds(strict_found, chk.min_strict_found, strict_false, chk.max_strict_false_per_frame);
      std::printf("  strict regression bounds (mask shafts found >= %.2f, false/frame <= %.3f): %s\n", chk.min_strict_found,
                  chk.max_strict_false_per_frame, mask_caps.empty() ? "VIOLATED (no mask videos)" : met ? "met" : "VIOLATED");
      ok = ok && met;
    }
    if (oracle) continue;  // (no pipeline ran: no poses, no insertion points)
    std::printf("  insertion points (assumed fx = fy = 700 px), over frames 186..%d:%s\n", frame - 1,
                trocar_track.empty() ? " none discovered" : "");
    if (verbose && all_axes.size() >= 2) {
      auto const e = intersectAxesRobust(all_axes);
      Eigen::Vector3d const ip = K * e.position;
      std::printf("  (diagnostic: robust common point of all %zu reported axes: %s (%.0f, %.0f, %.0f) mm, %zu inliers, "
                  "rms %.1f mm, spread %.1f deg, image (%.0f, %.0f))\n", all_axes.size(), toString(e.status),
                  e.position.x() * 1e3, e.position.y() * 1e3, e.position.z() * 1e3, e.inliers.size(), e.rms_distance * 1e3,
                  std::asin(std::min(1.0, e.conditioning)) * 180 / M_PI, ip.x() / ip.z(), ip.y() / ip.z());
    }
    std::map<int, std::vector<double>> tool_image_deg;
    std::map<int, std::vector<ImageLine>> annotated_lines;
    for (auto const& a : list) {
      tool_image_deg[a.tool].push_back(std::atan2(a.b.y() - a.a.y(), a.b.x() - a.a.x()) * 180.0 / M_PI);
      if (auto const l = lineThrough(a.a, a.b)) annotated_lines[a.tool].push_back(*l);
    }
    // The image of each tool's trocar as the common point of its image axes (Eq. (5), least
    // squares: its LMedS form, on half of these near-parallel lines, wanders along them), from the
    // annotated axes and from the detected ones: the 2-D check, free of the intrinsics.
    auto common = [](std::vector<ImageLine> const& lines) -> std::string {
      if (lines.size() < 2) return "too few axes";
      ImagePointEstimate const e = intersectImageLines(lines, Eigen::Vector2d(359.5, 287.5), 461.0);
      if (!e.ok) return "no common point";
      if (e.atInfinity()) return "at infinity";
      char buf[96];
      std::snprintf(buf, sizeof buf, "(%.0f, %.0f) (rms %.0f px, %zu axes)", e.pixel().x(), e.pixel().y(), e.rms_px, lines.size());
      return buf;
    };
    for (auto const& [tool, lines] : annotated_lines)
      std::printf("  tool %d: annotated image axes meet at %s, the detected ones at %s (px)\n", tool, common(lines).c_str(),
                  tool_lines.count(tool) ? common(tool_lines[tool]).c_str() : "none");
    std::printf("  each tool's trocar from its own detections' axes (robust Eq. (3); assumed intrinsics as above, 8 mm shafts):\n");
    reportToolTrocars(tool_axes, tool_image_deg, K, cv::Size(720, 576));
    for (auto const& [id, v] : trocar_track) {
      if (v.size() < 10) continue;
      Eigen::Vector3d m = Eigen::Vector3d::Zero();
      for (auto const& q : v) m += q;
      m /= static_cast<double>(v.size());
      double sd = 0.0;
      for (auto const& q : v) sd += (q - m).squaredNorm();
      sd = std::sqrt(sd / v.size());
      Eigen::Vector3d const ip = trocar_image[id];
      std::string where = "at infinity";
      if (std::abs(ip.z()) > 1e-12) {
        Eigen::Vector2d const px = ip.head<2>() / ip.z();
        bool const inside = px.x() >= 0 && px.y() >= 0 && px.x() < 720 && px.y() < 576;
        char buf[96];
        std::snprintf(buf, sizeof buf, "image (%.0f, %.0f)%s", px.x(), px.y(), inside ? " INSIDE the image" : " outside the image");
        where = buf;
      }
      auto const last = out.insertion_points;
      double cond = 0.0;
      for (auto const& p : last)
        if (p.id == id) cond = p.estimate.conditioning;
      std::printf("    id %d: mean (%.0f, %.0f, %.0f) mm, RMS motion %.1f mm over %zu frames, spread %.1f deg, %s\n", id,
                  m.x() * 1e3, m.y() * 1e3, m.z() * 1e3, sd * 1e3, v.size(), std::asin(std::min(1.0, cond)) * 180 / M_PI,
                  where.c_str());
    }
  }
  return ok;
}

}  // namespace

int main(int argc, char** argv) {
  std::string data = "../shared/data", overlay, params_path;
  int min_area = 1500;
  InvivoChecks chk;
  bool invivo = true, robotic = true;
  RoboticChecks robotic_chk;
  std::vector<std::string> sites{"OP1", "OP2", "OP3"};
  std::string detector, model;
  for (int i = 1; i < argc; ++i) {
    std::string const a = argv[i];
    if (a == "--data" && i + 1 < argc) data = argv[++i];
    else if (a == "--overlay" && i + 1 < argc) overlay = argv[++i];
    else if (a == "--min-area" && i + 1 < argc) min_area = std::atoi(argv[++i]);
    else if (a == "--invivo-only") robotic = false;
    else if (a == "--verbose") verbose = true;
    else if (a == "--baseline") baseline = true;
    else if (a == "--annotated-mask") annotated_mask = true;
    else if (a == "--min-found" && i + 1 < argc) chk.min_found = std::atof(argv[++i]);
    else if (a == "--max-line-px" && i + 1 < argc) chk.max_line_px = std::atof(argv[++i]);
    else if (a == "--max-false-per-image" && i + 1 < argc) chk.max_false_per_image = std::atof(argv[++i]);
    else if (a == "--robotic-only") invivo = false;
    else if (a == "--params" && i + 1 < argc) params_path = argv[++i];
    else if (a == "--detector" && i + 1 < argc) detector = argv[++i];
    else if (a == "--model" && i + 1 < argc) model = argv[++i];
    else if (a == "--min-strict-found" && i + 1 < argc) chk.min_strict_found = std::atof(argv[++i]);
    else if (a == "--max-strict-false-per-image" && i + 1 < argc) chk.max_strict_false_per_image = std::atof(argv[++i]);
    else if (a == "--sites" && i + 1 < argc) {
      sites.clear();
      std::stringstream ss(argv[++i]);
      for (std::string t; std::getline(ss, t, ',');) sites.push_back(t);
    }
    else if (a == "--robotic-min-found" && i + 1 < argc) robotic_chk.min_found = std::atof(argv[++i]);
    else if (a == "--robotic-max-false-per-frame" && i + 1 < argc) robotic_chk.max_false_per_frame = std::atof(argv[++i]);
    else if (a == "--robotic-min-strict-found" && i + 1 < argc) robotic_chk.min_strict_found = std::atof(argv[++i]);
    else if (a == "--robotic-max-strict-false-per-frame" && i + 1 < argc) robotic_chk.max_strict_false_per_frame = std::atof(argv[++i]);
    else {
      std::fprintf(stderr, "usage: endo_guidance_eval_real [--data DIR] [--overlay DIR] [--min-area PX] [--invivo-only|--robotic-only] [--verbose]\n"
                           "       [--baseline]   (in-vivo stills only: the issue's Canny + Hough baseline instead of the segmentation)\n"
                           "       [--annotated-mask]   (the learned detector's line stage fed the annotated shaft and instrument\n"
                           "                             masks at the model's input size, its ceiling; the videos: each annotated frame alone)\n"
                           "       [--params PARAMS.yaml]   (config/pipeline.yaml or a subset: its segmentation group is used)\n"
                           "       [--detector colour|learned] [--model MODEL.yaml]   (override the parameters' segmentation/detector, learned_model)\n"
                           "       [--sites OP1,OP2,OP3]   (the in-vivo operations scored; default all three)\n"
                           "       [--min-strict-found F] [--max-strict-false-per-image F]   (in-vivo, strict scoring at 10 px; exit 1 if violated)\n"
                           "       [--robotic-min-found F] [--robotic-max-false-per-frame F]   (per robotic sequence; exit 1 if violated)\n"
                           "       [--robotic-min-strict-found F] [--robotic-max-strict-false-per-frame F]   (per robotic sequence, its mask\n"
                           "                             shafts, strict scoring at 10 px; exit 1 if violated)\n"
                           "       [--min-found F] [--max-line-px PX] [--max-false-per-image F]   (in-vivo regression bounds; exit 1 if violated)\n");
      return 2;
    }
  }
  if (!fs::exists(data)) {
    std::printf("SKIPPED: real data folder '%s' absent (it lives in ../shared/data beside the repository)\n", data.c_str());
    return kSkipped;
  }
  PipelineParams pp;
  if (!params_path.empty()) {
    try {
      io::loadPipelineYaml(params_path, pp);
    } catch (std::exception const& e) {
      std::fprintf(stderr, "endo_guidance_eval_real: %s\n", e.what());
      return 2;
    }
  }
  if (annotated_mask) detector = "learned";  // (its parameters; the model gives the input size)
  try {
    if (!detector.empty()) pp.segmentation.detector = io::detectorFromString(detector);
    if (!model.empty()) pp.segmentation.learned.model = model;
    InstrumentSegmenter check(pp.segmentation);  // a model that cannot be loaded: said once, here
  } catch (std::exception const& e) {
    std::fprintf(stderr, "endo_guidance_eval_real: %s\n", e.what());
    return 2;
  }
  std::printf("detector: %s%s%s\n", io::toString(pp.segmentation.detector),
              pp.segmentation.detector == SegmentationParams::Detector::kLearned ? ", model " : "",
              pp.segmentation.detector == SegmentationParams::Detector::kLearned
                  ? (pp.segmentation.learned.model.empty() ? defaultShaftModel() : pp.segmentation.learned.model).c_str()
                  : "");
  SegmentationParams const& sp = pp.segmentation;
  bool ok = true;
  if (baseline && robotic) {
    std::printf("--baseline: the in-vivo stills only (the baseline has no insertion points for the sequences)\n");
    robotic = false;
  }
  if (invivo) ok = evalInvivo(fs::path(data) / "endovis15_rigid_invivo", overlay, sp, min_area, chk, sites);
  if (robotic) ok = evalRobotic(fs::path(data) / "endovis15_robotic", overlay, sp, robotic_chk) && ok;
  return ok ? 0 : 1;
}
