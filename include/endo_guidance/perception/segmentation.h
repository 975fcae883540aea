// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>
#include <deque>
#include <memory>
#include <optional>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"
#include "endo_guidance/perception/colour_feature.h"
#include "endo_guidance/perception/contour_fit.h"
#include "endo_guidance/perception/contour_tracking.h"
#include "endo_guidance/perception/field_of_view.h"
#include "endo_guidance/perception/learned_shaft_detector.h"
#include "endo_guidance/perception/region_growing.h"
#include "endo_guidance/perception/seed_search.h"
#include "endo_guidance/perception/strip_search.h"

namespace endo_guidance::perception {

/// All knobs of the segmentation (config/pipeline.yaml mirrors these defaults).
struct SegmentationParams {
  int processing_width = 320;     ///< the region stages run on the image reduced by an integer factor to about this width
  int sigma_radius = 1;           ///< Sigma filter window radius (processing px)
  int sigma_delta = 10;           ///< Sigma filter range (feature units)
  int fov_refresh = 25;           ///< frames between field-of-view detections (it rarely changes)
  int level_memory_px = 8;        ///< processing px: a seed this close to last frame's entry reuses its level
  int full_search_every = 5;      ///< frames: a rejected seed is searched in full again this often, but
  int strip_search_max_every = 30; ///< its strip search (the costliest step) less and less often: the
                                   ///< interval doubles, up to this, while the strip search keeps failing
  /// ... and its full search too: the interval doubles per full search that gives no shaft, up to
  /// this. Between full searches its region, grown again at its level, must stay within
  /// refused_area_change of its area at the last one and its run keep its width, else it is
  /// searched in full at once (something entered or left).
  int full_search_max_every = 20;
  double refused_area_change = 0.3;  ///< fraction of the larger area (see full_search_max_every)
  /// Sides sought again (the first pair had no edges, or from a region another seed grew) must
  /// enter the view at least this steeply: the sine of the angle between the axis and the border
  /// (ContourLinesParams::min_entry_sine, stricter for these, which are more often tissue).
  double resought_min_entry_sine = 0.3;
  /// ... and end inside the view, the tip at least this far (processing px) from its edge: a band
  /// across a corner of the view has both ends on the border.
  double resought_min_tip_depth_px = 6.0;
  /// ... and widen toward the tip at most this much (ContourLinesParams::max_widening for the
  /// others): a re-sought side can be a neighbour's edge.
  double resought_max_widening = 1.5;
  /// Seeds also on the edge of an accepted shaft that a refused region touches: a shaft crossing
  /// (or touching) it is cut by its strip, and the part beyond does not reach the field-of-view
  /// border (the part that does may be merged with a blob, or too short). Searched as the
  /// border is, in the field of view less that shaft; pairs checked as re-sought ones.
  bool crossing_seeds = true;
  /// What proposes the shaft candidates that the contour fit turns into lines: the colour method
  /// ([Doignon07] Sec. 3: seeds on the view's border, region growing, strip search) or the
  /// learned shaft mask (learned_shaft_detector.h). docs/accuracy.md compares them.
  enum class Detector { kColour, kLearned };
  Detector detector = Detector::kColour;
  LearnedDetectorParams learned;
  ColourFeatureParams feature;
  FieldOfViewParams fov;
  SeedSearchParams seeds;
  RegionGrowingParams regions;
  ContourLinesParams contours;
  StripSearchParams strip;
  ContourTrackingParams tracking;
};

/// What one frame gave, with the intermediate results for overlays and diagnostics.
struct SegmentationResult {
  std::vector<geometry::ApparentContour> contours;  ///< accepted shafts (full-resolution pixels)
  /// Per contour: the sub-pixel edge points behind each of its lines (lens-distortion correction).
  std::vector<std::array<std::vector<Eigen::Vector2d>, 2>> edges;
  std::vector<Seed> seeds;                ///< processing-scale pixels
  std::vector<Region> regions;            ///< processing-scale pixels
  std::vector<ContourRejection> region_status;  ///< per region: kNone = accepted
  int scale = 1;                          ///< processing -> full resolution factor
  /// The shafts were followed from the last frame's lines (contour_tracking.h), without the
  /// detection: seeds and regions are empty then.
  bool tracked = false;
  /// Strip searches run this frame (the costliest step: about as much as the rest of a frame).
  int strip_searches = 0;
  /// Seeds searched in full this frame (grown at every level; a refused seed's search is due
  /// every full_search_every frames, backing off to full_search_max_every).
  int full_searches = 0;
};

/// Instrument segmentation, [Doignon07] Sec. 3: S.H colour feature -> Sigma filter -> seeds along
/// the field-of-view border -> region growing -> two-class boundary split -> LMedS line pair ->
/// sub-pixel lines on the full-resolution image. In a video, each seed's growth level is
/// remembered; with tracking.detect_every > 1 (opt-in), the shafts found are followed by contour
/// tracking between detection frames (a lost one makes the frame a detection frame). Not thread-safe (one instance per
/// stream); call reset() between unrelated images.
class InstrumentSegmenter {
 public:
  /// With the learned detector, its model is loaded here: std::runtime_error if it cannot be.
  explicit InstrumentSegmenter(SegmentationParams const& params = {});
  /// Segments one BGR frame. `trocar_images`: homogeneous images of the known insertion points
  /// in full-resolution pixels ([Doignon07] Sec. 4), focusing the seed search; may be empty.
  SegmentationResult process(cv::Mat const& bgr, std::vector<Eigen::Vector3d> const& trocar_images = {});
  /// (Loads the learned detector's model when it is selected and its path or threads changed:
  /// std::runtime_error if it cannot be, the old parameters kept.)
  void setParams(SegmentationParams const& p);
  /// Forgets the previous frames (tracked shafts, seed memory, field of view).
  void reset();
  SegmentationParams const& params() const { return params_; }
  FieldOfView const& fieldOfView() const { return fov_; }
  /// Intermediate images of the last frame (processing scale), for debugging and overlays.
  cv::Mat const& feature() const { return filtered_; }
  cv::Mat const& labels() const { return labels_; }

 private:
  SegmentationParams params_;
  ColourFeature colour_;
  FieldOfView fov_;
  cv::Size fov_size_;
  double fov_area_ = 0.0;
  int frames_since_fov_ = 0;
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
  Memory const* remembered(Seed const& seed) const;
  static int entryDistance(cv::Point a, cv::Point b);
  static bool runChanged(Memory const& m, int width);
  bool fullSearchDue(Memory const& m, int width, int elapsed) const;  // width: of the seed's run now
  bool stripSearchDue(Memory const* m, int width, int elapsed) const;  // width: of the seed's run now
  void addCrossingSeeds(SegmentationResult& res, std::vector<std::vector<cv::Point>> const& strips,
                        std::vector<int> const& strip_labels, std::deque<FieldOfView>& views, std::vector<int>& view_shafts,
                        std::vector<int>& seed_view) const;
  std::optional<SegmentationResult> track(cv::Mat const& bgr);  // nullopt: detect
  void updateFieldOfView();  // on small_, every fov_refresh frames or when its size changes
  struct FrameSearch;  // one detection frame of the colour method, over its seeds (segmentation.cpp)
  struct SeedSearch;   // ... and one seed's search
  // One detection frame (small_ and fov_ set): the colour method's, or the learned detector's.
  SegmentationResult detectColour(cv::Mat const& bgr, std::vector<Eigen::Vector3d> const& trocars, int scale);
  SegmentationResult detectLearned(cv::Mat const& bgr, int scale);
  // Follows res's shafts in the next frames when `follow` (contour tracking on); memory: per shaft, its seed's entry.
  void startTracks(SegmentationResult const& res, bool follow, cv::Mat const& bgr, std::vector<std::size_t> const& memory);
  std::shared_ptr<ShaftNet> net_;  // the learned detector's network (Detector::kLearned)
  RegionGrower grower_;
  std::vector<Memory> memory_;
  std::vector<TrackedShaft> tracked_;  // the shafts of the last frame, to follow
  std::vector<std::size_t> tracked_memory_;  // per tracked shaft: its seed's entry in memory_
  cv::Size tracked_size_;
  int scale_ = 1;
  int since_detection_ = 0;  // tracking frames since the last detection frame
  cv::Mat small_, raw_, filtered_, labels_, gx_, gy_;
  RayField rays_;  // gx_, gy_ and the field of view packed for the strip search (packRayField())
};

/// Whether contour c is a second detection of one of the shafts already found: its entry and tip
/// (on its axis) within half that shaft's width (at its entry) of that shaft's axis, so that it
/// lies inside that shaft's image or its extension, and its axis within kDuplicateMaxAngleDeg
/// of that one. Two instruments side by side have axes a width apart; one crossing another
/// leaves the other's strip. The angle allows for a short stub of the same shaft merged with a
/// blob, a few degrees off.
inline constexpr double kDuplicateMaxAngleDeg = 15.0;
bool duplicatesAShaft(geometry::ApparentContour const& c, std::vector<geometry::ApparentContour> const& found);

/// The shafts of `found` that are second detections (duplicatesAShaft()) of a wider one in it,
/// whichever was found first, ascending: one shaft seen as a whole and again as the strip
/// between one edge and its printed label or highlight. Widths are compared at the middle of
/// the narrower's axis. The wider is kept: a strip inside a shaft's image is not a second
/// instrument (two instruments cannot overlap by half a width and stay parallel).
std::vector<std::size_t> narrowerDuplicates(std::vector<geometry::ApparentContour> const& found);

/// Two instruments' images overlap little: crossing shafts share a parallelogram about a width
/// square, touching ones an edge. Two contours whose quadrilaterals (between their lines, from
/// the feet of the entry to those of the tip) overlap by more than this fraction of their union
/// (intersection over union, as in a detector's non-maximum suppression) are one shaft seen
/// twice, or a shaft and a wedge between one of its edges and a tissue edge. A 30 px shaft
/// crossing an 80 px one at 30 deg, over half of it on the other, overlaps by 0.17.
inline constexpr double kMaxShaftOverlap = 1.0 / 3.0;
/// The contours of `found` that overlap (kMaxShaftOverlap) one with a smaller RMS line residual
/// (ApparentContour::residual_px; at equal residuals the earlier one is kept), ascending: the
/// contours are kept in order of residual, each unless it overlaps one kept before it: a wedge's
/// tissue line fits its edge points worse than a shaft's edge does.
std::vector<std::size_t> overlappingDuplicates(std::vector<geometry::ApparentContour> const& found);

/// Draws contours, axes, tips, entries and the directions of the insertion points on a BGR image
/// (seed Fig. 1, 2, 6).
void drawSegmentationOverlay(cv::Mat& bgr, SegmentationResult const& result,
                             std::vector<Eigen::Vector3d> const& trocar_images = {});

}  // namespace endo_guidance::perception
