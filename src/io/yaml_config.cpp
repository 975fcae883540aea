// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/io/yaml_config.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <functional>
#include <map>
#include <stdexcept>

namespace endo_guidance::io {

bool CameraModel::hasDistortion() const {
  for (double d : D)
    if (d != 0.0) return true;
  return false;
}

Eigen::Matrix3d CameraModel::rectifiedK() const {
  if (P(0, 0) > 0.0 && P(1, 1) > 0.0) return P.leftCols<3>();
  return K;
}

namespace {
YAML::Node loadFile(std::string const& path, char const* what) {
  try {
    return YAML::LoadFile(path);
  } catch (std::exception const& e) {
    throw std::runtime_error(std::string("cannot read ") + what + " '" + path + "': " + e.what());
  }
}

std::vector<double> matrixData(YAML::Node const& n, std::string const& key, std::size_t expect) {
  YAML::Node const m = n[key];
  if (!m || !m["data"]) throw std::runtime_error("camera YAML: missing '" + key + ".data'");
  auto v = m["data"].as<std::vector<double>>();
  if (expect && v.size() != expect)
    throw std::runtime_error("camera YAML: '" + key + ".data' has " + std::to_string(v.size()) + " values, expected " +
                             std::to_string(expect));
  return v;
}
}  // namespace

CameraModel loadCameraYaml(std::string const& path) { return cameraFromYaml(loadFile(path, "camera YAML")); }

CameraModel parseCameraYaml(std::string const& text) {
  try {
    return cameraFromYaml(YAML::Load(text));
  } catch (YAML::Exception const& e) {
    throw std::runtime_error(std::string("camera YAML: ") + e.what());
  }
}

void parsePipelineYaml(std::string const& text, PipelineParams& p) {
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (YAML::Exception const& e) {
    throw std::runtime_error(std::string("parameters YAML: ") + e.what());
  }
  auto const unknown = applyPipelineParams(root, p);
  if (!unknown.empty()) throw std::runtime_error("parameters YAML: unknown key " + unknown.front());
}

CameraModel cameraFromYaml(YAML::Node const& n) {
  if (!n.IsMap()) throw std::runtime_error("camera YAML: not a map of keys");
  CameraModel c;
  if (!n["image_width"] || !n["image_height"]) throw std::runtime_error("camera YAML: missing image_width/image_height");
  try {
    c.width = n["image_width"].as<int>();
  c.height = n["image_height"].as<int>();
  auto const k = matrixData(n, "camera_matrix", 9);
  for (int i = 0; i < 9; ++i) c.K(i / 3, i % 3) = k[static_cast<std::size_t>(i)];
  if (n["distortion_model"]) c.distortion_model = n["distortion_model"].as<std::string>();
  if (n["distortion_coefficients"]) c.D = matrixData(n, "distortion_coefficients", 0);
  if (n["projection_matrix"]) {
    auto const p = matrixData(n, "projection_matrix", 12);
    for (int i = 0; i < 12; ++i) c.P(i / 4, i % 4) = p[static_cast<std::size_t>(i)];
  }
  } catch (YAML::Exception const& e) {
    throw std::runtime_error(std::string("camera YAML: wrong value type: ") + e.what());
  }
  if (c.width <= 0 || c.height <= 0) throw std::runtime_error("camera YAML: image size must be positive");
  if (!(c.K(0, 0) > 0.0) || !(c.K(1, 1) > 0.0) || !c.K.allFinite())
    throw std::runtime_error("camera YAML: camera_matrix has a zero or invalid focal length");
  if (c.distortion_model != "plumb_bob" && c.distortion_model != "rational_polynomial" && c.hasDistortion())
    throw std::runtime_error("camera YAML: unsupported distortion model '" + c.distortion_model + "'");
  return c;
}

void loadPipelineYaml(std::string const& path, PipelineParams& p) {
  auto const unknown = applyPipelineParams(loadFile(path, "parameters YAML"), p);
  if (unknown.empty()) return;
  std::string list;
  for (auto const& k : unknown) list += " " + k;
  throw std::runtime_error("parameters YAML '" + path + "': unknown keys:" + list);
}

perception::SegmentationParams::Detector detectorFromString(std::string const& name) {
  if (name == "colour") return perception::SegmentationParams::Detector::kColour;
  if (name == "learned") return perception::SegmentationParams::Detector::kLearned;
  throw std::runtime_error("pipeline parameters: segmentation/detector must be 'colour' or 'learned', not '" + name + "'");
}

char const* toString(perception::SegmentationParams::Detector d) {
  return d == perception::SegmentationParams::Detector::kLearned ? "learned" : "colour";
}

namespace {
using Setter = std::function<void(YAML::Node const&)>;

// key -> setter of a field of p. Keys mirror config/pipeline.yaml (flat, grouped by prefix).
std::map<std::string, Setter> pipelineKeys(PipelineParams& p) {
  auto d = [](double& x) { return Setter([&x](YAML::Node const& n) { x = n.as<double>(); }); };
  auto i = [](int& x) { return Setter([&x](YAML::Node const& n) { x = n.as<int>(); }); };
  auto b = [](bool& x) { return Setter([&x](YAML::Node const& n) { x = n.as<bool>(); }); };
  auto z = [](std::size_t& x) { return Setter([&x](YAML::Node const& n) { x = n.as<std::size_t>(); }); };
  auto str = [](std::string& x) { return Setter([&x](YAML::Node const& n) { x = n.as<std::string>(); }); };
  auto& S = p.segmentation;
  auto& T = p.insertion_points;
  std::map<std::string, Setter> const keys{
      {"radius", d(p.radius)},
      {"reject_unattached", b(p.reject_unattached)},
      {"segmentation/detector", Setter([&S](YAML::Node const& n) { S.detector = detectorFromString(n.as<std::string>()); })},
      {"segmentation/learned_model", str(S.learned.model)},
      {"segmentation/learned_threads", i(S.learned.threads)},
      {"segmentation/processing_width", i(S.processing_width)},
      {"segmentation/hue_origin_deg", d(S.feature.hue_origin_deg)},
      {"segmentation/sigma_radius", i(S.sigma_radius)},
      {"segmentation/sigma_delta", i(S.sigma_delta)},
      {"segmentation/fov_dark_threshold", i(S.fov.dark_threshold)},
      {"segmentation/seed_threshold", i(S.seeds.threshold)},
      {"segmentation/seed_near_threshold", i(S.seeds.near_threshold)},
      {"segmentation/seed_relative_threshold", d(S.seeds.relative_threshold)},
      {"segmentation/seed_run_floor", i(S.seeds.run_floor)},
      {"segmentation/dark_border_level", Setter([&S](YAML::Node const& n) {
         S.seeds.dark_border_level = S.regions.dark_border_level = n.as<double>();
       })},
      {"segmentation/grow_background_fractions",
       Setter([&S](YAML::Node const& n) { S.regions.background_fractions = n.as<std::vector<double>>(); })},
      {"segmentation/grow_thresholds", Setter([&S](YAML::Node const& n) { S.regions.thresholds = n.as<std::vector<int>>(); })},
      {"segmentation/max_regions", i(S.regions.max_regions)},
      {"segmentation/max_angle_deg", d(S.contours.max_angle_deg)},
      {"segmentation/min_length_px", d(S.contours.min_length_px)},
      {"segmentation/min_width_px", d(S.contours.min_width_px)},
      {"segmentation/max_residual_px", d(S.contours.max_residual_px)},
      {"segmentation/extend_max_misses", i(S.contours.extend_max_misses)},
      {"segmentation/extend_gate_px", d(S.contours.extend_gate_px)},
      {"segmentation/min_edge_contrast", d(S.contours.min_edge_contrast)},
      {"segmentation/edge_red_green_weight", d(S.contours.edge_red_green_weight)},
      {"segmentation/brightness_fallback_contrast", d(S.contours.brightness_fallback_contrast)},
      {"segmentation/line_sigma_floor_px", d(S.contours.line_sigma_floor_px)},
      {"segmentation/edge_lobe_floor", d(S.contours.edge_lobe_floor)},
      {"segmentation/min_fill", d(S.contours.min_fill)},
      {"segmentation/min_parallel_side_ratio", d(S.contours.min_parallel_side_ratio)},
      {"segmentation/min_elongation", d(S.contours.min_elongation)},
      {"segmentation/max_widening", d(S.contours.max_widening)},
      {"segmentation/max_glare_fraction", d(S.contours.max_glare_fraction)},
      {"segmentation/level_memory_px", i(S.level_memory_px)},
      {"segmentation/full_search_every", i(S.full_search_every)},
      {"segmentation/strip_search_max_every", i(S.strip_search_max_every)},
      {"segmentation/full_search_max_every", i(S.full_search_max_every)},
      {"segmentation/refused_area_change", d(S.refused_area_change)},
      {"segmentation/resought_min_entry_sine", d(S.resought_min_entry_sine)},
      {"segmentation/resought_min_tip_depth_px", d(S.resought_min_tip_depth_px)},
      {"segmentation/resought_max_widening", d(S.resought_max_widening)},
      {"segmentation/detect_every", i(S.tracking.detect_every)},
      {"segmentation/track_max_width_change", d(S.tracking.max_width_change)},
      {"segmentation/track_coarse_step_px", d(S.tracking.coarse_step_px)},
      {"segmentation/track_tip_reach_px", d(S.tracking.tip_reach_px)},
      {"segmentation/strip_search", b(S.strip.enabled)},
      {"segmentation/crossing_seeds", b(S.crossing_seeds)},
      {"segmentation/strip_max_angle_deg", d(S.strip.max_angle_deg)},
      {"segmentation/strip_min_response", d(S.strip.min_response)},
      {"segmentation/strip_min_inside_low", d(S.strip.min_inside_low)},
      {"segmentation/strip_max_inside_outside_ratio", d(S.strip.max_inside_outside_ratio)},
      {"segmentation/strip_min_length_ratio", d(S.strip.min_length_ratio)},
      {"segmentation/strip_max_full_res_ratio", d(S.strip.max_full_res_ratio)},
      {"segmentation/strip_max_full_res_ratio_matte", d(S.strip.max_full_res_ratio_matte)},
      {"segmentation/strip_max_specular_fraction", d(S.strip.max_specular_fraction)},
      {"segmentation/strip_full_res_outside_quantile", d(S.strip.full_res_outside_quantile)},
      {"segmentation/strip_retry_min_halfwidth_px", d(S.strip.retry_min_halfwidth_px)},
      {"pose/min_distance", d(p.pose.min_distance)},
      {"pose/max_distance", d(p.pose.max_distance)},
      {"insertion_points/max_points", i(T.max_points)},
      {"insertion_points/attach_distance", d(T.attach_distance)},
      {"insertion_points/memory_views", d(T.tracker.memory_views)},
      {"insertion_points/min_views", z(T.tracker.min_views)},
      {"insertion_points/min_conditioning", d(T.tracker.min_conditioning)},
      {"insertion_points/max_sigma", d(T.tracker.max_sigma)},
      {"insertion_points/point_motion_sigma", d(T.tracker.point_motion_sigma)},
      {"insertion_points/gate_max", d(T.tracker.gate_max)},
      {"insertion_points/correlation_views", z(T.tracker.correlation_views)},
      {"insertion_points/breathing_period", d(T.tracker.breathing_period)},
      {"tracking/max_angle_deg", d(p.tracking.max_angle_deg)},
      {"tracking/max_distance_px", d(p.tracking.max_distance_px)},
  };
  return keys;
}

// Values the stages cannot work with are refused here, with the key, not met as a crash or a
// silent misbehaviour later (a zero processing width divides by zero).
void validatePipelineParams(PipelineParams const& p) {
  auto const& S = p.segmentation;
  auto const& T = p.insertion_points;
  auto need = [](bool ok, char const* key, char const* what) {
    if (!ok) throw std::runtime_error(std::string("pipeline parameters: ") + key + " must be " + what);
  };
  need(p.radius > 0.0 && p.radius < 0.05, "radius", "in (0, 0.05) m");
  need(S.learned.threads >= 1 && S.learned.threads <= 64, "segmentation/learned_threads", "in [1, 64]");
  need(S.processing_width >= 32, "segmentation/processing_width", ">= 32 px");
  need(S.sigma_radius >= 1 && S.sigma_radius <= 3, "segmentation/sigma_radius", "in [1, 3] (the Sigma filter's windows)");
  need(S.sigma_delta >= 0 && S.sigma_delta <= 255, "segmentation/sigma_delta", "in [0, 255]");
  need(S.fov_refresh >= 1, "segmentation/fov_refresh", ">= 1");
  need(S.level_memory_px >= 0, "segmentation/level_memory_px", ">= 0");
  need(S.full_search_every >= 1, "segmentation/full_search_every", ">= 1");
  need(S.strip_search_max_every >= 1, "segmentation/strip_search_max_every", ">= 1");
  need(S.full_search_max_every >= 1, "segmentation/full_search_max_every", ">= 1");
  need(S.refused_area_change >= 0.0 && S.refused_area_change <= 1.0, "segmentation/refused_area_change", "in [0, 1]");
  need(S.resought_min_entry_sine >= 0.0 && S.resought_min_entry_sine <= 1.0, "segmentation/resought_min_entry_sine", "in [0, 1]");
  need(S.resought_min_tip_depth_px >= 0.0, "segmentation/resought_min_tip_depth_px", ">= 0");
  need(S.resought_max_widening >= 1.0, "segmentation/resought_max_widening", ">= 1");
  need(S.strip.full_res_outside_quantile >= 0.0 && S.strip.full_res_outside_quantile <= 1.0,
       "segmentation/strip_full_res_outside_quantile", "in [0, 1]");
  need(S.contours.brightness_fallback_contrast >= 0.0, "segmentation/brightness_fallback_contrast", ">= 0 (grey levels per px; 0: off)");
  need(S.strip.retry_min_halfwidth_px >= 0.0, "segmentation/strip_retry_min_halfwidth_px", ">= 0 (px; 0: no retry)");
  need(S.tracking.detect_every >= 1, "segmentation/detect_every", ">= 1");
  need(S.regions.max_regions >= 1, "segmentation/max_regions", ">= 1");
  need(S.seeds.threshold >= 0 && S.seeds.threshold <= 255, "segmentation/seed_threshold", "in [0, 255]");
  need(S.seeds.near_threshold >= 0 && S.seeds.near_threshold <= 255, "segmentation/seed_near_threshold", "in [0, 255]");
  need(p.pose.min_distance > 0.0 && p.pose.min_distance < p.pose.max_distance, "pose/min_distance",
       "positive and below pose/max_distance");
  need(T.max_points >= 0, "insertion_points/max_points", ">= 0 (0: as many as the axes support)");
  need(T.tracker.max_sigma >= 0.0, "insertion_points/max_sigma", ">= 0 (0: no limit)");
  need(T.tracker.breathing_period >= 0.0, "insertion_points/breathing_period", ">= 0 (s; 0: off)");
  // The growth levels index these lists (region_growing.h): refused, not guessed.
  auto const& g = S.regions.thresholds;
  if (g.empty() || !std::is_sorted(g.begin(), g.end()) || std::adjacent_find(g.begin(), g.end()) != g.end() || g.front() < 0 || g.back() > 255)
    throw std::runtime_error("pipeline parameters: segmentation/grow_thresholds must be strictly ascending feature levels in [0, 255]");
  for (double f : S.regions.background_fractions)
    if (!(f >= 0.0 && f <= 1.0))
      throw std::runtime_error("pipeline parameters: segmentation/grow_background_fractions must lie in [0, 1]");
}
}  // namespace

std::vector<std::string> applyPipelineParams(YAML::Node const& root, PipelineParams& p) {
  auto const keys = pipelineKeys(p);
  std::vector<std::string> unknown;
  std::function<void(YAML::Node const&, std::string const&)> walk = [&](YAML::Node const& n, std::string const& prefix) {
    for (auto const& kv : n) {
      std::string const key = prefix.empty() ? kv.first.as<std::string>() : prefix + "/" + kv.first.as<std::string>();
      auto const it = keys.find(key);
      if (it != keys.end()) it->second(kv.second);
      else if (kv.second.IsMap()) walk(kv.second, key);
      else unknown.push_back(key);
    }
  };
  try {
    walk(root, "");
  } catch (YAML::Exception const& e) {
    throw std::runtime_error(std::string("pipeline parameters: wrong value type: ") + e.what());
  }
  validatePipelineParams(p);
  return unknown;
}

}  // namespace endo_guidance::io
