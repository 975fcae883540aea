// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// Small helpers shared by the evaluation programs.
#pragma once

#include <algorithm>
#include <cmath>
#include <vector>

namespace endo_guidance::tools {

/// The p-quantile (0..1, nearest rank) of v; NaN when empty.
inline double percentile(std::vector<double> v, double p) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<std::size_t>(p * (v.size() - 1) + 0.5))];
}

}  // namespace endo_guidance::tools
