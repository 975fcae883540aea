// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The one table of the pipeline's parameters. The YAML loading and its validation
// (yaml_config.h), config/pipeline.yaml and cfg/*.cfg (printed by `endo_guidance_params`,
// compared by the test `parameter_files_match_the_table`) and the nodes' dynamic_reconfigure
// mapping (ros_io::toReconfigure()) all come from it: adding a parameter is one line here, then
// `scripts/write_parameter_files.sh`.
#pragma once

#include <string>
#include <vector>

#include "endo_guidance/pipeline/pipeline.h"

namespace endo_guidance::io {

/// Which node's dynamic_reconfigure server tunes a parameter live (cfg/<Node>.cfg; the name there
/// is the key's last element).
enum class Live { kNo, kSegmentation, kInsertionPoints };

/// One parameter: its key in config/pipeline.yaml ("group/name"), the inclusive range of its
/// values (of each element of a list; ignored for bool, string and the detector), its unit ("":
/// a count, fraction or feature level), and one line of doc (the YAML's comment, the .cfg's
/// description).
struct ParamInfo {
  char const* key;
  double min, max;
  char const* unit;
  Live live;
  char const* doc;
};

/// A parameter held in two fields of the core's structs (the same level read by two stages).
struct TiedDouble {
  double& a;
  double& b;
};

/// Calls f(info, field) for every pipeline parameter in config/pipeline.yaml's order. `field` is
/// a reference to a double, int, bool, std::size_t, std::string, std::vector<double>,
/// std::vector<int>, perception::SegmentationParams::Detector, or a TiedDouble.
template <class F>
void forEachPipelineParam(pipeline::PipelineParams& p, F&& f) {
  using L = Live;
  auto& S = p.segmentation;
  auto& C = S.contours;
  auto& R = S.strip;
  auto& T = p.insertion_points;
  auto& K = T.tracker;
  f(ParamInfo{"radius", 1e-4, 0.05, "m", L::kNo, "instrument shaft radius (8 mm shafts)"}, p.radius);
  f(ParamInfo{"reject_unattached", 0, 1, "", L::kInsertionPoints,
              "drop shafts through no insertion point once one is well conditioned"}, p.reject_unattached);
  f(ParamInfo{"segmentation/detector", 0, 0, "", L::kNo,
              "colour | learned: what proposes the shaft candidates (docs/accuracy.md)"}, S.detector);
  f(ParamInfo{"segmentation/learned_model", 0, 0, "", L::kNo,
              "the learned detector's model YAML (empty: the package's models/shaft_net.yaml)"}, S.learned.model);
  f(ParamInfo{"segmentation/learned_threads", 1, 64, "", L::kNo,
              "OpenCV threads of the learned detector (a pool shared by the whole process)"}, S.learned.threads);
  f(ParamInfo{"segmentation/processing_width", 32, 4096, "px", L::kNo,
              "the region stages run on the frame reduced by an integer factor to about this width"}, S.processing_width);
  f(ParamInfo{"segmentation/hue_origin_deg", 0, 360, "deg", L::kNo,
              "hue of the lowest weight (green); tissue (red, yellow) maps high"}, S.feature.hue_origin_deg);
  f(ParamInfo{"segmentation/sigma_radius", 1, 3, "px", L::kNo, "Sigma filter window radius (processing scale)"}, S.sigma_radius);
  f(ParamInfo{"segmentation/sigma_delta", 0, 255, "", L::kSegmentation, "Sigma filter range (feature units)"}, S.sigma_delta);
  f(ParamInfo{"segmentation/fov_dark_threshold", 0, 255, "", L::kSegmentation,
              "max(B, G, R) at or below is the black surround"}, S.fov.dark_threshold);
  f(ParamInfo{"segmentation/seed_threshold", 0, 255, "", L::kSegmentation,
              "border runs at or below start a region (feature units)"}, S.seeds.threshold);
  f(ParamInfo{"segmentation/seed_near_threshold", 0, 255, "", L::kSegmentation,
              "relaxed threshold on the border arc facing a known trocar image"}, S.seeds.near_threshold);
  f(ParamInfo{"segmentation/seed_relative_threshold", 0, 1, "", L::kSegmentation,
              "on a dark border: also at most this fraction of the local tissue level"}, S.seeds.relative_threshold);
  f(ParamInfo{"segmentation/seed_run_floor", 0, 255, "", L::kSegmentation,
              "on a dark border a run extends up to this level; its seed in its lowest part"}, S.seeds.run_floor);
  f(ParamInfo{"segmentation/dark_border_level", 0, 255, "", L::kNo,
              "the border is dark where its local tissue level is below this"},
    TiedDouble{S.seeds.dark_border_level, S.regions.dark_border_level});
  f(ParamInfo{"segmentation/grow_background_fractions", 0, 1, "", L::kNo,
              "on a dark border, growth levels at seed + f (tissue - seed)"}, S.regions.background_fractions);
  f(ParamInfo{"segmentation/grow_thresholds", 0, 255, "", L::kNo,
              "growth levels tried per seed, strictly ascending (feature units)"}, S.regions.thresholds);
  f(ParamInfo{"segmentation/max_regions", 1, 32, "", L::kSegmentation, "shafts per frame"}, S.regions.max_regions);
  f(ParamInfo{"segmentation/max_angle_deg", 1, 60, "deg", L::kSegmentation,
              "max angle between the two contour lines of a shaft"}, C.max_angle_deg);
  f(ParamInfo{"segmentation/min_length_px", 1, 2000, "px", L::kSegmentation, "min shaft length seen, entry to tip"},
    C.min_length_px);
  f(ParamInfo{"segmentation/min_width_px", 1, 500, "px", L::kSegmentation, "min shaft width at its entry and its tip"},
    C.min_width_px);
  f(ParamInfo{"segmentation/max_residual_px", 0.1, 20, "px", L::kSegmentation,
              "max RMS of the sub-pixel edge points to their line"}, C.max_residual_px);
  f(ParamInfo{"segmentation/min_edge_contrast", 0.1, 50, "", L::kSegmentation,
              "edge channel per px: weaker profiles carry no edge"}, C.min_edge_contrast);
  f(ParamInfo{"segmentation/extend_max_misses", 0, 1000, "", L::kNo,
              "profiles: a line is followed along its edge until this many in a row miss (0: not followed)"},
    C.extend_max_misses);
  f(ParamInfo{"segmentation/extend_gate_px", 0, 10, "px", L::kNo,
              "an edge point within max(3 residuals, this) of the line continues it"}, C.extend_gate_px);
  f(ParamInfo{"segmentation/line_sigma_floor_px", 0, 10, "px", L::kNo,
              "systematic error at each end of a contour line, added to its covariance"}, C.line_sigma_floor_px);
  f(ParamInfo{"segmentation/edge_lobe_floor", -1, 1, "", L::kNo,
              "an edge is the centroid of its slope's lobe down to this fraction of the peak (< 0: window)"},
    C.edge_lobe_floor);
  f(ParamInfo{"segmentation/min_fill", 0, 1, "", L::kSegmentation,
              "fraction of the strip between the lines covered by the region"}, C.min_fill);
  f(ParamInfo{"segmentation/min_parallel_side_ratio", 0, 1, "", L::kNo,
              "a crooked side may be its stretch parallel to the other side, this long relative to it (0: never)"},
    C.min_parallel_side_ratio);
  f(ParamInfo{"segmentation/min_elongation", 0.5, 50, "", L::kSegmentation, "length over width"}, C.min_elongation);
  f(ParamInfo{"segmentation/max_widening", 0, 10, "", L::kSegmentation,
              "width at the tip over width at the entry (0: no limit)"}, C.max_widening);
  f(ParamInfo{"segmentation/max_glare_fraction", 0, 1, "", L::kSegmentation,
              "fraction of the samples between the lines that may be glare (near white, achromatic)"},
    C.max_glare_fraction);
  f(ParamInfo{"segmentation/level_memory_px", 0, 1000, "px", L::kNo,
              "a seed this close to last frame's reuses its growth level (processing scale)"}, S.level_memory_px);
  f(ParamInfo{"segmentation/full_search_every", 1, 1000, "frames", L::kNo,
              "a refused seed is grown at every level again this often"}, S.full_search_every);
  f(ParamInfo{"segmentation/strip_search_max_every", 1, 1000, "frames", L::kNo,
              "its strip search backs off (interval doubling) up to this"}, S.strip_search_max_every);
  f(ParamInfo{"segmentation/full_search_max_every", 1, 1000, "frames", L::kNo,
              "... and its full search too, while its run and region keep their size"}, S.full_search_max_every);
  f(ParamInfo{"segmentation/refused_area_change", 0, 1, "", L::kNo,
              "... its region's area change since the last full search (fraction of the larger)"}, S.refused_area_change);
  f(ParamInfo{"segmentation/resought_min_entry_sine", 0, 1, "", L::kNo,
              "sides sought again, or from another seed's region: sine of the entry angle at least"},
    S.resought_min_entry_sine);
  f(ParamInfo{"segmentation/resought_min_tip_depth_px", 0, 1000, "px", L::kNo,
              "... and their tip at least this far inside the field of view (processing scale)"},
    S.resought_min_tip_depth_px);
  f(ParamInfo{"segmentation/resought_max_widening", 1, 10, "", L::kNo,
              "... and their width at the tip over that at the entry at most this (crossing pairs too)"},
    S.resought_max_widening);
  f(ParamInfo{"segmentation/crossing_seeds", 0, 1, "", L::kSegmentation,
              "also seed on the edge of a shaft found that a refused region touches"}, S.crossing_seeds);
  f(ParamInfo{"segmentation/detect_every", 0, 30, "frames", L::kSegmentation,
              "full detection this often; the shafts found are tracked between (1: every frame; 0: the detector's own, learned 8, colour 1)"},
    S.tracking.detect_every);
  f(ParamInfo{"segmentation/track_max_width_change", 0, 10, "", L::kNo,
              "a tracked shaft's relative width change per frame (+2 px) beyond which it is lost"},
    S.tracking.max_width_change);
  f(ParamInfo{"segmentation/track_coarse_step_px", 0.5, 100, "px", L::kNo,
              "profile spacing of a tracked line's wide pass (the narrow pass: every 2 px)"}, S.tracking.coarse_step_px);
  f(ParamInfo{"segmentation/strip_search", 0, 1, "", L::kSegmentation,
              "seeds whose grown regions all leaked: search the shaft's sides in the feature gradient"}, R.enabled);
  f(ParamInfo{"segmentation/strip_max_angle_deg", 0, 90, "deg", L::kNo,
              "sides searched within this angle of the inward normal at the seed"}, R.max_angle_deg);
  f(ParamInfo{"segmentation/strip_min_response", 0, 10, "", L::kNo,
              "fraction of a full edge (Sobel 40): a side continues while its edge is this strong"}, R.min_response);
  f(ParamInfo{"segmentation/strip_min_inside_low", 0, 1, "", L::kNo,
              "fraction of the strip at or below the highest growth level"}, R.min_inside_low);
  f(ParamInfo{"segmentation/strip_max_inside_outside_ratio", 0.05, 1, "", L::kSegmentation,
              "strip search: strip median feature over the tissue's beside each side"}, R.max_inside_outside_ratio);
  f(ParamInfo{"segmentation/strip_min_length_ratio", 0, 1, "", L::kNo, "shorter side over the longer"},
    R.min_length_ratio);
  f(ParamInfo{"segmentation/strip_max_full_res_ratio", 0, 10, "", L::kNo,
              "full-resolution median chroma inside over beside (refuses specular speckle bands)"}, R.max_full_res_ratio);
  f(ParamInfo{"segmentation/strip_max_full_res_ratio_matte", 0, 10, "", L::kNo,
              "the same for a strip with few highlights inside (metal mirroring tissue)"}, R.max_full_res_ratio_matte);
  f(ParamInfo{"segmentation/strip_max_specular_fraction", 0, 1, "", L::kNo,
              "few highlights: this fraction of the inside samples near white"}, R.max_specular_fraction);
  f(ParamInfo{"segmentation/strip_full_res_outside_quantile", 0, 1, "", L::kNo,
              "the tissue's level beside a line: this quantile of its samples"}, R.full_res_outside_quantile);
  f(ParamInfo{"segmentation/strip_retry_min_halfwidth_px", 0, 100, "px", L::kNo,
              "lines that left their strip are refined again, the wide pass narrowed down to this (0: off)"},
    R.retry_min_halfwidth_px);
  f(ParamInfo{"pose/min_distance", 0, 100, "m", L::kNo, "an axis closer to the optical centre is rejected"},
    p.pose.min_distance);
  f(ParamInfo{"pose/max_distance", 0, 100, "m", L::kNo, "an axis farther is rejected"}, p.pose.max_distance);
  f(ParamInfo{"insertion_points/max_points", 0, 64, "", L::kNo, "0: discover as many as the axes support"},
    T.max_points);
  f(ParamInfo{"insertion_points/attach_distance", 0.001, 0.1, "m", L::kInsertionPoints,
              "Eq. (6) threshold for attaching an axis (widened to each point's gate)"}, T.attach_distance);
  f(ParamInfo{"insertion_points/memory_views", 1, 1e6, "axes", L::kNo, "forgetting time constant (several breaths)"},
    K.memory_views);
  f(ParamInfo{"insertion_points/min_views", 1, 1e6, "axes", L::kNo, "before a first estimate"}, K.min_views);
  f(ParamInfo{"insertion_points/min_conditioning", 0, 0.5, "rad", L::kInsertionPoints,
              "RMS angular spread (sine) below which a point is ill-conditioned"}, K.min_conditioning);
  f(ParamInfo{"insertion_points/max_sigma", 0, 0.1, "m", L::kInsertionPoints,
              "a point is located (on tf) once its covariance's longest axis is at most this (0: at once)"},
    K.max_sigma);
  f(ParamInfo{"insertion_points/point_motion_sigma", 0, 0.02, "m", L::kInsertionPoints,
              "RMS motion of a trocar (breathing)"}, K.point_motion_sigma);
  f(ParamInfo{"insertion_points/gate_max", 0.002, 0.2, "m", L::kInsertionPoints, "widest outlier gate"}, K.gate_max);
  f(ParamInfo{"insertion_points/correlation_views", 0, 1e6, "axes", L::kNo,
              "per block whose shared errors the covariance covers (0: axes independent)"}, K.correlation_views);
  f(ParamInfo{"insertion_points/breathing_period", 0, 20, "s", L::kInsertionPoints,
              "the ventilator's cycle, over which a trocar's own motion is shared by the axes (0: off)"},
    K.breathing_period);
  f(ParamInfo{"tracking/max_angle_deg", 0, 90, "deg", L::kNo, "a shaft keeps its track id within this angle"},
    p.tracking.max_angle_deg);
  f(ParamInfo{"tracking/max_distance_px", 0, 1e4, "px", L::kNo,
              "... and this distance of its previous entry and tip to its new axis"}, p.tracking.max_distance_px);
}

/// config/pipeline.yaml as the table gives it: every key with its unit and doc, at the values of
/// `p` (the code defaults: the shipped file).
std::string pipelineYaml(pipeline::PipelineParams p = {});
/// cfg/<node>.cfg for `live` (kSegmentation: Segmentation, kInsertionPoints: InsertionPoints).
std::string reconfigureCfg(Live live);
/// The key's last element (its name in a .cfg and on a node's dynamic_reconfigure server).
std::string leafName(char const* key);

}  // namespace endo_guidance::io
