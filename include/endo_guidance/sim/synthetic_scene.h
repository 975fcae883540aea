// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <array>
#include <cstdint>
#include <optional>
#include <random>
#include <vector>

#include "endo_guidance/geometry/apparent_contour.h"
#include "endo_guidance/geometry/plucker_line.h"

namespace endo_guidance::sim {

/// One instrument of a synthetic surgery: a shaft of radius `radius` pivoting about a trocar
/// outside the field of view; its tip follows a Lissajous path in front of the camera.
struct SyntheticInstrument {
  Eigen::Vector3d trocar_c;       ///< mean trocar position, camera frame (m)
  Eigen::Vector3d tip_centre_c;   ///< centre of the tip's path (m)
  Eigen::Vector3d tip_amplitude;  ///< half-extent of the tip's path along x, y, z (m)
  Eigen::Vector3d tip_frequency;  ///< Hz along x, y, z
  double radius = 0.004;          ///< m
};

struct SyntheticSceneOptions {
  int width = 640;
  int height = 480;
  Eigen::Matrix3d K = (Eigen::Matrix3d() << 500, 0, 319.5, 0, 500, 239.5, 0, 0, 1).finished();
  double fps = 25.0;
  double breathing_amplitude = 0.0;  ///< m, peak displacement of every trocar
  double breathing_period = 4.0;     ///< s
  Eigen::Vector3d breathing_direction = Eigen::Vector3d(0.2, -1.0, 0.3).normalized();
  double line_noise_px = 0.0;        ///< sigma of the contour endpoints, perpendicular to the line
  std::uint64_t seed = 42;
};

/// What the camera sees of one instrument in one frame, with the exact truth.
struct SyntheticView {
  int instrument = -1;
  double radius = 0.0;
  Eigen::Vector3d trocar_c;        ///< true trocar position at this frame (with breathing)
  Eigen::Vector3d tip_c;           ///< true tip position
  geometry::PluckerLine axis;                ///< true axis, direction trocar -> tip
  geometry::ApparentContour truth;           ///< exact contour lines (ApparentContour order), entry, tip
  geometry::ApparentContour measured;        ///< lines through noisy endpoints, with their covariance
  /// Pixel of the jaws' end (the visible tip) when the jaws have a 3D length (viewOfInstrument's
  /// jaw_length > 0); NaN: the renderer draws jaws 1.6 shaft widths long in the image.
  Eigen::Vector2d jaw_end_px = Eigen::Vector2d::Constant(NAN);
};

/// The view of one shaft (radius, through trocar_c to tip_c, camera frame) by a camera K of
/// width x height: exact contour lines, entry and tip pixels (measured = truth). nullopt when the
/// tip is outside the image, behind the camera, or less than 40 px of shaft is seen. The
/// renderer draws exactly these lines (the simulator and the synthetic scene share it).
/// jaw_length > 0: the jaws continue the shaft that far beyond tip_c (metres) and their end,
/// tip_c + jaw_length d, is the visible tip (jaw_end_px; it must be in the image too).
std::optional<SyntheticView> viewOfInstrument(Eigen::Matrix3d const& K, int width, int height, Eigen::Vector3d const& trocar_c,
                                              Eigen::Vector3d const& tip_c, double radius, int instrument = 0,
                                              double jaw_length = 0.0);

/// The default 3-instrument scene of the demo and the tests: a 640x480 endoscope, trocars 6-12 cm
/// off-axis around the camera, tips moving 10-15 cm in front of it.
std::vector<SyntheticInstrument> defaultInstruments();

/// A geometric synthetic sequence (exact contours + noise). The image renderer of the
/// segmentation stage draws the same scene.
class SyntheticScene {
 public:
  SyntheticScene(std::vector<SyntheticInstrument> instruments, SyntheticSceneOptions const& options = {});
  /// Views of the instruments visible in frame k (tip inside the image, > 40 px of shaft seen).
  std::vector<SyntheticView> frame(int k);
  /// True trocar positions at frame k (with breathing) and their mean (without).
  Eigen::Vector3d trocarAt(int instrument, int k) const;
  Eigen::Vector3d const& meanTrocar(int instrument) const { return instruments_[instrument].trocar_c; }
  std::size_t size() const { return instruments_.size(); }
  SyntheticSceneOptions const& options() const { return options_; }

 private:
  std::vector<SyntheticInstrument> instruments_;
  SyntheticSceneOptions options_;
  std::mt19937_64 rng_;
};

}  // namespace endo_guidance::sim
