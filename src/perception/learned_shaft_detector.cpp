// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/learned_shaft_detector.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <opencv2/dnn.hpp>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <utility>
#include <vector>

#include "endo_guidance/perception/contour_checks.h"
#include "endo_guidance/perception/contour_fit.h"
#include "endo_guidance/perception/mask_line_pairs.h"

namespace endo_guidance::perception {

namespace fs = std::filesystem;

std::string defaultShaftModel() { return std::string(ENDO_GUIDANCE_MODEL_DIR) + "/shaft_net.yaml"; }

struct ShaftNet::Impl {
  cv::dnn::Net net;
  cv::Mat resized, blob;
};

ShaftNet::ShaftNet(std::string const& yaml_path, int threads) : impl_(std::make_unique<Impl>()) {
  std::string const path = yaml_path.empty() ? defaultShaftModel() : yaml_path;
  auto fail = [&](std::string const& why) { throw std::runtime_error("shaft model '" + path + "': " + why); };
  if (!fs::is_regular_file(path)) fail("no such file");
  cv::FileStorage f;
  try {
    f.open(path, cv::FileStorage::READ);
  } catch (cv::Exception const& e) {
    fail(std::string("not a readable YAML file (") + e.what() + ")");
  }
  if (!f.isOpened()) fail("not a readable YAML file");
  std::string onnx = f["model"].empty() ? std::string() : static_cast<std::string>(f["model"]);
  int const w = f["width"].empty() ? 0 : static_cast<int>(f["width"]);
  int const h = f["height"].empty() ? 0 : static_cast<int>(f["height"]);
  if (onnx.empty()) fail("no 'model' (the ONNX file)");
  if (w < 8 || h < 8 || w > 4096 || h > 4096) fail("'width' and 'height' must be in [8, 4096]");
  size_ = cv::Size(w, h);
  mean_ = f["mean"].empty() ? 0.0 : static_cast<double>(f["mean"]);
  scale_ = f["scale"].empty() ? 1.0 : static_cast<double>(f["scale"]);
  if (!(scale_ > 0.0) || !std::isfinite(mean_)) fail("'scale' must be positive and 'mean' finite");
  for (auto const& c : f["classes"]) classes_.push_back(static_cast<std::string>(c));
  auto const it = std::find(classes_.begin(), classes_.end(), "shaft");
  if (it == classes_.end()) fail("'classes' has no 'shaft'");
  shaft_ = static_cast<int>(it - classes_.begin());
  auto const bg = std::find(classes_.begin(), classes_.end(), "background");
  background_ = bg == classes_.end() ? -1 : static_cast<int>(bg - classes_.begin());
  if (!f["side"].empty()) {
    side_ = static_cast<int>(f["side"]);
    if (side_ != static_cast<int>(classes_.size())) fail("'side' must be the channel after the classes'");
  }
  if (fs::path(onnx).is_relative()) onnx = (fs::path(path).parent_path() / onnx).string();
  if (!fs::is_regular_file(onnx)) fail("its ONNX file '" + onnx + "' is missing");
  try {
    impl_->net = cv::dnn::readNetFromONNX(onnx);
  } catch (cv::Exception const& e) {
    fail("OpenCV cannot load '" + onnx + "': " + e.what());
  }
  if (impl_->net.empty()) fail("OpenCV cannot load '" + onnx + "'");
  impl_->net.setPreferableBackend(cv::dnn::DNN_BACKEND_OPENCV);
  impl_->net.setPreferableTarget(cv::dnn::DNN_TARGET_CPU);
  if (threads < 1) fail("threads must be >= 1");
  cv::setNumThreads(threads);  // (OpenCV's DNN layers use the global thread pool)
  // One forward pass now: a model whose layers OpenCV cannot run fails here, with its shape checked.
  cv::Mat const out = logits(cv::Mat(size_, CV_8UC3, cv::Scalar::all(0)));
  int const outputs = static_cast<int>(classes_.size()) + (side_ >= 0 ? 1 : 0);
  if (out.dims != 4 || out.size[1] != outputs || out.size[2] != h || out.size[3] != w)
    fail("its output is not " + std::to_string(outputs) + " x height x width logits (the classes" +
         (side_ >= 0 ? ", then the side's)" : ")"));
}

ShaftNet::~ShaftNet() = default;

cv::Mat ShaftNet::logits(cv::Mat const& bgr) {
  CV_Assert(bgr.type() == CV_8UC3 && !bgr.empty());
  // Reduced as in training (area averaging), then (BGR - mean) * scale, channels in BGR order.
  cv::resize(bgr, impl_->resized, size_, 0, 0, bgr.cols > size_.width ? cv::INTER_AREA : cv::INTER_LINEAR);
  cv::dnn::blobFromImage(impl_->resized, impl_->blob, scale_, cv::Size(), cv::Scalar::all(mean_), false, false, CV_32F);
  impl_->net.setInput(impl_->blob);
  return impl_->net.forward();
}

ShaftProbabilities ShaftNet::probabilities(cv::Mat const& bgr) {
  cv::Mat const out = logits(bgr);
  int const n = size_.area(), k = static_cast<int>(classes_.size());
  auto const* l = out.ptr<float>();
  ShaftProbabilities r{cv::Mat(size_, CV_32F), cv::Mat(size_, CV_32F)};
  if (side_ >= 0) {  // sigmoid
    cv::Mat const logit(size_, CV_32F, const_cast<float*>(out.ptr<float>()) + side_ * n);
    cv::exp(-logit, r.side);
    r.side = 1.0 / (1.0 + r.side);
  }
  auto* ps = r.shaft.ptr<float>();
  auto* pi = r.instrument.ptr<float>();
  for (int i = 0; i < n; ++i) {  // softmax over the classes: the shaft's share, and all but the background's
    float m = l[i];
    for (int c = 1; c < k; ++c) m = std::max(m, l[c * n + i]);
    float s = 0.f;
    for (int c = 0; c < k; ++c) s += std::exp(l[c * n + i] - m);
    ps[i] = std::exp(l[shaft_ * n + i] - m) / s;
    pi[i] = background_ < 0 ? ps[i] : 1.f - std::exp(l[background_ * n + i] - m) / s;
  }
  return r;
}

namespace {
// One side pair's contour on the frame's edges beside the mask's sides (the contour fit searches
// a few px about them); kNone in its rejection when accepted. The edges are sought in the chroma
// first (edgeChannel(): shafts are greyer than tissue); a side without edges there is sought
// along its own colour direction (sideColourDirection(): the shaft's colour to the tissue's
// across the mask's side), as grey fat and membrane are as grey as a shaft. Edges whose line lies
// beyond three times the mask's outline error from the mask's side at either end are another
// edge's (a tissue fold, a jaw), not this side's. Where the frame has
// no edges either way on one side, that side is the mask's own line, its covariance as wide as the
// mask's outline error (kMaskOutlineSigmaPx), so that pose, trocar and servo weigh it so; with no
// edges on either side the pair is refused (the frame measures at least one side).
constexpr double kMaskOutlineSigmaPx = 4.0;  // full-res px: the network's outline to the annotated one, median 3-5 px (docs/accuracy.md)
ContourFit fitPair(SideFit sides, double width, Region const& region, DetectionFrame const& frame, ContourLinesParams const& p,
                   std::vector<geometry::ApparentContour> const& found) {
  sides.mask_gate_px = 3.0 * kMaskOutlineSigmaPx;
  ContourFit f = refineContour(sides, region, frame.fov, frame.bgr, frame.scale, p);
  if (f.rejection == ContourRejection::kWeakEdges) {
    // The samples: inside the shaft by under a third of its width, outside beyond the mask's error.
    double const inside = std::clamp(0.3 * width, 2.0, 6.0), outside = 5.0;
    for (int k = 0; k < 2; ++k) {
      Eigen::Vector2d const d(-sides.lines[k].y(), sides.lines[k].x());
      double t0 = std::numeric_limits<double>::infinity(), t1 = -t0;
      for (auto const& q : sides.points[k]) t0 = std::min(t0, d.dot(q)), t1 = std::max(t1, d.dot(q));
      sides.colour_direction[k] = sideColourDirection(frame.bgr, sides.lines[k], t0, t1, inside, outside);
    }
    // (and one side with no edge either way keeps the mask's side, worth what the mask's outline is)
    sides.mask_side_sigma_px = kMaskOutlineSigmaPx;
    f = refineContour(sides, region, frame.fov, frame.bgr, frame.scale, p);
  }
  if (f.contour && mostlyGlare(frame.bgr, *f.contour, p)) f.rejection = ContourRejection::kGlare;
  else if (f.contour && duplicatesAShaft(*f.contour, found)) f.rejection = ContourRejection::kDuplicate;
  if (f.rejection != ContourRejection::kNone) f.contour.reset();
  return f;
}

// The strip between the pair's sides (the middle 70 %) from the entry half a width on: its box in
// the processing-scale maps and its mask there (empty box: off the maps).
std::pair<cv::Rect, cv::Mat> entryStrip(MaskLinePair const& pair, cv::Size size) {
  Eigen::Vector2d const u = (pair.far - pair.entry).normalized(), v(-u.y(), u.x());
  double const len = std::min(std::max(0.5 * pair.width, 2.0), (pair.far - pair.entry).norm());
  double const half = std::max(0.35 * pair.width, 1.0);
  std::vector<cv::Point> quad;
  for (auto const& [t, a] : {std::pair{0.0, -half}, {len, -half}, {len, half}, {0.0, half}}) {
    Eigen::Vector2d const q = pair.entry + t * u + a * v;
    quad.emplace_back(static_cast<int>(std::lround(q.x())), static_cast<int>(std::lround(q.y())));
  }
  cv::Rect const roi = cv::boundingRect(quad) & cv::Rect(cv::Point(0, 0), size);
  cv::Mat strip = cv::Mat::zeros(roi.size(), CV_8U);
  if (roi.empty()) return {roi, strip};
  for (cv::Point& q : quad) q -= roi.tl();
  cv::fillConvexPoly(strip, quad, cv::Scalar(255));
  return {roi, strip};
}

// Whether a pair of the instrument's mask is a shaft the shaft class's pairs did not give (kNone):
// where it enters, the shaft class must hold at least half of the instrument's probability (else
// it is a tool's head: kNotShaftAtEntry), and no accepted shaft's region may cover half of it
// (else it is that shaft again, its lines drawn on toward the head: kDuplicate).
ContourRejection newShaftAtEntry(MaskLinePair const& pair, ShaftProbabilities const& p, cv::Mat const& labels) {
  auto const [roi, strip] = entryStrip(pair, p.shaft.size());
  if (roi.empty()) return ContourRejection::kNotShaftAtEntry;
  double const instrument = cv::mean(p.instrument(roi), strip)[0];
  if (!(instrument > 0.0) || cv::mean(p.shaft(roi), strip)[0] < 0.5 * instrument) return ContourRejection::kNotShaftAtEntry;
  return cv::countNonZero(labels(roi) & strip) * 2 < cv::countNonZero(strip) ? ContourRejection::kNone : ContourRejection::kDuplicate;
}

// The network for p: `current` when it is still the one p asks for.
std::shared_ptr<ShaftNet> networkFor(SegmentationParams const& p, SegmentationParams const& old, std::shared_ptr<ShaftNet> current) {
  if (current && p.learned.model == old.learned.model && p.learned.threads == old.learned.threads) return current;
  return std::make_shared<ShaftNet>(p.learned.model, p.learned.threads);
}
}  // namespace

LearnedShaftDetector::LearnedShaftDetector(SegmentationParams const& params)
    : params_(params), net_(networkFor(params, params, nullptr)) {}

void LearnedShaftDetector::setParams(SegmentationParams const& p) {
  net_ = networkFor(p, params_, net_);  // (throws before anything changed)
  params_ = p;
}

SegmentationResult shaftsOfProbability(DetectionFrame const& frame, ShaftProbabilities const& probability,
                                       SegmentationParams const& params, cv::Mat& labels) {
  CV_Assert(probability.shaft.type() == CV_32F && probability.shaft.size() == frame.fov.mask.size() &&
            probability.instrument.type() == CV_32F && probability.instrument.size() == frame.fov.mask.size() &&
            (probability.side.empty() || (probability.side.type() == CV_32F && probability.side.size() == frame.fov.mask.size())));
  SegmentationResult res;
  res.scale = frame.scale;
  labels = cv::Mat::zeros(frame.fov.mask.size(), CV_8U);
  // Every pair's region (its tip and fill) is the instrument's: the tip is the jaws' end.
  cv::Mat mask;
  cv::compare(probability.instrument, 0.5, mask, cv::CMP_GE);
  // The shaft class's pairs first, then the instrument's that enter as shaft and are new.
  for (bool const instrument : {false, true}) {
    if (static_cast<int>(res.contours.size()) >= params.regions.max_regions) break;
    cv::Mat const& p = instrument ? probability.instrument : probability.shaft;
    // (the shaft class's outline where its own jaws go on beyond it is no side)
    cv::Mat const beyond = instrument ? cv::Mat() : probability.instrument;
    for (MaskLinePair const& pair : findMaskLinePairs(p, frame.fov, frame.scale, params.contours, beyond, probability.side)) {
      if (static_cast<int>(res.contours.size()) >= params.regions.max_regions) break;
      auto region = regionOf(pair, mask);
      if (!region) continue;
      res.regions.push_back(std::move(*region));
      if (ContourRejection const r = instrument ? newShaftAtEntry(pair, probability, labels) : ContourRejection::kNone;
          r != ContourRejection::kNone) {
        res.region_status.push_back(r);
        continue;
      }
      ContourFit const f = fitPair(sideFitOf(pair, frame.scale), pair.width * frame.scale, res.regions.back(), frame,
                                   params.contours, res.contours);
      res.region_status.push_back(f.rejection);
      if (!f.contour) continue;
      res.contours.push_back(onImageAxis(*f.contour));  // (reported on the image axis, as the colour method's)
      res.edges.push_back(f.edges);
      res.contour_regions.push_back(res.regions.size() - 1);
      cv::drawContours(labels, std::vector<std::vector<cv::Point>>{res.regions.back().boundary}, 0,
                       cv::Scalar(static_cast<int>(res.contours.size())), cv::FILLED);
    }
  }
  std::vector<std::size_t> none;
  removeDuplicateShafts(res, none);
  locateTips(res, frame, &probability.instrument);
  return res;
}

SegmentationResult LearnedShaftDetector::detect(DetectionFrame const& frame) {
  ShaftProbabilities const net = net_->probabilities(frame.bgr);
  ShaftProbabilities p;  // at the processing scale
  cv::resize(net.shaft, p.shaft, frame.fov.mask.size(), 0, 0, cv::INTER_LINEAR);
  cv::resize(net.instrument, p.instrument, frame.fov.mask.size(), 0, 0, cv::INTER_LINEAR);
  if (!net.side.empty()) cv::resize(net.side, p.side, frame.fov.mask.size(), 0, 0, cv::INTER_LINEAR);
  SegmentationResult res = shaftsOfProbability(frame, p, params_, labels_);
  p.shaft.convertTo(feature_, CV_8U, -255.0, 255.0);  // low on shafts, as the colour feature
  return res;
}

}  // namespace endo_guidance::perception
