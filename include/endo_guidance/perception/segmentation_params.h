// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <string>

#include "endo_guidance/perception/colour_feature.h"
#include "endo_guidance/perception/contour_params.h"
#include "endo_guidance/perception/contour_tracking.h"
#include "endo_guidance/perception/field_of_view.h"
#include "endo_guidance/perception/region_growing.h"
#include "endo_guidance/perception/seed_search.h"
#include "endo_guidance/perception/strip_search.h"

namespace endo_guidance::perception {

/// The package's shaft network (models/shaft_net.yaml; scripts/train_shaft_net.sh reproduces it).
std::string defaultShaftModel();

struct LearnedDetectorParams {
  std::string model;               ///< the model's YAML (input size, normalisation, ONNX file); empty: defaultShaftModel()
  int threads = 1;                 ///< OpenCV threads (cv::setNumThreads(): process-wide)
};

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
  Detector detector = Detector::kLearned;
  LearnedDetectorParams learned;
  ColourFeatureParams feature;
  FieldOfViewParams fov;
  SeedSearchParams seeds;
  RegionGrowingParams regions;
  ContourLinesParams contours;
  StripSearchParams strip;
  ContourTrackingParams tracking;
};

}  // namespace endo_guidance::perception
