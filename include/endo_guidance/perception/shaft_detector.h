// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <array>
#include <cstddef>
#include <memory>
#include <optional>
#include <opencv2/core.hpp>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"
#include "endo_guidance/perception/contour_checks.h"
#include "endo_guidance/perception/field_of_view.h"
#include "endo_guidance/perception/region_growing.h"
#include "endo_guidance/perception/seed_search.h"
#include "endo_guidance/perception/segmentation_params.h"
#include "endo_guidance/perception/tip_location.h"

// The shaft-detector seam (docs/architecture.md): a detector proposes shaft candidates (a region
// or a strip entering the view, with its side pair: SideFit); the one contour fit
// (refineContour(), contour_fit.h) turns each into two sub-pixel lines with their covariance and
// runs the shape checks; the detector adds the checks of its own evidence and keeps one shaft
// per instrument (removeDuplicateShafts()). The colour method (colour_shaft_detector.h) and the
// learned mask (learned_shaft_detector.h) are its implementations.

namespace endo_guidance::perception {

/// What one frame gave, with the intermediate results for overlays and diagnostics.
struct SegmentationResult {
  std::vector<geometry::ApparentContour> contours;  ///< accepted shafts (full-resolution pixels)
  /// Per contour: the sub-pixel edge points behind each of its lines (lens-distortion correction).
  std::vector<std::array<std::vector<Eigen::Vector2d>, 2>> edges;
  std::vector<Seed> seeds;                ///< processing-scale pixels
  std::vector<Region> regions;            ///< processing-scale pixels
  std::vector<ContourRejection> region_status;  ///< per region: kNone = accepted
  std::vector<std::size_t> contour_regions;     ///< per contour: its region in `regions` (empty when tracked)
  /// Per contour (after locateTips()): the colours its tip was located with, which the tracked
  /// frames locate it with (nullopt: not located on the frame).
  std::vector<std::optional<TipColours>> tip_colours;
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

/// One detection frame as every detector sees it (InstrumentSegmenter prepares it).
struct DetectionFrame {
  cv::Mat const& bgr;    ///< full resolution, CV_8UC3
  cv::Mat const& small;  ///< reduced by `scale` (reduceImage())
  FieldOfView const& fov;  ///< of `small`
  double fov_area = 0.0;   ///< its pixels
  int scale = 1;
  std::vector<Eigen::Vector3d> const& trocar_images;  ///< homogeneous, full-resolution px; may be empty
  int elapsed = 1;  ///< frames since the last detection frame (1 without contour tracking)
};

/// What proposes shaft candidates and fits them (see the seam above). One instance per stream.
class ShaftDetector {
 public:
  virtual ~ShaftDetector() = default;
  /// A copy with this one's memory of earlier frames (a stream's state carried over).
  virtual std::unique_ptr<ShaftDetector> clone() const = 0;
  /// The frame's accepted shafts (contours, their edge points, regions and their status).
  virtual SegmentationResult detect(DetectionFrame const& frame) = 0;
  /// Whether the shafts of the last detect() may be followed by contour tracking.
  virtual bool followable() const = 0;
  /// Its own cadence (ContourTrackingParams::detect_every 0): a full detection this often, the
  /// shafts followed between. 1: every frame.
  virtual int detectEvery() const { return 1; }
  /// Contour tracking moved shaft `i` of the last detect() by `shift` (processing px) since the
  /// frame before: a detector with a memory of where shafts were moves it along.
  virtual void shaftMoved(std::size_t i, cv::Point shift) {}
  /// New parameters, of this detector's kind: std::runtime_error if they cannot be taken, and
  /// then the old ones are kept. Forgets earlier frames.
  virtual void setParams(SegmentationParams const& p) = 0;
  /// Forgets earlier frames.
  virtual void reset() = 0;
  /// The last frame's feature image (low on shafts) and region labels, processing scale.
  virtual cv::Mat const& feature() const = 0;
  virtual cv::Mat const& labels() const = 0;
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

/// Drops the narrower duplicates, then the overlapping ones, of res.contours (with their edges
/// and contour_regions; their regions' status becomes kDuplicate). `keys`: the detector's own
/// per-contour data, dropped alike.
void removeDuplicateShafts(SegmentationResult& res, std::vector<std::size_t>& keys);

/// Each contour's tip located on the frame (locateTipOnFrame()), on its image axis: the last step
/// of both detectors, after the duplicates' removal. The coarse mask is `instrument` (a network's
/// probability at the processing scale, surer than its thresholded region) or else each
/// contour's region.
void locateTips(SegmentationResult& res, DetectionFrame const& frame, cv::Mat const* instrument = nullptr);

/// The contour as reported: entry and tip moved onto its image axis (the lines' bisector), where
/// a seed or a mask's far point lies off it (an oblique entry, a jaw's corner).
geometry::ApparentContour onImageAxis(geometry::ApparentContour c);

}  // namespace endo_guidance::perception
