// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// A node's dynamic_reconfigure Config and its pipeline parameters, mapped by the parameter
// table (io/parameter_table.h): the parameters live for that node, by their names.
#pragma once

#include <dynamic_reconfigure/Config.h>

#include <string>
#include <type_traits>

#include "endo_guidance/io/parameter_table.h"

namespace endo_guidance::ros_io {

namespace detail {
template <class Values, class V>
void setNamed(Values& values, std::string const& name, V v) {
  for (auto& x : values)
    if (x.name == name) {
      x.value = v;
      return;
    }
  values.emplace_back();
  values.back().name = name;
  values.back().value = v;
}
template <class Values, class V>
void getNamed(Values const& values, std::string const& name, V& v) {
  for (auto const& x : values)
    if (x.name == name) v = static_cast<V>(x.value);
}
// f(message values of the field's kind, name, field) for each parameter live on `live`.
template <class F>
void forEachLive(pipeline::PipelineParams& p, io::Live live, dynamic_reconfigure::Config& m, F&& f) {
  io::forEachPipelineParam(p, [&](io::ParamInfo const& info, auto&& field) {
    using T = std::decay_t<decltype(field)>;
    if (info.live != live) return;
    std::string const name = io::leafName(info.key);
    if constexpr (std::is_same_v<T, bool>) f(m.bools, name, field);
    else if constexpr (std::is_same_v<T, int>) f(m.ints, name, field);
    else if constexpr (std::is_same_v<T, double>) f(m.doubles, name, field);
  });
}
}  // namespace detail

/// The live parameters of `params` into `config` (the server's start: the loaded values).
template <class Config>
void toReconfigure(pipeline::PipelineParams params, io::Live live, Config& config) {
  dynamic_reconfigure::Config m;
  config.__toMessage__(m);
  detail::forEachLive(params, live, m, [](auto& values, std::string const& name, auto& field) {
    detail::setNamed(values, name, field);
  });
  config.__fromMessage__(m);
}

/// ... and back: `params`' live fields from `config` (the server's callback).
template <class Config>
void fromReconfigure(Config const& config, io::Live live, pipeline::PipelineParams& params) {
  dynamic_reconfigure::Config m;
  config.__toMessage__(m);
  detail::forEachLive(params, live, m, [](auto& values, std::string const& name, auto& field) {
    detail::getNamed(values, name, field);
  });
}

/// Whether `key` is one of the flat names dynamic_reconfigure's server for `Config` mirrors into
/// the node's namespace: found there again after a respawn, and not an unknown key.
template <class Config>
bool isReconfigureMirror(std::string const& key) {
  for (auto const& d : Config::__getParamDescriptions__())
    if (d->name == key) return true;
  return false;
}

}  // namespace endo_guidance::ros_io
