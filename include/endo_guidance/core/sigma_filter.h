// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <opencv2/core.hpp>

namespace endo_guidance::core {

/// Lee's sigma filter [Lee83] on an 8-bit image: each pixel becomes the mean of the pixels of its
/// (2 radius + 1)^2 window whose value is within +-delta of its own,
/// \f[ \hat{f}(p) = \frac{\sum_{q \in W(p)} f(q)\,[|f(q) - f(p)| \le \delta]}{\sum_{q \in W(p)} [|f(q) - f(p)| \le \delta]} \f]
/// so noise is smoothed but an edge (a jump above delta) is kept. Written for speed on the
/// integer feature: per window offset one branch-free pass over a row (vectorised by the
/// compiler on 16-bit accumulators), a reciprocal table for the division. Border: replicated.
/// src and dst must differ. Radius 1..3.
void sigmaFilter(cv::Mat const& src, cv::Mat& dst, int radius = 2, int delta = 12);

}  // namespace endo_guidance::core
