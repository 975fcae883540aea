// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/geometry/insertion_point_tracker.h"

#include <Eigen/Eigenvalues>
#include <Eigen/LU>
#include <algorithm>
#include <cmath>
#include <limits>

#include "endo_guidance/geometry/classification.h"

namespace endo_guidance::geometry {

InsertionPointTracker::InsertionPointTracker(InsertionPointTrackerOptions const& o)
    : options_(o), rho_(std::exp(-1.0 / std::max(1.0, o.memory_views))) {}

void InsertionPointTracker::clearSums() {
  Bw_.setZero();
  Bu_.setZero();
  sw_ = sw2_ = 0.0;
  accepted_ = consecutive_rejects_ = 0;
  blocks_T_.setZero();
  blocks_w_ = blocks_w2_ = 0.0;
  open_M_.setZero();
  open_n_ = 0;
  span_ = 0.0;
  last_stamp_ = std::numeric_limits<double>::quiet_NaN();
}

void InsertionPointTracker::reset() {
  window_.clear();
  initialized_ = false;
  clearSums();
  rejected_ = 0;
  held_ = false;
  estimate_ = InsertionPointEstimate{};
}

double InsertionPointTracker::distanceTo(PluckerLine const& axis) const {
  if (!initialized_ || !estimate_.ok()) return std::numeric_limits<double>::infinity();
  return axis.distanceTo(estimate_.position);
}

Eigen::Matrix3d InsertionPointTracker::residualCovariance(PluckerLine const& axis, AxisCovariance const& cov,
                                                          Eigen::Vector3d const& x) const {
  Eigen::Vector3d const& d = axis.direction();
  Eigen::Matrix3d const P = Eigen::Matrix3d::Identity() - d * d.transpose();
  double const b2 = options_.point_motion_sigma * options_.point_motion_sigma;  // the trocar's own motion
  if (cov.isZero(0.0) || !cov.allFinite()) {
    double const s = options_.default_axis_sigma;
    return (0.5 * s * s + b2) * P;  // s^2 in all, split over the two directions across the axis
  }
  // r = d x x + m:  dr/dd = -[x]x, dr/dm = I.
  Eigen::Matrix<double, 3, 6> J;
  J.leftCols<3>() = -skew(x);
  J.rightCols<3>().setIdentity();
  return P * (J * cov * J.transpose() + b2 * Eigen::Matrix3d::Identity()) * P;
}

double InsertionPointTracker::gate(PluckerLine const& axis, AxisCovariance const& cov) const {
  if (!initialized_ || !estimate_.ok()) return std::numeric_limits<double>::infinity();
  Eigen::Matrix3d const P = Eigen::Matrix3d::Identity() - axis.direction() * axis.direction().transpose();
  double const across = (P * estimate_.covariance * P).trace();  // the estimate's variance across the axis
  // The axis's own uncertainty widens the gate only up to the default gate: an axis that cannot
  // be placed within gate_distance of the point adds little to it, and a mis-segmented short shaft
  // (lines along its open jaws: 7-11 deg off, with a wide covariance) would be attached.
  double const own_max = options_.gate_distance / std::max(options_.gate_sigmas, 1e-9);
  double const own = std::min(residualCovariance(axis, cov, estimate_.position).trace(), own_max * own_max);
  double const rms2 = estimate_.rms_distance * estimate_.rms_distance;
  double const spread = std::sqrt(std::max(rms2, own) + std::max(0.0, across));
  return std::clamp(options_.gate_sigmas * spread, options_.gate_distance,
                    std::max(options_.gate_distance, options_.gate_max));
}

bool InsertionPointTracker::wellConditioned() const {
  return initialized_ && estimate_.ok() && estimate_.views >= options_.min_views &&
         estimate_.conditioning >= options_.min_conditioning;
}

bool InsertionPointTracker::located() const {
  if (!wellConditioned()) return false;
  return !(options_.max_sigma > 0.0) || estimate_.longestSigma() <= options_.max_sigma;
}

void InsertionPointTracker::accumulate(AxisObservation const& o, Eigen::Vector3d const& at) {
  Eigen::Vector3d const& d = o.axis.direction();
  Eigen::Vector3d const m = o.axis.moment() - origin_.cross(d);  // the axis relative to origin_
  Eigen::Matrix<double, 3, 4> Bk;
  Bk.leftCols<3>() = skew(d);  // first three rows of L*, Eq. (2)
  Bk.col(3) = m;
  // W = pseudo-inverse of the residual covariance on the plane across the axis.
  Eigen::Matrix3d const Sr = residualCovariance(o.axis, o.covariance, at);
  Eigen::Vector3d const e1 = d.unitOrthogonal(), e2 = d.cross(e1);
  Eigen::Matrix<double, 3, 2> E;
  E << e1, e2;
  Eigen::Matrix2d S2 = E.transpose() * Sr * E;
  S2.diagonal().array() += 1e-12;  // floor: 1 um
  Eigen::Matrix3d W = E * S2.inverse() * E.transpose();
  // Huber weight on the normalised residual at the current estimate: a wrong axis that passed
  // the gate (a mis-segmented region) pulls with a bounded force.
  if (initialized_ && estimate_.ok() && options_.huber_k > 0.0) {
    Eigen::Vector4d xt;
    xt << estimate_.position - origin_, 1.0;
    Eigen::Vector3d const r = Bk * xt;
    double const chi = std::sqrt(std::max(0.0, r.dot(W * r)));
    if (chi > options_.huber_k) W *= options_.huber_k / chi;
  }
  Eigen::Matrix4d const Mk = Bk.transpose() * W * Bk;
  Bw_ = rho_ * Bw_ + Mk;
  Bu_ = rho_ * Bu_ + Bk.transpose() * Bk;
  sw_ = rho_ * sw_ + 1.0;
  sw2_ = rho_ * rho_ * sw2_ + 1.0;
  // The time since the last accepted axis (axes of one frame share their breathing phase; a
  // pause counts as one cycle at most: the motion's phase is then independent, not averaged).
  double dt = options_.assumed_axis_interval;
  if (std::isfinite(o.stamp) && std::isfinite(last_stamp_) && o.stamp >= last_stamp_) dt = o.stamp - last_stamp_;
  if (options_.breathing_period > 0.0) dt = std::min(dt, options_.breathing_period);
  if (std::isfinite(o.stamp)) last_stamp_ = o.stamp;
  span_ = rho_ * span_ + dt;
  ++accepted_;
  if (options_.correlation_views > 0) {
    blocks_T_ *= rho_ * rho_;
    blocks_w_ *= rho_;
    blocks_w2_ *= rho_ * rho_;
    open_M_ = rho_ * open_M_ + Mk;
    if (++open_n_ >= options_.correlation_views) {
      Eigen::Matrix<double, 3, 4, Eigen::RowMajor> const A = open_M_.topRows<3>();
      Eigen::Map<Eigen::Matrix<double, 12, 1> const> const a(A.data());
      blocks_T_.noalias() += a * a.transpose();
      blocks_w_ += 1.0;
      blocks_w2_ += 1.0;
      open_M_.setZero();
      open_n_ = 0;
    }
  }
}

// The cluster-robust covariance of the estimate (see the class comment): the scatter of the
// blocks' score vectors g_b = f_b A_b x~ (the open block's too) between S^-1 on both sides, with
// the small-sample factor B / (B - 1), B the effective number of blocks (*blocks).
Eigen::Matrix3d InsertionPointTracker::clusterCovariance(Eigen::Matrix3d const& Sinv, Eigen::Vector4d const& xt,
                                                         double* blocks) const {
  Eigen::Matrix3d meat;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) meat(i, j) = xt.dot(blocks_T_.block<4, 4>(4 * i, 4 * j) * xt);
  double w = blocks_w_, w2 = blocks_w2_;
  if (open_n_ > 0) {
    Eigen::Vector3d const g = (open_M_ * xt).head<3>();
    meat += g * g.transpose();
    w += 1.0;
    w2 += 1.0;
  }
  double const nb = w2 > 0.0 ? w * w / w2 : 0.0;
  *blocks = nb;
  if (nb < 2.0) return Eigen::Matrix3d::Zero();
  return Sinv * meat * Sinv * (nb / (nb - 1.0));
}

void InsertionPointTracker::solve() {
  InsertionPointEstimate e;
  e.views = std::min<std::size_t>(accepted_, static_cast<std::size_t>(std::llround(sw_)));
  Eigen::Matrix3d const Su = Bu_.topLeftCorner<3, 3>();  // sum (I - d d^T)
  // (its eigenvector of the smallest eigenvalue: the mean axis direction, for the floor below)
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(Su / std::max(sw_, 1e-300));
  e.conditioning = std::sqrt(std::max(0.0, es.eigenvalues()(0)));
  Eigen::Matrix3d const S = Bw_.topLeftCorner<3, 3>();
  Eigen::Vector3d const b = Bw_.topRightCorner<3, 1>();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> sw(S);
  // Parallel axes: S singular (the common point is at infinity).
  if (!(sw.eigenvalues()(0) > 1e-10 * std::max(sw.eigenvalues()(2), 1e-300))) {
    e.status = InsertionPointStatus::kAtInfinity;
    estimate_ = e;
    return;
  }
  Eigen::Matrix3d const Sinv = sw.eigenvectors() * sw.eigenvalues().cwiseInverse().asDiagonal() * sw.eigenvectors().transpose();
  Eigen::Vector3d const x = -Sinv * b;  // weighted least squares with I_4 = 1
  Eigen::Vector4d xt;
  xt << x, 1.0;
  e.rms_distance = std::sqrt(std::max(0.0, xt.dot(Bu_ * xt)) / std::max(sw_, 1e-300));
  // Forgetting: cov ~ S^-1 sw2/sw; inflated by the normalised chi^2 when the axes scatter more
  // than their covariances say (breathing, model error).
  double const n_eff = sw_ * sw_ / std::max(sw2_, 1e-300);
  double const dof = std::max(1.0, 2.0 * n_eff - 3.0);
  double const chi2 = std::max(0.0, xt.dot(Bw_ * xt)) * n_eff / sw_ / dof;
  e.covariance = Sinv * (sw2_ / sw_) * std::max(1.0, chi2);
  // Consecutive axes share their errors: the covariance must cover the scatter of blocks of them
  // too (from three blocks on; it is only ever widened, in the model's shape).
  double nb = 0.0;
  Eigen::Matrix3d const Sc = options_.correlation_views > 0 ? clusterCovariance(Sinv, xt, &nb) : Eigen::Matrix3d::Zero();
  if (nb >= 3.0) {
    Eigen::GeneralizedSelfAdjointEigenSolver<Eigen::Matrix3d> ge(Sc, e.covariance, Eigen::EigenvaluesOnly);
    if (ge.info() == Eigen::Success && std::isfinite(ge.eigenvalues()(2))) e.covariance *= std::max(1.0, ge.eigenvalues()(2));
  }
  // Along the mean axis the point is fixed only through the axes' angular spread: an error
  // shared by the axes (rms across them at the point) moves it by rms / spread there, averaged
  // over the independent groups of correlation_views axes at best. Early on, the blocks above
  // cannot see errors shared by all of them (a slow sweep), which would make a point claim a
  // fraction of its error. The trocar's own motion (breathing, up to point_motion_sigma of the
  // rms) is shared for longer: by every axis of a breathing cycle, so it averages over the
  // cycles the axes span.
  if (e.conditioning > 0.0) {
    double const spread2 = e.conditioning * e.conditioning;
    double floor2 = 0.0;
    if (options_.correlation_views > 0)
      floor2 = e.rms_distance * e.rms_distance /
               (spread2 * std::max(1.0, n_eff / static_cast<double>(options_.correlation_views)));
    if (options_.breathing_period > 0.0) {
      double const cycles = std::max(1.0, n_eff * (span_ / sw_) / options_.breathing_period);
      double const motion = std::min(e.rms_distance, options_.point_motion_sigma);
      floor2 = std::max(floor2, motion * motion / (spread2 * cycles));
    }
    Eigen::Vector3d const u = es.eigenvectors().col(0);  // the least constrained direction: the mean axis
    double const along = u.dot(e.covariance * u);
    if (along < floor2) e.covariance += (floor2 - along) * u * u.transpose();
  }
  e.position = x + origin_;
  Eigen::Vector4d h;
  h << e.position, 1.0;
  h.normalize();
  if (h(2) < 0.0) h = -h;  // sign convention I_z > 0
  e.homogeneous = h;
  e.status = InsertionPointStatus::kOk;
  estimate_ = e;
}

bool InsertionPointTracker::initialiseFrom(std::vector<AxisObservation> const& obs) {
  std::vector<PluckerLine> axes;
  for (auto const& o : obs) axes.push_back(o.axis);
  InsertionPointEstimate const e = intersectAxesRobust(axes, options_.robust);  // Eq. (3), LMedS
  if (!e.ok() || e.inliers.size() < 2) return false;
  held_ = false;
  origin_ = e.position;
  Eigen::Vector3d at = e.position;
  for (int it = 0; it < std::max(1, options_.reweight_iterations); ++it) {
    clearSums();
    for (int i : e.inliers) accumulate(obs[static_cast<std::size_t>(i)], at);
    initialized_ = true;
    solve();
    if (!estimate_.ok()) break;
    at = estimate_.position;
  }
  if (!estimate_.ok()) initialized_ = false;
  return estimate_.ok();
}

bool InsertionPointTracker::initialise(std::vector<PluckerLine> const& axes, std::vector<AxisCovariance> const& covariances,
                                       std::vector<double> const& stamps) {
  std::vector<AxisObservation> obs;
  for (std::size_t i = 0; i < axes.size(); ++i)
    obs.push_back({axes[i], i < covariances.size() ? covariances[i] : AxisCovariance::Zero(),
                   i < stamps.size() ? stamps[i] : std::numeric_limits<double>::quiet_NaN()});
  return initialiseFrom(obs);
}

InsertionPointTracker::Update InsertionPointTracker::update(PluckerLine const& axis, AxisCovariance const& cov, double stamp) {
  if (!axis.direction().allFinite() || !axis.moment().allFinite() || !cov.allFinite()) return Update::kInvalid;
  if (frozen_) return Update::kFrozen;
  window_.push_back({axis, cov, stamp});
  while (window_.size() > options_.window) window_.pop_front();
  if (!initialized_) {
    if (window_.size() < options_.min_views) return Update::kBuffered;
    return initialiseFrom({window_.begin(), window_.end()}) ? Update::kAccepted : Update::kBuffered;
  }
  if (!estimate_.ok() || axis.distanceTo(estimate_.position) > gate(axis, cov)) {
    ++rejected_;
    if (++consecutive_rejects_ < options_.reinit_after) return Update::kRejected;
    // A run of outliers: the point moved (or was wrong). Re-initialise from recent axes only.
    std::size_t const recent = std::min(window_.size(), 2 * options_.reinit_after);
    return initialiseFrom({window_.end() - static_cast<long>(recent), window_.end()}) ? Update::kReinitialised
                                                                                       : Update::kRejected;
  }
  consecutive_rejects_ = 0;
  // Exponential forgetting without new angular information winds the estimate up: an instrument
  // held still replaces the diverse views that fixed its trocar by copies of one, the spread
  // shrinks and the point would stop being located although every axis passes through it. Such
  // an axis is consistent with the point and adds nothing to it: the point is held. (A point
  // that loses its location as the spread grows, or by its axes' scatter, is not held.)
  bool const was_located = located();
  State const before = was_located ? state() : State{};
  accumulate({axis, cov, stamp}, estimate_.position);
  solve();
  held_ = was_located && !located() && !(estimate_.conditioning > before.estimate.conditioning);
  if (held_) {
    restore(before);
    return Update::kHeld;
  }
  return Update::kAccepted;
}

InsertionPointTracker::State InsertionPointTracker::state() const {
  return {Bw_, Bu_, open_M_, blocks_T_, blocks_w_, blocks_w2_, sw_, sw2_, span_, last_stamp_, open_n_, accepted_, estimate_};
}

void InsertionPointTracker::restore(State const& s) {
  Bw_ = s.Bw, Bu_ = s.Bu, open_M_ = s.open_M, blocks_T_ = s.blocks_T;
  blocks_w_ = s.blocks_w, blocks_w2_ = s.blocks_w2, sw_ = s.sw, sw2_ = s.sw2, span_ = s.span, last_stamp_ = s.last_stamp;
  open_n_ = s.open_n, accepted_ = s.accepted;
  estimate_ = s.estimate;
}

// --------------------------------------------------------------------------------------------

InsertionPointSet::InsertionPointSet(InsertionPointSetOptions const& o) : options_(o) {}

void InsertionPointSet::setOptions(InsertionPointSetOptions const& o) {
  auto admissible = options_.admissible;
  options_ = o;
  if (!options_.admissible) options_.admissible = admissible;
  for (auto& p : points_) p.tracker.setOptions(o.tracker);
}

void InsertionPointTracker::setOptions(InsertionPointTrackerOptions const& o) {
  options_ = o;
  rho_ = std::exp(-1.0 / std::max(1.0, o.memory_views));
}

int InsertionPointSet::classify(PluckerLine const& axis, double* distance, AxisCovariance const& cov) const {
  // Eq. (6): the nearest point, in units of each point's own gate, if within it.
  int best = -1;
  double best_ratio = std::numeric_limits<double>::infinity(), best_d = best_ratio;
  for (auto const& p : points_) {
    if (!p.tracker.initialized() || !p.tracker.estimate().ok()) continue;
    double const dd = classifyAxis(axis, {p.tracker.estimate().position}, 1.0).distance;
    double const tau = std::max(options_.attach_distance, p.tracker.gate(axis, cov));
    if (dd / tau < best_ratio) {
      best_ratio = dd / tau;
      best_d = dd;
      best = p.id;
    }
  }
  if (distance) *distance = best_d;
  return best_ratio < 1.0 ? best : -1;
}

InsertionPointTracker* InsertionPointSet::find(int id) {
  for (auto& p : points_)
    if (p.id == id) return &p.tracker;
  return nullptr;
}

int InsertionPointSet::update(PluckerLine const& axis, AxisCovariance const& cov, double stamp) {
  if (!axis.direction().allFinite() || !axis.moment().allFinite() || !cov.allFinite()) return -1;
  ++fed_;
  prune();
  int const id = classify(axis, nullptr, cov);
  if (id >= 0) {
    for (auto& p : points_)
      if (p.id == id) {
        p.tracker.update(axis, cov, stamp);
        p.last_update = fed_;
      }
    mergeDuplicates();
    return find(id) ? id : classify(axis, nullptr, cov);  // merged away: report the survivor
  }
  pool_.push_back({axis, cov, stamp});
  while (pool_.size() > options_.pool_size) pool_.pop_front();
  if (++since_discover_ >= options_.discover_every) {
    since_discover_ = 0;
    discover();
  }
  return -1;
}

void InsertionPointSet::discover() {
  if (options_.max_points > 0 && static_cast<int>(points_.size()) >= options_.max_points) return;
  if (pool_.size() < options_.discover_min_inliers) return;
  std::vector<PluckerLine> axes;
  for (auto const& a : pool_) axes.push_back(a.axis);
  // With several unknown points in the pool, the largest cluster need not be half of it: look
  // for the best-supported point at a quantile that the smallest admissible cluster reaches.
  RobustIntersectOptions ro = options_.tracker.robust;
  ro.inlier_fraction = std::max(0.1, static_cast<double>(options_.discover_min_inliers) / axes.size());
  InsertionPointEstimate const e = intersectAxesRobust(axes, ro);
  if (!e.ok() || e.inliers.size() < options_.discover_min_inliers || e.conditioning < options_.discover_min_spread ||
      e.rms_distance > options_.discover_max_rms)
    return;
  std::vector<PluckerLine> inl;
  std::vector<AxisCovariance> cov;
  std::vector<double> stamps;
  for (int i : e.inliers) {
    AxisObservation const& a = pool_[static_cast<std::size_t>(i)];
    inl.push_back(a.axis);
    cov.push_back(a.covariance);
    stamps.push_back(a.stamp);
  }
  // A cluster at a known point is that point's (its axes strayed beyond the gate early on).
  for (auto& p : points_)
    if (p.tracker.estimate().ok() && samePoint(p.tracker.estimate(), e)) {
      for (std::size_t i = 0; i < inl.size(); ++i) p.tracker.update(inl[i], cov[i], stamps[i]);
      p.last_update = fed_;
      dropExplained();
      return;
    }
  Entry entry{next_id_, InsertionPointTracker(options_.tracker), fed_};
  if (!entry.tracker.initialise(inl, cov, stamps)) return;
  // Admissibility is judged on the covariance-weighted estimate: the plain one is biased toward
  // the image by the axes' angular noise (see InsertionPointTracker).
  if (options_.admissible && !options_.admissible(entry.tracker.estimate().position)) return;
  ++next_id_;
  points_.push_back(std::move(entry));
  dropExplained();
}

void InsertionPointSet::dropExplained() {
  std::deque<AxisObservation> rest;
  for (auto const& a : pool_)
    if (classify(a.axis, nullptr, a.covariance) < 0) rest.push_back(a);
  pool_.swap(rest);
}

void InsertionPointSet::mergeDuplicates() {
  for (std::size_t i = 0; i < points_.size(); ++i)
    for (std::size_t j = i + 1; j < points_.size(); ++j) {
      auto const& a = points_[i].tracker.estimate();
      auto const& b = points_[j].tracker.estimate();
      if (!a.ok() || !b.ok() || !samePoint(a, b)) continue;
      points_.erase(points_.begin() + static_cast<long>(a.views >= b.views ? j : i));
      mergeDuplicates();
      return;
    }
}

bool InsertionPointSet::samePoint(InsertionPointEstimate const& a, InsertionPointEstimate const& b) const {
  Eigen::Vector3d const d = a.position - b.position;
  if (d.norm() < options_.merge_distance) return true;
  Eigen::Matrix3d const S = a.covariance + b.covariance;
  Eigen::FullPivLU<Eigen::Matrix3d> lu(S);
  if (!lu.isInvertible()) return false;
  return d.dot(lu.solve(d)) < options_.merge_sigmas * options_.merge_sigmas;
}

void InsertionPointSet::prune() {
  points_.erase(std::remove_if(points_.begin(), points_.end(),
                               [&](Entry const& p) {
                                 return p.tracker.estimate().views < options_.prune_max_views &&
                                        fed_ - p.last_update > options_.prune_after;
                               }),
                points_.end());
}

bool InsertionPointSet::reset(int id) {
  for (auto it = points_.begin(); it != points_.end(); ++it)
    if (it->id == id) {
      points_.erase(it);
      return true;
    }
  return false;
}

void InsertionPointSet::resetAll() {
  points_.clear();
  pool_.clear();
  since_discover_ = 0;
}

bool InsertionPointSet::setFrozen(int id, bool frozen) {
  InsertionPointTracker* t = find(id);
  if (!t) return false;
  t->setFrozen(frozen);
  return true;
}

}  // namespace endo_guidance::geometry
