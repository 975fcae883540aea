// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <Eigen/Core>
#include <cstdint>
#include <vector>

#include "endo_guidance/geometry/plucker_line.h"

namespace endo_guidance::geometry {

enum class InsertionPointStatus {
  kOk = 0,
  kTooFewAxes,   ///< fewer than 2 (usable) axes
  kAtInfinity,   ///< the axes are (nearly) parallel: the common point is at infinity
  kNoConsensus,  ///< robust search found no subset of axes that agree
};
char const* toString(InsertionPointStatus s);

/// A common point of instrument axes: the insertion point (trocar) in the camera frame.
struct InsertionPointEstimate {
  InsertionPointStatus status = InsertionPointStatus::kTooFewAxes;
  /// Homogeneous null vector of Eq. (3), |I| = 1, sign chosen so that I_z > 0.
  Eigen::Vector4d homogeneous = Eigen::Vector4d::Zero();
  Eigen::Vector3d position = Eigen::Vector3d::Zero();      ///< metres (valid when ok())
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Zero();    ///< m^2, from the residuals
  std::size_t views = 0;                                   ///< axes used (inliers)
  double rms_distance = 0.0;                               ///< RMS distance of those axes, metres
  double conditioning = 0.0;                               ///< RMS angular spread of the axes, rad
  std::vector<int> inliers;                                ///< indices into the input (robust form)
  bool ok() const { return status == InsertionPointStatus::kOk; }
  /// The covariance's longest axis (1 sigma, metres); +inf when it is not finite.
  double longestSigma() const;
};

/// RMS angular spread (radians) of a set of axis directions about their mean direction (sign of
/// each direction ignored): sqrt of the smallest eigenvalue of (1/n) sum (I - d d^T), weighted.
/// It is the conditioning of the insertion point: the estimate's error along the mean axis grows
/// as 1/spread. 0 for fewer than 2 axes or all parallel.
double axesAngularSpread(std::vector<PluckerLine> const& axes, std::vector<double> const& weights = {});

/// Least-squares common point of n >= 2 axes, [Doignon07] Eq. (3): the right singular vector
/// of the smallest singular value of the stacked dual Plücker matrices
/// \f[ \begin{pmatrix} L_1^* \\ \vdots \\ L_n^* \end{pmatrix} \tilde{\mathbf{I}} = 0 \f]
/// after a similarity normalisation of the lines (centroid to the origin, unit RMS distance).
/// Optional weights (>= 0) scale each line's block. Fails with kAtInfinity for parallel axes.
InsertionPointEstimate intersectAxes(std::vector<PluckerLine> const& axes, std::vector<double> const& weights = {});

struct RobustIntersectOptions {
  int max_samples = 500;            ///< pairs drawn (all pairs if fewer)
  double inlier_fraction = 0.5;     ///< order statistic minimised: 0.5 = least median of squares
  double min_inlier_threshold = 5e-4;  ///< metres: inlier distance never below this
  double max_inlier_threshold = 0.01;  ///< metres: nor above this
  double inlier_sigmas = 2.5;       ///< inliers: distance < inlier_sigmas * robust sigma
  double min_pair_sine = 0.01;      ///< skip pairs of near-parallel axes
  std::uint64_t seed = 1;           ///< deterministic sampling
};

/// Robust common point (LMedS over pairs of axes, then Eq. (3) on the inliers): survives up to
/// 50 % of wrong axes with the default inlier_fraction.
InsertionPointEstimate intersectAxesRobust(std::vector<PluckerLine> const& axes,
                                           RobustIntersectOptions const& options = {});

}  // namespace endo_guidance::geometry
