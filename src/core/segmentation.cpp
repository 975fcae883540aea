// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/core/segmentation.h"

#include <opencv2/imgproc.hpp>

#include "endo_guidance/core/sigma_filter.h"

namespace endo_guidance {

InstrumentSegmenter::InstrumentSegmenter(SegmentationParams const& params) : params_(params), colour_(params.feature) {}

void InstrumentSegmenter::setParams(SegmentationParams const& p) {
  bool const new_colour = p.feature.hue_origin_deg != params_.feature.hue_origin_deg || p.feature.gain != params_.feature.gain;
  params_ = p;
  if (new_colour) colour_ = ColourFeature(p.feature);
  fov_size_ = cv::Size();  // re-detect
}

SegmentationResult InstrumentSegmenter::process(cv::Mat const& bgr, std::vector<Eigen::Vector3d> const& trocars) {
  CV_Assert(bgr.type() == CV_8UC3 && !bgr.empty());
  SegmentationResult res;
  int const scale = std::max(1, static_cast<int>(std::lround(static_cast<double>(bgr.cols) / params_.processing_width)));
  res.scale = scale;
  if (scale > 1) cv::resize(bgr, small_, cv::Size(bgr.cols / scale, bgr.rows / scale), 0, 0, cv::INTER_AREA);
  else small_ = bgr;
  if (small_.size() != fov_size_ || ++frames_since_fov_ >= params_.fov_refresh) {
    fov_ = detectFieldOfView(small_, params_.fov);
    fov_size_ = small_.size();
    frames_since_fov_ = 0;
  }
  colour_.compute(small_, raw_);
  sigmaFilter(raw_, filtered_, params_.sigma_radius, params_.sigma_delta);
  // Trocar images in processing pixels: x_small = (x_full - (s - 1)/2) / s.
  std::vector<Eigen::Vector3d> t_small;
  double const off = 0.5 * (scale - 1);
  for (auto const& t : trocars) t_small.emplace_back((t.x() - off * t.z()) / scale, (t.y() - off * t.z()) / scale, t.z());
  res.seeds = findSeeds(filtered_, fov_, params_.seeds, t_small);
  std::vector<std::pair<cv::Point, int>> levels_now;
  grower_.reset(filtered_, fov_);
  double const max_area = params_.regions.max_area_fraction * cv::countNonZero(fov_.mask);
  for (int si = 0; si < static_cast<int>(res.seeds.size()); ++si) {
    if (static_cast<int>(res.contours.size()) >= params_.regions.max_regions) break;
    Seed const& seed = res.seeds[si];
    if (grower_.claimed(seed.position)) continue;
    // Grow at each threshold level; score each level's straight-line pair cheaply and refine the
    // best ones in full until one is accepted. In a video the level that worked for a shaft
    // entering here in the last frame is tried first, with its neighbours only.
    auto const& T = params_.regions.thresholds;
    std::vector<int> levels;
    int const remembered = rememberedLevel(seed.position);
    if (remembered >= 0) {
      for (int d : {0, -1, 1})
        if (remembered + d >= 0 && remembered + d < static_cast<int>(T.size())) levels.push_back(remembered + d);
    } else {
      for (int i = 0; i < static_cast<int>(T.size()); ++i) levels.push_back(i);
      }
    struct Candidate {
      Region region;
      SideFit sides;
      double score;
      int level;
    };
    std::vector<Candidate> cands;
    std::optional<Region> smallest;
    ContourRejection why = ContourRejection::kTooFewPoints;
    for (int li : levels) {
      auto r = grower_.grow(seed.position, T[li], si);
      if (!r) continue;
      if (r->area > max_area) {
        if (remembered < 0) break;  // leaked into tissue: higher thresholds only leak more
        continue;
      }
      if (!smallest || r->area < smallest->area) smallest = r;
      if (r->area < params_.regions.min_area) continue;
      SideFit sf = fitSides(*r, fov_, scale, params_.contours);
      double const score = scoreSides(sf, bgr, params_.contours);
      if (score < 0.0) {
        why = sf.rejection != ContourRejection::kNone ? sf.rejection : ContourRejection::kWeakEdges;
        continue;
      }
      cands.push_back({std::move(*r), std::move(sf), score, li});
    }
    std::sort(cands.begin(), cands.end(), [](Candidate const& a, Candidate const& b) { return a.score > b.score; });
    std::optional<Region> best;
    ContourFit best_fit;
    int best_level = -1;
    for (auto& cd : cands) {
      ContourFit f = refineContour(cd.sides, cd.region, fov_, bgr, scale, params_.contours);
      if (f.contour) {
        best = std::move(cd.region);
        best_fit = std::move(f);
        best_level = cd.level;
        break;
      }
      why = f.rejection;
    }
    if (best) levels_now.emplace_back(seed.position, best_level);
    Region const* keep = best ? &*best : (smallest ? &*smallest : nullptr);
    if (!keep) continue;
    res.regions.push_back(*keep);
    res.region_status.push_back(best ? ContourRejection::kNone : why);
    // Claimed either way, so the other seeds of this blob are skipped; an accepted shaft claims
    // only its strip (widened by 2 px), so a touching instrument's seed still grows.
    std::vector<cv::Point> strip;
    if (best) {
      ApparentContour const& c = *best_fit.contour;
      double const off = 0.5 * (scale - 1);
      Eigen::Vector2d const ax = (c.tip_px - c.entry_px).normalized();
      for (Eigen::Vector2d const& e : {Eigen::Vector2d(c.entry_px - 2.0 * scale * ax), Eigen::Vector2d(c.tip_px + 2.0 * scale * ax)})
        for (int k = 0; k < 2; ++k) {
          Eigen::Vector2d const n = c.lines[k].head<2>();
          Eigen::Vector2d const f = e - n * (c.lines[k].dot(Eigen::Vector3d(e.x(), e.y(), 1.0)) + 2.0 * scale);
          strip.emplace_back(static_cast<int>(std::lround((f.x() - off) / scale)), static_cast<int>(std::lround((f.y() - off) / scale)));
        }
      std::swap(strip[2], strip[3]);
    }
    grower_.claim(*keep, best ? static_cast<int>(res.regions.size()) : 255, strip);
    if (best) {
      ApparentContour c = *best_fit.contour;
      c.insertion_point_id = seed.insertion_point;
      res.contours.push_back(c);
    }
  }
  labels_ = grower_.labels();
  last_levels_ = std::move(levels_now);
  return res;
}

int InstrumentSegmenter::rememberedLevel(cv::Point const& seed) const {
  for (auto const& [p, level] : last_levels_)
    if (std::abs(p.x - seed.x) + std::abs(p.y - seed.y) <= params_.level_memory_px) return level;
  return -1;
}

void drawSegmentationOverlay(cv::Mat& img, SegmentationResult const& r, std::vector<Eigen::Vector3d> const& trocars) {
  double const s = r.scale, off = 0.5 * (s - 1);
  for (std::size_t i = 0; i < r.regions.size(); ++i) {
    bool const ok = r.region_status[i] == ContourRejection::kNone;
    std::vector<cv::Point> pts;
    for (auto const& q : r.regions[i].boundary) pts.emplace_back(static_cast<int>(q.x * s + off), static_cast<int>(q.y * s + off));
    cv::polylines(img, pts, true, ok ? cv::Scalar(255, 255, 0) : cv::Scalar(0, 0, 255), 1, cv::LINE_AA);
  }
  for (auto const& sd : r.seeds)
    cv::circle(img, cv::Point(static_cast<int>(sd.position.x * s + off), static_cast<int>(sd.position.y * s + off)), 4,
               {0, 255, 255}, 1, cv::LINE_AA);
  for (auto const& c : r.contours) {
    Eigen::Vector2d const e = c.entry_px, t = c.tip_px;
    for (int k = 0; k < 2; ++k) {
      // Draw each line between the feet of the entry and the tip.
      Eigen::Vector2d const n = c.lines[k].head<2>();
      Eigen::Vector2d const a = e - n * c.lines[k].dot(Eigen::Vector3d(e.x(), e.y(), 1));
      Eigen::Vector2d const b = t - n * c.lines[k].dot(Eigen::Vector3d(t.x(), t.y(), 1));
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

}  // namespace endo_guidance
