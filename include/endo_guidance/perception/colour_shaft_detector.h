// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <deque>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "endo_guidance/perception/colour_feature.h"
#include "endo_guidance/perception/region_growing.h"
#include "endo_guidance/perception/shaft_detector.h"
#include "endo_guidance/perception/strip_search.h"

namespace endo_guidance::perception {

/// The colour method's shaft detector, [Doignon07] Sec. 3: S.H colour feature -> Sigma filter ->
/// seeds along the field-of-view border -> region growing at threshold levels -> the boundary's
/// two-class split into a side pair -> the contour fit; the strip search where every region
/// leaked. In a video each seed's growth level is remembered (and a refused seed's searches back
/// off), so that a frame mostly re-grows last frame's regions.
class ColourShaftDetector final : public ShaftDetector {
 public:
  explicit ColourShaftDetector(SegmentationParams const& params);
  std::unique_ptr<ShaftDetector> clone() const override { return std::make_unique<ColourShaftDetector>(*this); }
  SegmentationResult detect(DetectionFrame const& frame) override;
  bool followable() const override { return confirmed_; }
  void shaftMoved(std::size_t i, cv::Point shift) override;
  void setParams(SegmentationParams const& p) override;
  void reset() override;
  cv::Mat const& feature() const override { return filtered_; }
  cv::Mat const& labels() const override { return labels_; }

 private:
  struct Memory {           // what a seed near `entry` gave in the last frame
    cv::Point entry;        // processing px
    int level = 0;          // threshold level of the accepted (or smallest rejected) region
    double score = 0.0;     // its side-pair score
    bool accepted = false;
    ContourRejection why = ContourRejection::kNone;
    int age = 0;            // frames since its last full search
    int strip_age = 0;      // frames since its last strip search
    int strip_fails = 0;    // consecutive strip searches that gave no shaft
    int width = 0;          // border points of its run
    std::optional<StripCandidate> strip;  // the strip it was found as (strip search), if so
    bool grown = true;      // a region was kept (false: every level leaked)
    bool parallel = false;  // accepted with a side parallel to the other (SideFit::parallel: merged with a blob)
    int threshold = 0;      // the growth threshold of `level` (an absolute level added above the lowered ones is found again by it)
    bool carried = false;   // kept from an earlier frame: no seed was near it in the last one
    int fails = 0;          // consecutive full searches that gave no shaft
    int area = 0;           // of the region kept at its last full search (processing px)
  };
  struct FrameSearch;  // one detection frame, over its seeds (colour_shaft_detector.cpp)
  struct SeedSearch;   // ... and one seed's search
  Memory const* remembered(Seed const& seed) const;
  static int entryDistance(cv::Point a, cv::Point b);
  static bool runChanged(Memory const& m, int width);
  bool fullSearchDue(Memory const& m, int width, int elapsed) const;  // width: of the seed's run now
  bool stripSearchDue(Memory const* m, int width, int elapsed) const;  // width: of the seed's run now
  void addCrossingSeeds(FrameSearch& F) const;

  SegmentationParams params_;
  ColourFeature colour_;
  RegionGrower grower_;
  std::vector<Memory> memory_;
  std::vector<std::size_t> contour_memory_;  // per shaft of the last detect(): its seed's entry in memory_
  bool confirmed_ = false;  // every shaft of the last detect() was also found at the one before
  cv::Mat raw_, filtered_, labels_, gx_, gy_;
  RayField rays_;  // gx_, gy_ and the field of view packed for the strip search (packRayField())
};

}  // namespace endo_guidance::perception
