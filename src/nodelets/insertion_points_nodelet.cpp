// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// endo_guidance/InsertionPoints: instrument axes -> insertion points (trocars), the attached
// instruments, tf <optical frame> -> trocar_<id>, rviz markers; services to reset or freeze an
// estimate. A thin adapter over geometry::InsertionPointSet.
#include <dynamic_reconfigure/server.h>
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <std_msgs/Header.h>
#include <tf2_ros/transform_broadcaster.h>
#include <visualization_msgs/MarkerArray.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <limits>
#include <map>
#include <memory>
#include <mutex>

#include "endo_guidance/FreezeInsertionPoint.h"
#include "endo_guidance/InsertionPointArray.h"
#include "endo_guidance/InsertionPointsConfig.h"
#include "endo_guidance/InstrumentAxisArray.h"
#include "endo_guidance/ResetInsertionPoint.h"
#include "endo_guidance/pipeline/pipeline.h"
#include "endo_guidance/ros/conversions.h"
#include "endo_guidance/ros/frame_monitor.h"
#include "endo_guidance/ros/markers.h"
#include "endo_guidance/ros/reconfigure.h"

namespace endo_guidance {

class InsertionPointsNodelet : public nodelet::Nodelet {
 public:
  // Callbacks first (each shutdown waits for a running one): nodelet may still run them while the
  // members they read are destroyed (TSan: the diagnostics read the reports during unload).
  ~InsertionPointsNodelet() override {
    axes_sub_.shutdown(), info_sub_.shutdown();
    monitor_.reset();
  }
  void onInit() override;

 private:
  void infoCb(sensor_msgs::CameraInfoConstPtr const& info);
  // One message's outputs, built under the lock and published after it.
  struct Outputs {
    InstrumentAxisArray::Ptr instruments{new InstrumentAxisArray};
    InsertionPointArray::Ptr points{new InsertionPointArray};
    visualization_msgs::MarkerArray::Ptr markers;  // null while nobody listens
    std::vector<geometry_msgs::TransformStamped> tfs;
    std::vector<geometry::CylinderPose> poses;  // per reported instrument: its measured axis
    std::map<int, std::vector<Eigen::Vector3d>> attached;  // trocar id -> tips (or axis points) of its shafts
  };
  void axesCb(InstrumentAxisArray::ConstPtr const& msg);
  void checkTimeJump(ros::Time stamp, std::vector<std::string>& warnings);
  void attachAxes(InstrumentAxisArray const& msg, Outputs& out);
  void setAxesThrough(std_msgs::Header const& header, Outputs& out) const;
  void reportPoints(std_msgs::Header const& header, Outputs& out) const;
  void configCb(InsertionPointsConfig& c, uint32_t level);
  bool resetSrv(ResetInsertionPoint::Request& req, ResetInsertionPoint::Response& res);
  bool freezeSrv(FreezeInsertionPoint::Request& req, FreezeInsertionPoint::Response& res);
  void diagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat);

  ros::NodeHandle nh_, pnh_;
  ros::Subscriber axes_sub_, info_sub_;
  ros::Publisher points_pub_, instruments_pub_, markers_pub_;
  ros::ServiceServer reset_srv_, freeze_srv_;
  std::unique_ptr<tf2_ros::TransformBroadcaster> tf_;
  std::unique_ptr<ros_io::FrameMonitor> monitor_;
  std::unique_ptr<dynamic_reconfigure::Server<InsertionPointsConfig>> reconfigure_;
  boost::recursive_mutex reconfigure_mutex_;

  std::mutex mutex_;  // guards everything below
  pipeline::PipelineParams params_;
  std::string frame_prefix_ = "trocar_";
  bool publish_tf_ = true, reset_on_time_jump_ = true;
  std::unique_ptr<geometry::InsertionPointSet> set_;
  sensor_msgs::CameraInfoConstPtr info_;
  std::string info_error_ = "no camera_info received yet";
  std::string pending_warning_;  // reported outside the lock (the diagnostics take it)
  int first_id_ = 0, stored_next_id_ = 0;  // ~next_id: where a restarted nodelet goes on numbering
  ros::Time last_stamp_;
  std::vector<pipeline::InsertionPointReport> last_reports_;
};

void InsertionPointsNodelet::onInit() {
  nh_ = getNodeHandle();
  pnh_ = getPrivateNodeHandle();
  pnh_.param<std::string>("frame_prefix", frame_prefix_, "trocar_");
  pnh_.param("publish_tf", publish_tf_, true);
  pnh_.param("reset_on_time_jump", reset_on_time_jump_, true);
  pnh_.param("next_id", first_id_, 0);  // left by a previous run on this master (respawn)
  first_id_ = std::max(first_id_, 0);
  stored_next_id_ = first_id_;
  try {
    for (auto const& k : ros_io::loadPipelineParams(
             pnh_, params_, {"frame_prefix", "publish_tf", "reset_on_time_jump", "expected_rate", "next_id"}))
      if (!ros_io::isReconfigureMirror<InsertionPointsConfig>(k)) NODELET_WARN_STREAM("unknown parameter '" << k << "' ignored");
  } catch (std::exception const& e) {
    NODELET_ERROR_STREAM("bad parameters, using the defaults: " << e.what());
    params_ = pipeline::PipelineParams{};
  }
  double expected_rate = 0.0;
  pnh_.param("expected_rate", expected_rate, 0.0);
  monitor_ = std::make_unique<ros_io::FrameMonitor>(nh_, pnh_, "insertion_points", expected_rate);
  monitor_->setExtra([this](diagnostic_updater::DiagnosticStatusWrapper& s) { diagnostics(s); });
  tf_ = std::make_unique<tf2_ros::TransformBroadcaster>();

  reconfigure_ = std::make_unique<dynamic_reconfigure::Server<InsertionPointsConfig>>(reconfigure_mutex_, pnh_);
  InsertionPointsConfig c = InsertionPointsConfig::__getDefault__();  // (every field set, groups included)
  ros_io::toReconfigure(params_, io::Live::kInsertionPoints, c);
  reconfigure_->updateConfig(c);
  reconfigure_->setCallback([this](InsertionPointsConfig& cfg, uint32_t level) { configCb(cfg, level); });

  points_pub_ = nh_.advertise<InsertionPointArray>("insertion_points", 5);
  instruments_pub_ = nh_.advertise<InstrumentAxisArray>("instruments", 5);
  markers_pub_ = nh_.advertise<visualization_msgs::MarkerArray>("trocar_markers", 2);
  reset_srv_ = pnh_.advertiseService("reset", &InsertionPointsNodelet::resetSrv, this);
  freeze_srv_ = pnh_.advertiseService("freeze", &InsertionPointsNodelet::freezeSrv, this);
  info_sub_ = nh_.subscribe("camera_info", 2, &InsertionPointsNodelet::infoCb, this);
  axes_sub_ = nh_.subscribe("axes", 10, &InsertionPointsNodelet::axesCb, this);
}

void InsertionPointsNodelet::configCb(InsertionPointsConfig& c, uint32_t) {
  std::lock_guard<std::mutex> lock(mutex_);
  ros_io::fromReconfigure(c, io::Live::kInsertionPoints, params_);
  if (set_) set_->setOptions(params_.insertion_points);
}

void InsertionPointsNodelet::infoCb(sensor_msgs::CameraInfoConstPtr const& info) {
  std::lock_guard<std::mutex> lock(mutex_);
  info_error_ = ros_io::validateCameraInfo(*info);
  if (!info_error_.empty()) return;
  bool const changed = !info_ || info_->width != info->width || info_->height != info->height || info_->K != info->K ||
                       info_->P != info->P;
  sensor_msgs::CameraInfoConstPtr const old = info_;
  info_ = info;
  if (!changed) return;
  auto const options = pipeline::outOfViewOptions(params_.insertion_points, ros_io::rectifiedK(*info),
                                              cv::Size(static_cast<int>(info->width), static_cast<int>(info->height)));
  std::string const mode = std::to_string(info->width) + "x" + std::to_string(info->height);
  if (set_ && old && ros_io::sameCameraScale(*old, *info)) {
    // Another mode of the same camera: the trocars (camera frame) hold; only the view moved.
    set_->setOptions(options);
    pending_warning_ = "camera mode changed to " + mode + " (same camera, K scaled): insertion points kept";
    return;
  }
  int const next_id = set_ ? set_->nextId() : first_id_;
  set_ = std::make_unique<geometry::InsertionPointSet>(options);
  set_->setNextId(next_id);  // ids are never reused: a servo on an old id must not pivot about a new trocar
  if (old) pending_warning_ = "camera_info changed (another camera, " + mode + "): insertion points reset, new ids from " +
                              std::to_string(next_id);
}

void InsertionPointsNodelet::axesCb(InstrumentAxisArray::ConstPtr const& msg) {
  monitor_->received();
  auto const t0 = std::chrono::steady_clock::now();
  std::unique_lock<std::mutex> lock(mutex_);
  if (!set_) {
    lock.unlock();
    return monitor_->rejected(info_error_.empty() ? "no camera_info received yet" : info_error_);
  }
  std::vector<std::string> warnings;
  if (!pending_warning_.empty()) warnings.push_back(std::move(pending_warning_)), pending_warning_.clear();
  checkTimeJump(msg->header.stamp, warnings);
  Outputs out;
  out.instruments->header = out.points->header = msg->header;
  if (markers_pub_.getNumSubscribers() > 0) {
    out.markers.reset(new visualization_msgs::MarkerArray);
    out.markers->markers.push_back(ros_io::deleteAll(msg->header));
  }
  attachAxes(*msg, out);
  last_reports_ = pipeline::reportInsertionPoints(*set_, ros_io::rectifiedK(*info_));
  setAxesThrough(msg->header, out);
  reportPoints(msg->header, out);
  int const next_id = set_->nextId();
  bool const store_id = next_id != stored_next_id_;
  stored_next_id_ = next_id;
  lock.unlock();
  if (store_id) pnh_.setParam("next_id", next_id);  // only when a point is discovered
  for (auto const& w : warnings) monitor_->warn(w);
  if (publish_tf_ && !out.tfs.empty()) tf_->sendTransform(out.tfs);
  points_pub_.publish(out.points);
  instruments_pub_.publish(out.instruments);
  if (out.markers) markers_pub_.publish(out.markers);
  monitor_->processed(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count(), msg->header.stamp);
}

// A looped bag: stamps going back reset the points (new ids), unless told not to.
void InsertionPointsNodelet::checkTimeJump(ros::Time stamp, std::vector<std::string>& warnings) {
  if (!last_stamp_.isZero() && stamp < last_stamp_) {
    char b[64];
    std::snprintf(b, sizeof b, "%.2f", (last_stamp_ - stamp).toSec());
    if (reset_on_time_jump_) set_->resetAll();
    warnings.push_back(std::string("time went backwards (") + b + " s, bag loop?)" +
                       (reset_on_time_jump_ ? ": insertion points reset, new ids from " + std::to_string(set_->nextId()) : ""));
  }
  last_stamp_ = stamp;
}

// Each valid axis is attached to its insertion point (or kept unattached, or dropped).
void InsertionPointsNodelet::attachAxes(InstrumentAxisArray const& msg, Outputs& out) {
  std::vector<Eigen::Vector3d> images;
  pipeline::wellConditionedImages(*set_, ros_io::rectifiedK(*info_), &images);
  bool const established = !images.empty();
  // (an unstamped message: the tracker assumes 25 Hz; a zero stamp for every message would span no time)
  double const stamp = msg.header.stamp.isZero() ? std::numeric_limits<double>::quiet_NaN() : msg.header.stamp.toSec();
  for (auto const& a : msg.axes) {
    auto const parsed = ros_io::fromMsg(a);
    if (!parsed) {
      monitor_->rejected("invalid Pluecker axis (non-unit direction, moment not orthogonal, or non-finite)");
      continue;
    }
    geometry::CylinderPose const& pose = *parsed;
    bool keep = true;
    int const id = pipeline::attachAxis(*set_, pose, params_.reject_unattached, established, &keep, stamp);
    if (!keep) continue;
    InstrumentAxis m = a;
    m.insertion_point_id = id;
    m.through_valid = false;  // (set once this frame's reports are known; zero until then)
    m.axis_through = PluckerLine();
    m.covariance_through.fill(0.0);
    out.instruments->axes.push_back(m);
    out.poses.push_back(pose);
    if (id >= 0)
      out.attached[id].push_back(a.tip_valid ? Eigen::Vector3d(a.tip.x, a.tip.y, a.tip.z)
                                             : Eigen::Vector3d(pose.axis.direction().cross(pose.axis.moment())));
  }
}

// Each shaft attached to a located point: its axis through that point (constrained_axis.h).
void InsertionPointsNodelet::setAxesThrough(std_msgs::Header const& header, Outputs& out) const {
  for (std::size_t i = 0; i < out.instruments->axes.size(); ++i) {
    InstrumentAxis& m = out.instruments->axes[i];
    auto const f = pipeline::axisThroughInsertionPoint(out.poses[i], m.insertion_point_id, last_reports_,
                                                   params_.insertion_points.tracker.point_motion_sigma);
    if (f && ros_io::setThrough(f->pose, m) && out.markers)
      ros_io::appendThroughMarker(out.markers->markers, header, static_cast<int>(i), *f,
                                  m.tip_valid ? std::optional<Eigen::Vector3d>(Eigen::Vector3d(m.tip.x, m.tip.y, m.tip.z)) : std::nullopt);
  }
}

// The points' message and markers, and a tf frame for each located one.
void InsertionPointsNodelet::reportPoints(std_msgs::Header const& header, Outputs& out) const {
  for (auto const& r : last_reports_) {
    InsertionPoint p;
    if (!ros_io::toMsg(r, p)) continue;
    out.points->points.push_back(p);
    if (out.markers) ros_io::appendTrocarMarkers(out.markers->markers, header, r, out.attached[r.id]);
    // An ill-conditioned point, or one not yet located along its axes, is not a frame to pivot
    // about: flagged, not guessed.
    if (!r.located) continue;
    geometry_msgs::TransformStamped t;
    t.header = header;  // the image's stamp and optical frame
    t.child_frame_id = frame_prefix_ + std::to_string(r.id);
    t.transform.translation.x = r.estimate.position.x();
    t.transform.translation.y = r.estimate.position.y();
    t.transform.translation.z = r.estimate.position.z();
    t.transform.rotation.w = 1.0;  // axes parallel to the optical frame
    out.tfs.push_back(t);
  }
}

bool InsertionPointsNodelet::resetSrv(ResetInsertionPoint::Request& req, ResetInsertionPoint::Response& res) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!set_) {
    res.message = "no camera_info yet: nothing to reset";
    return true;
  }
  if (req.id < 0) {
    set_->resetAll();
    res.success = true;
    res.message = "all insertion points reset";
  } else {
    res.success = set_->reset(req.id);
    res.message = res.success ? "insertion point " + std::to_string(req.id) + " reset" : "no insertion point " + std::to_string(req.id);
  }
  NODELET_INFO_STREAM(res.message);
  return true;
}

bool InsertionPointsNodelet::freezeSrv(FreezeInsertionPoint::Request& req, FreezeInsertionPoint::Response& res) {
  std::lock_guard<std::mutex> lock(mutex_);
  res.success = set_ && set_->setFrozen(req.id, req.freeze);
  res.message = res.success ? std::string(req.freeze ? "frozen " : "released ") + std::to_string(req.id)
                            : "no insertion point " + std::to_string(req.id);
  NODELET_INFO_STREAM(res.message);
  return true;
}

void InsertionPointsNodelet::diagnostics(diagnostic_updater::DiagnosticStatusWrapper& stat) {
  std::lock_guard<std::mutex> lock(mutex_);
  int well = 0, located = 0;
  for (auto const& r : last_reports_) {
    well += r.well_conditioned;
    located += r.located;
    char v[160];
    std::snprintf(v, sizeof v, "views %zu, spread %.1f deg, rms %.1f mm, longest sigma %.1f mm%s", r.estimate.views,
                  r.estimate.conditioning * 180.0 / M_PI, r.estimate.rms_distance * 1e3,
                  r.estimate.longestSigma() * 1e3, !r.well_conditioned ? " (ill-conditioned)" : r.located ? "" : " (not located yet: no frame)");
    stat.add(frame_prefix_ + std::to_string(r.id), v);
  }
  stat.add("insertion points", last_reports_.size());
  stat.add("well conditioned", well);
  stat.add("located (published on tf)", located);
  if (stat.level == diagnostic_msgs::DiagnosticStatus::OK && !last_reports_.empty() && well == 0)
    stat.mergeSummary(diagnostic_msgs::DiagnosticStatus::WARN, "no well-conditioned insertion point yet");
  else if (stat.level == diagnostic_msgs::DiagnosticStatus::OK && well > 0 && located == 0)
    stat.mergeSummary(diagnostic_msgs::DiagnosticStatus::WARN, "no insertion point located yet (none on tf for the servo)");
}

}  // namespace endo_guidance

PLUGINLIB_EXPORT_CLASS(endo_guidance::InsertionPointsNodelet, nodelet::Nodelet)
