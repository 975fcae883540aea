// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// Frames the package's image transports could not decode, by the transport's topic: the plugin has no
// node to report to, so the node that subscribed collects them for its diagnostics. One registry
// per process (an inline function's static is shared by the plugin's and the nodelets' libraries).
#pragma once

#include <cstddef>
#include <map>
#include <mutex>
#include <string>
#include <utility>

namespace endo_guidance::ros_io {

class TransportErrors {
 public:
  static TransportErrors& instance() {
    static TransportErrors registry;
    return registry;
  }
  void report(std::string const& topic, std::string const& why) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto& e = errors_[topic];
    ++e.first;
    e.second = why;
  }
  /// The frames lost on topic since the last call, and the last reason.
  std::pair<std::size_t, std::string> take(std::string const& topic) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto it = errors_.find(topic);
    if (it == errors_.end()) return {0, {}};
    auto e = std::move(it->second);
    errors_.erase(it);
    return e;
  }

 private:
  std::mutex mutex_;
  std::map<std::string, std::pair<std::size_t, std::string>> errors_;
};

}  // namespace endo_guidance::ros_io
