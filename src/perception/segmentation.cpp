// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/perception/segmentation.h"

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <utility>
#include <vector>

#include "endo_guidance/perception/colour_shaft_detector.h"
#include "endo_guidance/perception/contour_checks.h"
#include "endo_guidance/perception/image_reduction.h"
#include "endo_guidance/perception/learned_shaft_detector.h"

namespace endo_guidance::perception {

namespace {
// What the stages index or divide by (the YAML loader refuses these with the key's name).
SegmentationParams const& checked(SegmentationParams const& p) {
  if (p.regions.thresholds.empty()) throw std::invalid_argument("segmentation: no growth thresholds");
  if (p.processing_width <= 0) throw std::invalid_argument("segmentation: processing_width must be positive");
  return p;
}
}  // namespace

std::unique_ptr<ShaftDetector> makeShaftDetector(SegmentationParams const& params) {
  if (params.detector == SegmentationParams::Detector::kLearned) return std::make_unique<LearnedShaftDetector>(params);
  return std::make_unique<ColourShaftDetector>(params);
}

InstrumentSegmenter::InstrumentSegmenter(SegmentationParams const& params)
    : params_(checked(params)), detector_(makeShaftDetector(params)) {}

InstrumentSegmenter::InstrumentSegmenter(SegmentationParams const& params, std::unique_ptr<ShaftDetector> detector)
    : params_(checked(params)), detector_(std::move(detector)) {
  if (!detector_) throw std::invalid_argument("InstrumentSegmenter: null shaft detector");
}

InstrumentSegmenter::InstrumentSegmenter(InstrumentSegmenter const& o)
    : params_(o.params_),
      detector_(o.detector_->clone()),
      fov_(o.fov_),
      fov_size_(o.fov_size_),
      fov_area_(o.fov_area_),
      frames_since_fov_(o.frames_since_fov_),
      tracked_(o.tracked_),
      tracked_size_(o.tracked_size_),
      scale_(o.scale_),
      since_detection_(o.since_detection_),
      small_(o.small_) {}

InstrumentSegmenter& InstrumentSegmenter::operator=(InstrumentSegmenter const& o) {
  if (this != &o) *this = InstrumentSegmenter(o);
  return *this;
}

InstrumentSegmenter::~InstrumentSegmenter() = default;

void InstrumentSegmenter::setParams(SegmentationParams const& p) {
  checked(p);
  if (p.detector != params_.detector) detector_ = makeShaftDetector(p);  // (throws before anything changed)
  else detector_->setParams(p);
  params_ = p;
  fov_size_ = cv::Size();  // re-detect
  tracked_.clear();
}

void InstrumentSegmenter::reset() {
  fov_size_ = cv::Size();
  detector_->reset();
  tracked_.clear();
  since_detection_ = 0;
}

std::optional<SegmentationResult> InstrumentSegmenter::track(cv::Mat const& bgr) {
  if (tracked_.empty() || bgr.size() != tracked_size_ || since_detection_ + 1 >= detectEvery()) return std::nullopt;
  std::vector<TrackedShaft> now;
  for (TrackedShaft const& t : tracked_) {
    TrackingResult r = trackContour(t, bgr, params_.contours, params_.tracking, &fov_, scale_);
    // Lost, no longer less chromatic than the tissue beside it, or now glare: this is a detection frame.
    if (!r.shaft) return std::nullopt;
    AcrossSamples const across = acrossContour(bgr, r.shaft->contour);
    if (!stripContrastFullRes(across, params_.strip) || mostlyGlare(across, params_.contours)) return std::nullopt;
    now.push_back(std::move(*r.shaft));
  }
  // Two tracks that converged on one shaft (its double detection: shaft and shadow, or two
  // seeds on its border run) -- a frame that needs the detection.
  for (std::size_t i = 0; i < now.size(); ++i)
    for (std::size_t j = i + 1; j < now.size(); ++j) {
      geometry::ImageLine const ai = geometry::imageAxis(now[i].contour);
      geometry::ApparentContour const& cj = now[j].contour;
      if (std::abs(ai.head<2>().dot(geometry::imageAxis(cj).head<2>())) > std::cos(2.0 * M_PI / 180.0) &&
          std::abs(ai.dot(cj.entry_px.homogeneous())) < 3.0 && std::abs(ai.dot(cj.tip_px.homogeneous())) < 3.0)
        return std::nullopt;
    }
  // The seeds' memory follows the shafts, so that the next detection frame finds each shaft's
  // seed where its memory is (and tries its growth level first).
  for (std::size_t i = 0; i < now.size(); ++i) {
    Eigen::Vector2d const shift = (now[i].contour.entry_px - tracked_[i].contour.entry_px) / scale_;
    detector_->shaftMoved(i, cv::Point(static_cast<int>(std::lround(shift.x())), static_cast<int>(std::lround(shift.y()))));
  }
  SegmentationResult res;
  res.scale = scale_;
  res.tracked = true;
  for (TrackedShaft const& t : now) {
    res.contours.push_back(t.contour);
    res.edges.push_back(t.edges);
  }
  tracked_ = std::move(now);
  ++since_detection_;
  return res;
}

SegmentationResult InstrumentSegmenter::process(cv::Mat const& bgr, std::vector<Eigen::Vector3d> const& trocars) {
  CV_Assert(bgr.type() == CV_8UC3 && !bgr.empty());
  if (auto t = track(bgr)) return std::move(*t);
  // The reduction factor for about processing_width columns, never more than the shorter side: a
  // frame wider than tall (say 1920x1) still reduces to at least one pixel each way.
  int const scale = std::clamp(static_cast<int>(std::lround(static_cast<double>(bgr.cols) / params_.processing_width)), 1,
                               std::min(bgr.rows, bgr.cols));
  reduceImage(bgr, scale, small_);  // (image_reduction.h)
  updateFieldOfView();
  SegmentationResult res = detector_->detect({bgr, small_, fov_, fov_area_, scale, trocars, since_detection_ + 1});
  startTracks(res, detector_->followable(), bgr.size());
  return res;
}

void InstrumentSegmenter::startTracks(SegmentationResult const& res, bool follow, cv::Size frame_size) {
  // The shafts found are followed in the next frames (contour_tracking.h).
  tracked_.clear();
  if (follow && detectEvery() > 1)
    for (std::size_t i = 0; i < res.contours.size(); ++i)
      tracked_.push_back(startTrack(res.contours[i], res.edges[i], i < res.tip_colours.size() ? res.tip_colours[i] : std::nullopt));
  tracked_size_ = frame_size;
  scale_ = res.scale;
  since_detection_ = 0;
}

void InstrumentSegmenter::updateFieldOfView() {
  if (small_.size() == fov_size_ && ++frames_since_fov_ < params_.fov_refresh) return;
  fov_ = detectFieldOfView(small_, params_.fov);
  fov_size_ = small_.size();
  fov_area_ = cv::countNonZero(fov_.mask);
  frames_since_fov_ = 0;
}


void drawSegmentationOverlay(cv::Mat& img, SegmentationResult const& r, std::vector<Eigen::Vector3d> const& trocars) {
  auto full = [&](cv::Point const& q) {  // (the block's centre, truncated to a pixel)
    Eigen::Vector2d const f = toFullRes(Eigen::Vector2d(q.x, q.y), r.scale);
    return cv::Point(static_cast<int>(f.x()), static_cast<int>(f.y()));
  };
  for (std::size_t i = 0; i < r.regions.size(); ++i) {
    bool const ok = r.region_status[i] == ContourRejection::kNone;
    std::vector<cv::Point> pts;
    for (auto const& q : r.regions[i].boundary) pts.push_back(full(q));
    cv::polylines(img, pts, true, ok ? cv::Scalar(255, 255, 0) : cv::Scalar(0, 0, 255), 1, cv::LINE_AA);
  }
  for (auto const& sd : r.seeds)
    cv::circle(img, full(sd.position), 4, {0, 255, 255}, 1, cv::LINE_AA);
  for (auto const& c : r.contours) {
    Eigen::Vector2d const e = c.entry_px, t = c.tip_px;
    for (int k = 0; k < 2; ++k) {
      // Draw each line between the feet of the entry and the tip.
      Eigen::Vector2d const a = geometry::footOnLine(c.lines[k], e);
      Eigen::Vector2d const b = geometry::footOnLine(c.lines[k], t);
      cv::line(img, {static_cast<int>(a.x()), static_cast<int>(a.y())}, {static_cast<int>(b.x()), static_cast<int>(b.y())},
               k == 0 ? cv::Scalar(0, 255, 0) : cv::Scalar(255, 0, 255), 2, cv::LINE_AA);
    }
    cv::circle(img, {static_cast<int>(t.x()), static_cast<int>(t.y())}, 6, {0, 255, 255}, 2, cv::LINE_AA);
    cv::line(img, {static_cast<int>(e.x()), static_cast<int>(e.y())}, {static_cast<int>(t.x()), static_cast<int>(t.y())},
             {255, 255, 255}, 1, cv::LINE_AA);
  }
  // Directions of the insertion points (their images usually lie outside the frame).
  cv::Point2f const c(img.cols / 2.f, img.rows / 2.f);
  for (std::size_t j = 0; j < trocars.size(); ++j) {
    Eigen::Vector2d d = std::abs(trocars[j].z()) > 1e-12 ? Eigen::Vector2d(trocars[j].head<2>() / trocars[j].z() - Eigen::Vector2d(c.x, c.y))
                                                        : Eigen::Vector2d(trocars[j].head<2>());
    if (d.norm() < 1e-9) continue;
    d.normalize();
    cv::Point2f const tip = c + cv::Point2f(static_cast<float>(d.x()), static_cast<float>(d.y())) * (0.45f * std::min(img.cols, img.rows));
    cv::arrowedLine(img, c, tip, {0, 128, 255}, 2, cv::LINE_AA, 0, 0.08);
    cv::putText(img, "trocar " + std::to_string(j), tip + cv::Point2f(4, 4), cv::FONT_HERSHEY_SIMPLEX, 0.5, {0, 128, 255}, 1,
                cv::LINE_AA);
  }
}

}  // namespace endo_guidance::perception
