// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/io/parameter_table.h"

#include <charconv>
#include <sstream>
#include <stdexcept>
#include <type_traits>

#include "endo_guidance/io/yaml_config.h"

namespace endo_guidance::io {

namespace {
// The shortest text that reads back as the same double, with a decimal point ("2.0", "0.004").
std::string number(double v) {
  char b[32];
  auto const r = std::to_chars(b, b + sizeof b, v);
  std::string s(b, r.ptr);
  if (s.find_first_of(".e") == std::string::npos) s += ".0";
  return s;
}

template <class Field>
std::string yamlValue(Field const& field) {
  using T = std::decay_t<Field>;
  if constexpr (std::is_same_v<T, TiedDouble>) return number(field.a);
  else if constexpr (std::is_same_v<T, double>) return number(field);
  else if constexpr (std::is_same_v<T, bool>) return field ? "true" : "false";
  else if constexpr (std::is_same_v<T, std::string>) return "\"" + field + "\"";
  else if constexpr (std::is_same_v<T, perception::SegmentationParams::Detector>) return toString(field);
  else if constexpr (std::is_same_v<T, std::vector<double>> || std::is_same_v<T, std::vector<int>>) {
    std::string s = "[";
    for (std::size_t i = 0; i < field.size(); ++i) {
      if (i) s += ", ";
      if constexpr (std::is_same_v<T, std::vector<double>>) s += number(field[i]);
      else s += std::to_string(field[i]);
    }
    return s + "]";
  } else {
    return std::to_string(field);
  }
}

std::string pad(std::string s, std::size_t width) {
  if (s.size() < width) s.append(width - s.size(), ' ');
  return s;
}
}  // namespace

std::string leafName(char const* key) {
  std::string const k(key);
  auto const slash = k.rfind('/');
  return slash == std::string::npos ? k : k.substr(slash + 1);
}

std::string pipelineYaml(pipeline::PipelineParams p) {
  std::ostringstream out;
  out << "# endo_guidance pipeline parameters (the offline program's --params and the nodes' private\n"
         "# namespace), every one at its code default. Written by `endo_guidance_params --yaml` from the\n"
         "# parameter table (include/endo_guidance/io/parameter_table.h): edit the table, not this file.\n";
  std::string group;
  forEachPipelineParam(p, [&](ParamInfo const& info, auto&& field) {
    std::string const key(info.key);
    auto const slash = key.find('/');
    std::string const g = slash == std::string::npos ? "" : key.substr(0, slash);
    if (g != group) {
      out << "\n" << g << ":\n";
      group = g;
    }
    std::string const indent = g.empty() ? "" : "  ";
    std::string const line = indent + leafName(info.key) + ": " + yamlValue(field);
    std::string const comment = "# " + (*info.unit ? std::string(info.unit) + ", " : std::string()) + info.doc;
    std::string const beside = pad(line, 36) + "  " + comment;
    if (beside.size() <= 110) out << beside << "\n";
    else out << indent << comment << "\n" << line << "\n";  // a long one above its key
  });
  return out.str();
}

std::string reconfigureCfg(Live live) {
  if (live == Live::kNo) throw std::invalid_argument("reconfigureCfg: no node");
  std::string const node = live == Live::kSegmentation ? "Segmentation" : "InsertionPoints";
  std::ostringstream out;
  out << "#!/usr/bin/env python3\n"
         "# The live-tunable parameters of endo_guidance/" << node << ", written by\n"
         "# `endo_guidance_params --cfg " << node << "` from the parameter table\n"
         "# (include/endo_guidance/io/parameter_table.h): edit the table, not this file. The node starts\n"
         "# from the values it loaded (config/pipeline.yaml and the launch's parameters), not these defaults.\n"
         "PACKAGE = \"endo_guidance\"\n"
         "from dynamic_reconfigure.parameter_generator_catkin import ParameterGenerator, int_t, double_t, bool_t\n\n"
         "gen = ParameterGenerator()\n";
  pipeline::PipelineParams p;
  forEachPipelineParam(p, [&](ParamInfo const& info, auto&& field) {
    using T = std::decay_t<decltype(field)>;
    if (info.live != live) return;
    std::string const doc = std::string(info.doc) + (*info.unit ? std::string(" (") + info.unit + ")" : std::string());
    out << "gen.add(\"" << leafName(info.key) << "\", ";
    if constexpr (std::is_same_v<T, bool>) {
      out << "bool_t, 0, \"" << doc << "\", " << (field ? "True" : "False") << ")\n";
    } else if constexpr (std::is_same_v<T, int>) {
      out << "int_t, 0, \"" << doc << "\", " << field << ", " << static_cast<int>(info.min) << ", "
          << static_cast<int>(info.max) << ")\n";
    } else if constexpr (std::is_same_v<T, double>) {
      out << "double_t, 0, \"" << doc << "\", " << number(field) << ", " << number(info.min) << ", " << number(info.max)
          << ")\n";
    } else {
      throw std::logic_error(std::string("parameter table: ") + info.key + " cannot be live (bool, int or double only)");
    }
  });
  out << "exit(gen.generate(PACKAGE, \"endo_guidance\", \"" << node << "\"))\n";
  return out.str();
}

}  // namespace endo_guidance::io
