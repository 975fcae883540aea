// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <array>
#include <opencv2/core.hpp>
#include <optional>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"

namespace endo_guidance::perception {

/// A coarse instrument mask at the processing scale: a probability (CV_32F in [0, 1]) or a
/// region (CV_8U, 255 on it) whose pixel (0, 0) is processing pixel `origin`; 0 outside it.
struct InstrumentMask {
  cv::Mat map;
  cv::Point origin;
};

/// The colours a tip was located with (locateTipOnFrame()): the tissue's two beside the shaft and
/// the instrument's, from `tool0` to `tool1` (the same twice when it has one).
struct TipColours {
  cv::Vec3f tissue0, tissue1, tool0, tool1;
};

/// The tip (the jaws' end) of a fitted contour located on the full-resolution frame, from a
/// coarse mask of the instrument (a network's at 160 x 128, or a region grown at half resolution):
/// such a mask stops a few of its own pixels short of thin jaws, and joins the jaws of two
/// instruments that nearly touch; the frame does neither. About the shaft's end, two colours of
/// the instrument (a black shaft's jaws are metal) and two of the tissue beside the shaft are
/// taken where the mask is sure of them (k-means; a trimap, as in matting). A pixel's instrument
/// share is its distance to the tissue's colours over that plus its distance to the instrument's;
/// the tip is the farthest point along the image axis where the share, connected to the shaft's
/// end, crosses one half (sub-pixel), within 2.5 widths beyond that end (the jaws' reach, as the
/// contour fit's). nullopt, and the mask's tip stands, when no instrument colour differs from
/// the tissue's by `min_contrast` levels or the instrument runs on past that reach.
///
/// `edges`: the contour's edge points per line (ContourFit::edges: the shaft's end is where the
/// shorter line ends); `fov`: the field of view's mask at the processing scale, `scale`: processing
/// to full resolution; `colours` (optional): set to the colours it took when it located the tip.
std::optional<Eigen::Vector2d> locateTipOnFrame(cv::Mat const& bgr, geometry::ApparentContour const& c,
                                                std::array<std::vector<Eigen::Vector2d>, 2> const& edges, InstrumentMask const& instrument,
                                                cv::Mat const& fov, int scale, double min_contrast = 20.0, TipColours* colours = nullptr);

/// The same with the colours a detection took (a tracked frame has no mask to take them from):
/// the instrument is what those colours call it from between the lines at the shaft's end on.
std::optional<Eigen::Vector2d> locateTipWithColours(cv::Mat const& bgr, geometry::ApparentContour const& c,
                                                    std::array<std::vector<Eigen::Vector2d>, 2> const& edges, TipColours const& colours,
                                                    cv::Mat const& fov, int scale);

}  // namespace endo_guidance::perception
