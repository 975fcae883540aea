// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <algorithm>

#include <cstddef>
#include <deque>
#include <functional>
#include <limits>
#include <vector>

#include "endo_guidance/geometry/insertion_point.h"

namespace endo_guidance::geometry {

using AxisCovariance = Eigen::Matrix<double, 6, 6>;  ///< of (direction, moment), as CylinderPose

/// One axis as the insertion points take it: the axis (camera frame), its covariance (zero: none
/// given) and when it was seen (s; NaN: none).
struct AxisObservation {
  PluckerLine axis;
  AxisCovariance covariance;
  double stamp;
};

struct InsertionPointTrackerOptions {
  std::size_t window = 300;          ///< axes kept for (re)initialisation (bounded memory)
  double memory_views = 500.0;       ///< forgetting time constant, in accepted axes (rho = exp(-1/memory)):
                                     ///< 20 s at 25 Hz spans several breaths, so the mean is estimated
  std::size_t min_views = 10;        ///< axes needed before the first estimate
  double min_conditioning = 0.035;   ///< rad (2 deg): below, the estimate is flagged ill-conditioned
  double max_sigma = 0.005;          ///< metres: a well-conditioned point is located (located()) once its
                                     ///< covariance's longest axis (1 sigma) is at most this (0: at once):
                                     ///< well conditioned alone can still be centimetres off
  double default_axis_sigma = 0.001; ///< metres: assumed distance noise of an axis given without covariance
  double point_motion_sigma = 0.001; ///< metres: RMS motion of the trocar itself (breathing), added to
                                     ///< every axis's residual covariance
  double gate_distance = 0.008;      ///< metres: an axis is an outlier beyond max(this, gate_sigmas * spread)
  double gate_sigmas = 4.0;
  double gate_max = 0.025;           ///< metres: the gate never widens beyond this
  std::size_t reinit_after = 40;     ///< consecutive outliers that trigger a robust re-initialisation
  double huber_k = 2.5;              ///< Huber threshold on the normalised residual (0: off)
  int reweight_iterations = 3;       ///< Gauss-Markov reweighting passes when (re)initialising
  std::size_t correlation_views = 10; ///< axes per block of the cluster-robust covariance (0: the model
                                     ///< covariance alone): consecutive axes of one shaft share their
                                     ///< errors (compression, breathing), which the model covariance,
                                     ///< taking them as independent, underestimates several-fold
  double breathing_period = 4.0;     ///< s (0: off): the trocar's own motion is shared by the axes of a
                                     ///< breathing cycle, so the covariance along the mean axis is at least
                                     ///< min(rms, point_motion_sigma) / spread per cycle seen (the time the
                                     ///< axes span, from their stamps). A slow sweep of precise axes about a
                                     ///< breathing trocar was located 12-19 mm off without it
  double assumed_axis_interval = 0.04; ///< s between axes given without a stamp (25 Hz)
  RobustIntersectOptions robust;
};

/// Recursive, weighted form of Eq. (3) for a live stream: one insertion point followed with
/// exponential forgetting, so that a trocar moving a few millimetres with breathing is
/// estimated about its mean position.
///
/// With B_k = [ [d]x | m ] the first three rows of the dual Plücker matrix (Eq. (2)),
/// r_k = B_k x~ = d x (x - p) is the distance vector of x~ = (x, 1) to axis k. Each axis is
/// weighted by the inverse of the covariance of r_k at the current estimate,
/// \f[ \Sigma_{r,k} = P_k (J \Sigma_k J^\top + \sigma_b^2 I) P_k,\quad J = [\,-[\mathbf{x}]_\times \;\; I\,],\quad P_k = I - \mathbf{d}\mathbf{d}^\top,\qquad
///     W_k = \Sigma_{r,k}^{+} \f]
/// (Gauss-Markov: an axis measured far from the trocar has a wide error tube there). Without
/// this, the angular noise of axes pivoting about their visible part biases a plain
/// least-squares point toward the image (errors in variables). The tracker keeps
/// \f[ \mathcal{B}_w = \sum_k \rho^{n-k} B_k^\top W_k B_k = \begin{pmatrix} S & \mathbf{b} \\ \mathbf{b}^\top & c \end{pmatrix},\qquad
///     \hat{\mathbf{x}} = -S^{-1}\mathbf{b},\quad \mathrm{cov}(\hat{\mathbf{x}}) \approx S^{-1} \f]
/// and the unweighted sum for the RMS distance and the angular spread. The covariance is the
/// model's, inflated where the axes scatter more than it says, and, since consecutive axes of a
/// shaft share their errors, where blocks of correlation_views consecutive axes do (cluster-robust
/// "sandwich" [Liang86]: with the blocks' weighted sums M_b and g_b = (M_b x~)_{1..3},
/// \f$ \Sigma_c = \tfrac{B}{B-1} S^{-1} (\sum_b g_b g_b^\top) S^{-1} \f$, the model covariance scaled by
/// the largest generalised eigenvalue of \f$ \Sigma_c \f$ over it when above 1, keeping its shape),
/// and at least \f$ \mathrm{rms}^2 / (\mathrm{spread}^2\, G) \f$ along the mean axis, G the number of
/// independent groups of correlation_views axes (the along-axis error of a shared error), and at
/// least \f$ \min(\mathrm{rms}, \sigma_b)^2 / (\mathrm{spread}^2\, G_b) \f$, G_b the number of
/// breathing cycles the axes span (breathing_period; each pause counted as one cycle at most): the
/// trocar's own motion is shared by every axis of a cycle.
/// Memory is O(1) in the axes, plus a
/// bounded window of recent axes. Axes beyond the gate are rejected (not accumulated); a run of
/// rejections re-initialises the estimate robustly (LMedS, Eq. (3)) from the most recent axes.
class InsertionPointTracker {
 public:
  /// kHeld: the axis passes through the located point but would narrow the axes' angular spread
  /// until the point is no longer located (an instrument held still): not accumulated, the point
  /// held where the earlier, diverse views put it.
  enum class Update { kBuffered, kAccepted, kRejected, kReinitialised, kFrozen, kInvalid, kHeld };

  explicit InsertionPointTracker(InsertionPointTrackerOptions const& options = {});

  /// Feeds one axis (camera frame), its covariance (zero: default_axis_sigma is assumed) and the
  /// time it was seen (s, any origin, non-decreasing; NaN: assumed_axis_interval after the last).
  Update update(PluckerLine const& axis, AxisCovariance const& covariance = AxisCovariance::Zero(),
                double stamp = std::numeric_limits<double>::quiet_NaN());
  /// Seeds the tracker from a batch of axes (robust Eq. (3), then reweighted on the inliers);
  /// covariances and stamps as in update(), either may be empty.
  bool initialise(std::vector<PluckerLine> const& axes, std::vector<AxisCovariance> const& covariances = {},
                  std::vector<double> const& stamps = {});

  bool initialized() const { return initialized_; }
  /// The current estimate; status kTooFewAxes until initialised.
  InsertionPointEstimate const& estimate() const { return estimate_; }
  /// Distance of an axis to the current estimate (metres); +inf when not initialised.
  double distanceTo(PluckerLine const& axis) const;
  /// Distance an axis of this point is expected to stay within (metres): gate_sigmas times the
  /// combined spread of the axes (rms, the axis's own uncertainty) and of the estimate across
  /// the axis, clamped to [gate_distance, gate_max].
  double gate(PluckerLine const& axis, AxisCovariance const& covariance = AxisCovariance::Zero()) const;
  /// True when initialised with enough views and angular spread: the point's image and the
  /// attachment of axes to it can be relied on.
  bool wellConditioned() const;
  /// True when well conditioned and the covariance's longest axis is at most max_sigma: the
  /// position itself can be relied on (a frame to pivot an instrument about). Along the mean
  /// axis the position is fixed only as the axes' spread grows; meanwhile it is not located.
  bool located() const;
  /// True while the last consistent axes were held (Update::kHeld) rather than accumulated.
  bool held() const { return held_; }

  void reset();
  void setFrozen(bool frozen) { frozen_ = frozen; }
  bool frozen() const { return frozen_; }
  /// New thresholds (live tuning); the accumulated estimate is kept.
  void setOptions(InsertionPointTrackerOptions const& options);
  std::size_t rejected() const { return rejected_; }
  InsertionPointTrackerOptions const& options() const { return options_; }

 private:
  Eigen::Matrix3d residualCovariance(PluckerLine const& axis, AxisCovariance const& cov, Eigen::Vector3d const& x) const;
  void accumulate(AxisObservation const& o, Eigen::Vector3d const& at);
  void clearSums();
  void solve();
  Eigen::Matrix3d clusterCovariance(Eigen::Matrix3d const& Sinv, Eigen::Vector4d const& xt, double* blocks) const;
  bool initialiseFrom(std::vector<AxisObservation> const& obs);
  /// The recursive sums and the estimate, kept to undo an update that is held.
  struct State {
    Eigen::Matrix4d Bw, Bu, open_M;
    Eigen::Matrix<double, 12, 12> blocks_T;
    double blocks_w, blocks_w2, sw, sw2, span, last_stamp;
    std::size_t open_n, accepted;
    InsertionPointEstimate estimate;
  };
  State state() const;
  void restore(State const& s);

  InsertionPointTrackerOptions options_;
  double rho_;
  std::deque<AxisObservation> window_;
  bool initialized_ = false;
  bool frozen_ = false, held_ = false;
  Eigen::Vector3d origin_ = Eigen::Vector3d::Zero();
  Eigen::Matrix4d Bw_ = Eigen::Matrix4d::Zero();  ///< weighted normal matrix (relative to origin_)
  Eigen::Matrix4d Bu_ = Eigen::Matrix4d::Zero();  ///< unweighted
  /// Blocks of correlation_views consecutive accepted axes, in O(1): with A_b the first three rows
  /// of a completed block's weighted normal matrix (forgotten like Bw_ within it) and f_b its
  /// forgetting weight since, blocks_T_ = sum f_b^2 vec(A_b) vec(A_b)^T (vec row-major, 12), so that
  /// sum_b f_b^2 (A_b x~)(A_b x~)^T is its contraction with x~; blocks_w_ = sum f_b, blocks_w2_ =
  /// sum f_b^2 (the effective number of blocks); the open block's sum and size.
  Eigen::Matrix<double, 12, 12> blocks_T_ = Eigen::Matrix<double, 12, 12>::Zero();
  double blocks_w_ = 0.0, blocks_w2_ = 0.0;
  Eigen::Matrix4d open_M_ = Eigen::Matrix4d::Zero();
  std::size_t open_n_ = 0;
  double sw_ = 0.0, sw2_ = 0.0;
  /// Time spanned by the accepted axes, forgotten like sw_ (each interval at most a breathing
  /// cycle), and the last accepted axis's stamp.
  double span_ = 0.0, last_stamp_ = std::numeric_limits<double>::quiet_NaN();
  std::size_t accepted_ = 0, rejected_ = 0, consecutive_rejects_ = 0;
  InsertionPointEstimate estimate_;
};

struct InsertionPointSetOptions {
  int max_points = 0;                 ///< 0 = automatic (discover as many as the axes support)
  double attach_distance = 0.01;      ///< metres: Eq. (6) threshold for attaching an axis (at least;
                                      ///< widened to each tracker's gate())
  double merge_distance = 0.012;      ///< metres: two points closer than this are one (the better kept),
  double merge_sigmas = 3.0;          ///< or closer than this many sigmas of their covariances (elongated
                                      ///< along the axes while the spread is small)
  std::size_t prune_after = 250;      ///< axes fed to the set without one for a weak point: it is dropped
  std::size_t prune_max_views = 60;   ///< a point with fewer views than this is weak
  std::size_t pool_size = 400;        ///< unattached axes kept for discovering new points
  std::size_t discover_min_inliers = 15;  ///< axes agreeing on a new point before it is created
  double discover_min_spread = 0.02;  ///< rad: and their angular spread
  double discover_max_rms = 0.012;    ///< metres: and their RMS distance (the tips' region, where all
                                      ///< shafts pass within a few cm, is not a trocar)
  std::size_t discover_every = 10;    ///< try discovery every N unattached axes
  InsertionPointTrackerOptions tracker;
  /// Where an insertion point may be (camera frame); empty = anywhere. The pipeline requires it
  /// to lie outside the field of view: a trocar is in the abdominal wall, instruments enter the
  /// view from it (a cluster of axes inside the view is where the tips meet, not a trocar).
  std::function<bool(Eigen::Vector3d const&)> admissible;
};

/// Several insertion points: each new axis is attached (Eq. (6)) to the nearest tracked point
/// within its gate, or pooled; the pool is searched robustly for new points.
class InsertionPointSet {
 public:
  explicit InsertionPointSet(InsertionPointSetOptions const& options = {});
  /// Feeds one axis (its stamp as in InsertionPointTracker::update()); returns the id of the point
  /// it was attached to, or -1.
  int update(PluckerLine const& axis, AxisCovariance const& covariance = AxisCovariance::Zero(),
             double stamp = std::numeric_limits<double>::quiet_NaN());
  /// Id of the point an axis passes through (nearest within its gate), or -1; no update.
  int classify(PluckerLine const& axis, double* distance = nullptr,
               AxisCovariance const& covariance = AxisCovariance::Zero()) const;
  struct Entry {
    int id;
    InsertionPointTracker tracker;
    std::size_t last_update = 0;  ///< value of the set's axis counter when it last took an axis
  };
  std::vector<Entry> const& points() const { return points_; }
  InsertionPointTracker* find(int id);
  bool reset(int id);   ///< forget one point (it will be rediscovered); false if unknown
  void resetAll();
  bool setFrozen(int id, bool frozen);
  /// New options (live tuning) for the set and every tracked point; estimates are kept.
  void setOptions(InsertionPointSetOptions const& options);
  InsertionPointSetOptions const& options() const { return options_; }
  /// The id the next discovered point gets. Ids are never reused (a reset or a new camera does not
  /// restart them), so that a servo holding an old id never pivots about another trocar.
  int nextId() const { return next_id_; }
  void setNextId(int id) { next_id_ = std::max(next_id_, id); }

 private:
  void discover();
  void mergeDuplicates();
  void dropExplained();
  void prune();
  bool samePoint(InsertionPointEstimate const& a, InsertionPointEstimate const& b) const;
  InsertionPointSetOptions options_;
  std::size_t fed_ = 0;
  std::vector<Entry> points_;
  std::deque<AxisObservation> pool_;
  std::size_t since_discover_ = 0;
  int next_id_ = 0;
};

}  // namespace endo_guidance::geometry
