// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace endo_guidance::perception {

/// The colour image reduced by an integer factor f for the region stages: each output pixel is
/// the rounded mean of an f x f block (the last cols % f columns and rows % f rows are dropped,
/// so that x_small = (x_full - (f - 1) / 2) / f holds everywhere: cv::resize of an odd-sized
/// image to half its size spreads the blocks instead, and takes OpenCV's slow general path).
/// f = 1 shares `src`; f = 2 is cv::resize(INTER_AREA)'s (a + b + c + d + 2) >> 2 (with AVX2 by
/// pshufb, bit for bit); other factors round sum / f^2 to nearest (half up), in one pass. `dst`
/// may be `src` (in place).
void reduceImage(cv::Mat const& src, int f, cv::Mat& dst);

/// A pixel of the image reduced by f (the region stages' processing scale) at full resolution:
/// the centre of its block, p_full = f p + (f - 1) / 2.
inline Eigen::Vector2d toFullRes(Eigen::Vector2d const& p, int f) {
  double const off = 0.5 * (f - 1);
  return Eigen::Vector2d(p.x() * f + off, p.y() * f + off);
}
/// The inverse of toFullRes(): a full-resolution pixel at the processing scale.
inline Eigen::Vector2d toProcessing(Eigen::Vector2d const& p, int f) {
  double const off = 0.5 * (f - 1);
  return (p - Eigen::Vector2d(off, off)) / f;
}
/// toProcessing() of a homogeneous point (w = 0: a direction, unchanged up to scale; the trocar
/// images may lie at infinity).
inline Eigen::Vector3d toProcessing(Eigen::Vector3d const& p, int f) {
  double const off = 0.5 * (f - 1);
  return Eigen::Vector3d((p.x() - off * p.z()) / f, (p.y() - off * p.z()) / f, p.z());
}

}  // namespace endo_guidance::perception
