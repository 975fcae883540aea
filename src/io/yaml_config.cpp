// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/io/yaml_config.h"

#include "endo_guidance/io/parameter_table.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cstdio>
#include <type_traits>
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
// One value from YAML into a field of the table's type.
template <class Field>
void setFromYaml(Field& field, YAML::Node const& n) {
  using T = std::decay_t<Field>;
  if constexpr (std::is_same_v<T, TiedDouble>) {
    field.a = field.b = n.as<double>();
  } else if constexpr (std::is_same_v<T, perception::SegmentationParams::Detector>) {
    field = detectorFromString(n.as<std::string>());
  } else {
    field = n.as<T>();
  }
}

std::string describeRange(ParamInfo const& info) {
  char b[96];
  std::snprintf(b, sizeof b, "in [%g, %g]%s%s", info.min, info.max, *info.unit ? " " : "", info.unit);
  return b;
}

// A value outside its range (or NaN) is refused with its key, not met as a crash or a silent
// misbehaviour later (a zero processing width divides by zero).
template <class Field>
void checkRange(ParamInfo const& info, Field const& field) {
  using T = std::decay_t<Field>;
  auto in = [&info](double v) { return v >= info.min && v <= info.max; };
  bool ok = true;
  if constexpr (std::is_same_v<T, TiedDouble>) ok = in(field.a) && in(field.b);
  else if constexpr (std::is_same_v<T, double> || std::is_same_v<T, int> || std::is_same_v<T, std::size_t>)
    ok = in(static_cast<double>(field));
  else if constexpr (std::is_same_v<T, std::vector<double>> || std::is_same_v<T, std::vector<int>>)
    ok = std::all_of(field.begin(), field.end(), [&in](auto v) { return in(static_cast<double>(v)); });
  if (!ok) throw std::runtime_error(std::string("pipeline parameters: ") + info.key + " must be " + describeRange(info));
}

void validatePipelineParams(PipelineParams& p) {
  forEachPipelineParam(p, [](ParamInfo const& info, auto const& field) { checkRange(info, field); });
  // What one range cannot say.
  if (!(p.pose.min_distance > 0.0 && p.pose.min_distance < p.pose.max_distance))
    throw std::runtime_error("pipeline parameters: pose/min_distance must be positive and below pose/max_distance");
  // The growth levels index these lists (region_growing.h): refused, not guessed.
  auto const& g = p.segmentation.regions.thresholds;
  if (g.empty() || std::adjacent_find(g.begin(), g.end(), std::greater_equal<int>()) != g.end())
    throw std::runtime_error("pipeline parameters: segmentation/grow_thresholds must be strictly ascending feature levels in [0, 255]");
}
}  // namespace

std::vector<std::string> applyPipelineParams(YAML::Node const& root, PipelineParams& p) {
  std::map<std::string, std::function<void(YAML::Node const&)>> setters;
  forEachPipelineParam(p, [&setters](ParamInfo const& info, auto&& field) {
    if constexpr (std::is_same_v<std::decay_t<decltype(field)>, TiedDouble>)  // (references: held by value)
      setters[info.key] = [field](YAML::Node const& n) mutable { setFromYaml(field, n); };
    else
      setters[info.key] = [&field](YAML::Node const& n) { setFromYaml(field, n); };
  });
  std::vector<std::string> unknown;
  std::function<void(YAML::Node const&, std::string const&)> walk = [&](YAML::Node const& n, std::string const& prefix) {
    for (auto const& kv : n) {
      std::string const key = prefix.empty() ? kv.first.as<std::string>() : prefix + "/" + kv.first.as<std::string>();
      auto const it = setters.find(key);
      if (it != setters.end()) it->second(kv.second);
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
