// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// rostest: the three nodelets in one manager (test/ros/pipeline.test) fed with a rendered
// synthetic surgery whose geometry is exactly known. Frames are published in lock step (the
// next one after the previous one's insertion points came back), so no frame is dropped and the
// result does not depend on the machine's speed.
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_msgs/DiagnosticArray.h>
#include <dynamic_reconfigure/Reconfigure.h>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <sensor_msgs/CompressedImage.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <tf2_ros/transform_listener.h>
#include <visualization_msgs/MarkerArray.h>

#include <algorithm>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <mutex>

#include "endo_guidance/ApparentContourArray.h"
#include "endo_guidance/FreezeInsertionPoint.h"
#include "endo_guidance/InsertionPointArray.h"
#include "endo_guidance/InstrumentAxisArray.h"
#include "endo_guidance/ResetInsertionPoint.h"
#include "endo_guidance/ros/conversions.h"
#include "endo_guidance/sim/scene_renderer.h"
#include "endo_guidance/sim/synthetic_scene.h"
#include "ros_test_main.h"

using namespace endo_guidance;

namespace {

std::string const kFrame = "endoscope_optical_frame";

template <class M>
struct Latest {
  std::mutex m;
  typename M::ConstPtr msg;
  int count = 0;
  void cb(typename M::ConstPtr const& x) {
    std::lock_guard<std::mutex> l(m);
    msg = x;
    ++count;
  }
  typename M::ConstPtr get() {
    std::lock_guard<std::mutex> l(m);
    return msg;
  }
};

using endo_guidance::test::callService;

bool finite(std::initializer_list<double> v) {
  for (double x : v)
    if (!std::isfinite(x)) return false;
  return true;
}

/// Distance (px) of a reported contour to the nearest true shaft: the largest distance of its
/// lines to the ends of the true lines (at the true entry and tip).
double nearestTruthPx(endo_guidance::ApparentContour const& m, std::vector<sim::SyntheticView> const& views) {
  double best = 1e9;
  for (auto const& v : views) {
    double e = 0.0;
    for (int s = 0; s < 2; ++s)
      for (auto const& q : {v.truth.entry_px, v.truth.tip_px}) {
        Eigen::Vector2d const f = geometry::footOnLine(v.truth.lines[s], q);
        e = std::max(e, std::abs(m.lines[s].a * f.x() + m.lines[s].b * f.y() + m.lines[s].c));
      }
    best = std::min(best, e);
  }
  return best;
}

class Graph : public ::testing::Test {
 protected:
  void SetUp() override {
    ros::NodeHandle("~").param("compressed", compressed_, false);
    image_pub_ = nh_.advertise<sensor_msgs::Image>("endoscope/image_raw", 5);
    compressed_pub_ = nh_.advertise<sensor_msgs::CompressedImage>("endoscope/image_raw/compressed", 5);
    info_pub_ = nh_.advertise<sensor_msgs::CameraInfo>("endoscope/camera_info", 5);
    subs_.push_back(nh_.subscribe("endoscope/contours", 50, &Latest<ApparentContourArray>::cb, &contours_));
    subs_.push_back(nh_.subscribe("endoscope/axes", 50, &Latest<InstrumentAxisArray>::cb, &axes_));
    subs_.push_back(nh_.subscribe("endoscope/insertion_points", 50, &Latest<InsertionPointArray>::cb, &points_));
    subs_.push_back(nh_.subscribe("/diagnostics", 50, &Graph::diagCb, this));
    subs_.push_back(nh_.subscribe("endoscope/instruments", 50, &Latest<InstrumentAxisArray>::cb, &instruments_));
    subs_.push_back(nh_.subscribe("endoscope/trocar_markers", 50, &Latest<visualization_msgs::MarkerArray>::cb, &trocar_markers_));
    for (int i = 0; i < 100 && ((!compressed_ && image_pub_.getNumSubscribers() == 0) || info_pub_.getNumSubscribers() == 0 ||
                                points_sub_ready() == false);
         ++i)
      ros::WallDuration(0.05).sleep();
    for (int i = 0; i < 100 && compressed_ && compressed_pub_.getNumSubscribers() == 0; ++i) ros::WallDuration(0.05).sleep();
    ASSERT_GT(compressed_ ? compressed_pub_.getNumSubscribers() : image_pub_.getNumSubscribers(), 0u)
        << "the Segmentation nodelet did not subscribe to the camera";
  }
  /// Shuts the subscriptions down before the members their callbacks write are destroyed
  /// (shutdown() waits for a callback already running).
  void TearDown() override {
    for (auto& s : subs_) s.shutdown();
  }
  bool points_sub_ready() { return subs_[2].getNumPublishers() > 0 && subs_[0].getNumPublishers() > 0; }
  void diagCb(diagnostic_msgs::DiagnosticArray::ConstPtr const& d) {
    std::lock_guard<std::mutex> l(diag_mutex_);
    for (auto const& s : d->status) {
      diag_text_ += s.name + ": " + s.message + ";";
      for (auto const& kv : s.values) diag_text_ += " " + kv.key + "=" + kv.value;
      diag_text_ += "\n";
    }
  }
  /// Waits (wall time) until some diagnostics text contains `what`.
  bool diagnosticsSay(std::string const& what, double timeout = 4.0) {
    for (ros::WallTime t0 = ros::WallTime::now(); (ros::WallTime::now() - t0).toSec() < timeout; ros::WallDuration(0.05).sleep()) {
      std::lock_guard<std::mutex> l(diag_mutex_);
      if (diag_text_.find(what) != std::string::npos) return true;
    }
    return false;
  }
  sensor_msgs::CameraInfo info(ros::Time const& t) const {
    sensor_msgs::CameraInfo c;
    c.header.stamp = t;
    c.header.frame_id = kFrame;
    c.width = 640;
    c.height = 480;
    c.distortion_model = "plumb_bob";
    c.D.assign(5, 0.0);
    for (int i = 0; i < 9; ++i) c.K[i] = so_.K(i / 3, i % 3);
    c.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
    for (int i = 0; i < 12; ++i) c.P[i] = (i % 4 == 3) ? 0.0 : so_.K(i / 4, i % 4);
    return c;
  }
  /// Publishes one frame and waits until the insertion points of its stamp come back.
  bool publish(cv::Mat const& bgr, ros::Time const& t, sensor_msgs::CameraInfo const* ci = nullptr, std::string const& enc = "bgr8") {
    cv_bridge::CvImage img;
    img.header.stamp = t;
    img.header.frame_id = kFrame;
    img.encoding = enc;
    img.image = bgr;
    sensor_msgs::CompressedImage c;
    if (compressed_) {  // as compressed_image_transport publishes it
      c.header = img.header;
      c.format = "bgr8; jpeg compressed bgr8";
      cv::imencode(".jpg", bgr, c.data, {cv::IMWRITE_JPEG_QUALITY, 95});
    }
    auto send = [&] {
      info_pub_.publish(ci ? *ci : info(t));
      if (compressed_)
        compressed_pub_.publish(c);
      else
        image_pub_.publish(img.toImageMsg());
    };
    send();
    // On a loaded machine the very first pair can be lost while connections settle: one resend.
    bool resent = false;
    for (ros::WallTime t0 = ros::WallTime::now(); (ros::WallTime::now() - t0).toSec() < 4.0; ros::WallDuration(0.001).sleep()) {
      if (!resent && (ros::WallTime::now() - t0).toSec() > 2.0) {
        send();
        resent = true;
      }
      auto const p = points_.get();
      auto const a = axes_.get();
      auto const c = contours_.get();
      auto const i = instruments_.get();
      if (p && p->header.stamp == t && a && a->header.stamp == t && c && c->header.stamp == t && i && i->header.stamp == t)
        return true;
    }
    return false;
  }

  ros::NodeHandle nh_;
  sim::SyntheticSceneOptions so_;
  ros::Publisher image_pub_, info_pub_, compressed_pub_;
  bool compressed_ = false;
  Latest<ApparentContourArray> contours_;
  Latest<InstrumentAxisArray> axes_;
  Latest<InsertionPointArray> points_;
  Latest<InstrumentAxisArray> instruments_;
  Latest<visualization_msgs::MarkerArray> trocar_markers_;
  std::mutex diag_mutex_;
  std::string diag_text_;
  // Last, so destroyed first: the spinner threads keep delivering (diagnostics, late results)
  // until the subscriptions are shut down, and a callback must never write into a destroyed
  // member (it aborted the test with "double free or corruption" at the end of a test).
  std::vector<ros::Subscriber> subs_;
};

using sim::SceneRenderer;
using sim::SyntheticScene;
using sim::defaultInstruments;

TEST_F(Graph, ContoursAxesTrocarsAndTfMatchTheTruth) {
  SyntheticScene scene(defaultInstruments(), so_);
  SceneRenderer renderer(so_.width, so_.height);
  tf2_ros::Buffer buffer;
  tf2_ros::TransformListener listener(buffer);
  int const frames = 220;
  int matched_contours = 0, all_contours = 0, truth_views = 0, axes_seen = 0;
  std::size_t last_shafts = 0;
  double worst_axis_deg = 0.0;
  std::vector<double> axis_errors;
  std::vector<double> through_errors, through_measured;  // the same instruments' direction errors, through the trocar and alone
  for (int k = 0; k < frames; ++k) {
    ros::Time const t(100.0 + k * 0.04);
    auto const views = scene.frame(k);
    ASSERT_TRUE(publish(renderer.render(views, k), t)) << "frame " << k << " got no insertion points back";
    auto const c = contours_.get();
    auto const a = axes_.get();
    ASSERT_TRUE(c && c->header.stamp == t && c->header.frame_id == kFrame);
    ASSERT_TRUE(a && a->header.stamp == t);
    last_shafts = c->contours.size();
    // Every reported contour is one of the true shafts (lines within 1.5 px at the ends).
    for (auto const& m : c->contours) {
      ASSERT_TRUE(finite({m.lines[0].a, m.lines[0].b, m.lines[0].c, m.lines[1].a, m.lines[1].b, m.lines[1].c, m.residual_px}));
      bool const ok = nearestTruthPx(m, views) < 1.5;
      matched_contours += ok;
      ++all_contours;
    }
    truth_views += static_cast<int>(views.size());
    // Every axis is finite; once the trocars are known, every reported instrument (attached to
    // a trocar) is close to a true axis.
    for (auto const& m : a->axes)
      ASSERT_TRUE(finite({m.axis.direction.x, m.axis.direction.y, m.axis.direction.z, m.axis.moment.x, m.axis.moment.y, m.axis.moment.z}));
    auto const inst = instruments_.get();
    ASSERT_TRUE(inst && inst->header.stamp == t);
    if (k < 120) continue;
    for (auto const& m : inst->axes) {
      ASSERT_TRUE(finite({m.axis.direction.x, m.axis.direction.y, m.axis.direction.z, m.axis.moment.x, m.axis.moment.y, m.axis.moment.z}));
      for (double x : m.covariance) ASSERT_TRUE(std::isfinite(x));
      Eigen::Vector3d const d(m.axis.direction.x, m.axis.direction.y, m.axis.direction.z);
      double best = 180.0;
      for (auto const& v : views) best = std::min(best, std::acos(std::min(1.0, d.dot(v.axis.direction()))) * 180.0 / M_PI);
      worst_axis_deg = std::max(worst_axis_deg, best);
      axis_errors.push_back(best);
      ++axes_seen;
      // The axis through its insertion point: given for a shaft attached to a located point, and
      // closer to the true axis of the same shaft (the nearest one to the measured direction).
      bool located_point = false;
      if (auto const pts = points_.get())
        for (auto const& q : pts->points) located_point = located_point || (q.id == m.insertion_point_id && q.located);
      EXPECT_EQ(m.through_valid, located_point) << "frame " << k;
      if (!m.through_valid) continue;
      ASSERT_TRUE(finite({m.axis_through.direction.x, m.axis_through.direction.y, m.axis_through.direction.z,
                          m.axis_through.moment.x, m.axis_through.moment.y, m.axis_through.moment.z}));
      for (double x : m.covariance_through) ASSERT_TRUE(std::isfinite(x));
      Eigen::Vector3d const dt(m.axis_through.direction.x, m.axis_through.direction.y, m.axis_through.direction.z);
      geometry::PluckerLine const* truth = nullptr;
      for (auto const& v : views)
        if (!truth || d.dot(v.axis.direction()) > d.dot(truth->direction())) truth = &v.axis;
      through_errors.push_back(std::acos(std::min(1.0, dt.dot(truth->direction()))) * 180.0 / M_PI);
      through_measured.push_back(std::acos(std::min(1.0, d.dot(truth->direction()))) * 180.0 / M_PI);
    }
  }
  std::printf("[ graph ] %d of %d contours on a true shaft (%d true views); %d late instruments, worst direction error %.2f deg\n",
              matched_contours, all_contours, truth_views, axes_seen, worst_axis_deg);
  EXPECT_GT(matched_contours, truth_views * 6 / 10);
  EXPECT_GE(matched_contours, all_contours * 9 / 10);  // raw contours: few false ones (they are filtered below)
  EXPECT_GT(axes_seen, 100);
  std::sort(axis_errors.begin(), axis_errors.end());
  ASSERT_FALSE(axis_errors.empty());
  double const p95 = axis_errors[axis_errors.size() * 95 / 100];
  std::printf("[ graph ] instrument direction error p95 %.2f deg\n", p95);
  EXPECT_LT(p95, compressed_ ? 5.0 : 2.0);
  EXPECT_LT(worst_axis_deg, compressed_ ? 10.0 : 3.0);  // JPEG (q95) blurs a short shaft's edges
  ASSERT_GT(through_errors.size(), 50u);
  auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + static_cast<long>(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  std::printf("[ graph ] through the insertion point: %zu instruments, direction error median %.3f deg (alone %.3f deg)\n",
              through_errors.size(), median(through_errors), median(through_measured));
  EXPECT_LT(median(through_errors), median(through_measured));
  auto const p = points_.get();
  ASSERT_TRUE(p);
  int well = 0, located = 0;
  for (auto const& q : p->points) {
    ASSERT_TRUE(finite({q.position.x, q.position.y, q.position.z, q.image_point[0], q.image_point[1], q.image_point[2]}));
    ASSERT_TRUE(std::all_of(q.covariance.begin(), q.covariance.end(), [](double c) { return std::isfinite(c); }));
    well += q.well_conditioned;
    located += q.located;
    EXPECT_TRUE(q.well_conditioned || !q.located);  // located implies well conditioned
  }
  EXPECT_EQ(well, 3);
  EXPECT_EQ(located, 3);
  // tf: optical frame -> trocar_<id> (located points only) at the last image stamp, each within 3
  // mm of a true trocar.
  int found = 0;
  for (auto const& q : p->points) {
    if (!q.located) continue;
    geometry_msgs::TransformStamped tr;
    ASSERT_NO_THROW(tr = buffer.lookupTransform(kFrame, "trocar_" + std::to_string(q.id), p->header.stamp, ros::Duration(1.0)));
    Eigen::Vector3d const X(tr.transform.translation.x, tr.transform.translation.y, tr.transform.translation.z);
    double best = 1e9;
    for (std::size_t i = 0; i < scene.size(); ++i) best = std::min(best, (X - scene.meanTrocar(static_cast<int>(i))).norm());
    std::printf("[ graph ] tf %s -> trocar_%d: %.2f mm from the true trocar\n", kFrame.c_str(), q.id, best * 1e3);
    EXPECT_LT(best, 0.003);
    found += best < 0.003;
  }
  EXPECT_EQ(found, 3);
  // The segmentation's diagnostics: the last frame's shafts and the strip searches per frame.
  EXPECT_TRUE(diagnosticsSay("shafts (last frame)=" + std::to_string(last_shafts)));
  EXPECT_TRUE(diagnosticsSay("strip searches per frame="));
  // rviz: the last frame's trocar markers draw one "axes_through" line per instrument given its
  // axis through a located trocar, on that axis.
  auto const inst = instruments_.get();
  ASSERT_TRUE(inst);
  visualization_msgs::MarkerArray::ConstPtr mk;
  for (int i = 0; i < 100 && !(mk && mk->markers.size() > 0 && mk->markers[0].header.stamp == inst->header.stamp); ++i) {
    mk = trocar_markers_.get();
    ros::WallDuration(0.01).sleep();
  }
  ASSERT_TRUE(mk && !mk->markers.empty() && mk->markers[0].header.stamp == inst->header.stamp) << "no trocar markers for the last frame";
  int through = 0, drawn = 0;
  for (auto const& m : inst->axes) through += m.through_valid;
  for (auto const& m : mk->markers) {
    if (m.ns != "axes_through") continue;
    ++drawn;
    ASSERT_EQ(m.points.size(), 2u);
    ASSERT_GE(m.id, 0);
    ASSERT_LT(static_cast<std::size_t>(m.id), inst->axes.size());
    auto const& a = inst->axes[static_cast<std::size_t>(m.id)];
    ASSERT_TRUE(a.through_valid);
    auto const through = ros_io::throughFromMsg(a);
    ASSERT_TRUE(through);
    for (auto const& q : m.points) EXPECT_LT(through->axis.distanceTo(Eigen::Vector3d(q.x, q.y, q.z)), 1e-6);
  }
  EXPECT_GT(through, 0);
  EXPECT_EQ(drawn, through);
}

TEST_F(Graph, BadInputsAreReportedSkippedAndTheNodeKeepsRunning) {
  SyntheticScene scene(defaultInstruments(), so_);
  SceneRenderer renderer(so_.width, so_.height);
  cv::Mat const good = renderer.render(scene.frame(10), 10);
  double t = 500.0;
  auto next = [&t] { return ros::Time(t += 0.04); };
  ASSERT_TRUE(publish(good, next()));
  int const before = contours_.count;

  // Wrong encoding: nothing published for it, a clear error on /diagnostics.
  cv::Mat grey;
  cv::cvtColor(good, grey, cv::COLOR_BGR2GRAY);
  EXPECT_FALSE(publish(grey, next(), nullptr, "mono8"));
  EXPECT_TRUE(diagnosticsSay("is not 8-bit colour"));
  // Image size differs from camera_info.
  cv::Mat small;
  cv::resize(good, small, {320, 240});
  EXPECT_FALSE(publish(small, next()));
  EXPECT_TRUE(diagnosticsSay("differs from camera_info"));
  // All-zero K (an uncalibrated camera).
  ros::Time tz = next();
  sensor_msgs::CameraInfo zero = info(tz);
  zero.K.fill(0.0);
  zero.P.fill(0.0);
  EXPECT_FALSE(publish(good, tz, &zero));
  EXPECT_TRUE(diagnosticsSay("zero or invalid camera matrix K"));
  EXPECT_EQ(contours_.count, before) << "a bad frame produced output";
  // Missing camera_info: images alone never pair.
  for (int i = 0; i < 45; ++i) {
    cv_bridge::CvImage img(std_msgs::Header(), "bgr8", good);
    img.header.stamp = next();
    img.header.frame_id = kFrame;
    image_pub_.publish(img.toImageMsg());
    ros::WallDuration(0.1).sleep();
  }
  EXPECT_TRUE(diagnosticsSay("is camera_info published"));
  // Time going backwards (a bag loop): reported, state reset, frames still processed.
  ASSERT_TRUE(publish(good, next()));
  EXPECT_TRUE(publish(good, ros::Time(10.0)));
  EXPECT_TRUE(diagnosticsSay("time went backwards"));
  // A non-finite axis straight into InsertionPoints: rejected, never published.
  ros::Publisher axes_pub = nh_.advertise<InstrumentAxisArray>("endoscope/axes", 2);
  for (int i = 0; i < 40 && axes_pub.getNumSubscribers() == 0; ++i) ros::WallDuration(0.05).sleep();
  InstrumentAxisArray bad;
  bad.header.stamp = ros::Time(11.0);
  bad.header.frame_id = kFrame;
  bad.axes.resize(1);
  bad.axes[0].axis.direction.x = std::nan("");
  bad.axes[0].axis.direction.z = 1.0;
  bool said = false;
  for (int i = 0; i < 3 && !said; ++i) {
    axes_pub.publish(bad);
    said = diagnosticsSay("invalid Pluecker axis", 1.5);
  }
  EXPECT_TRUE(said);
  // Still running: a good frame gives contours again.
  int const c0 = contours_.count;
  EXPECT_TRUE(publish(good, ros::Time(12.0)));
  EXPECT_GT(contours_.count, c0);
  auto const c = contours_.get();
  ASSERT_TRUE(c);
  EXPECT_GE(c->contours.size(), 1u);
}


namespace {
// Sets a parameter of `node`'s dynamic_reconfigure server, in the config's list `list` (ints,
// doubles); the value it reports back (-1: the call failed or the parameter is not in its config).
template <typename Param>
double setParameter(std::string const& node, std::string const& name, double value,
                    std::vector<Param> dynamic_reconfigure::Config::*list) {
  dynamic_reconfigure::Reconfigure srv;
  Param p;
  p.name = name;
  p.value = static_cast<decltype(p.value)>(value);
  (srv.request.config.*list).push_back(p);
  if (!callService(node + "/set_parameters", srv)) return -1.0;
  for (auto const& q : srv.response.config.*list)
    if (q.name == name) return q.value;
  return -1.0;
}
}  // namespace

// Runtime tuning: a minimum shaft length longer than the view finds no shaft (the contour fit
// checks it, whichever detector proposes); restored, the shafts come back.
TEST_F(Graph, DynamicReconfigureChangesTheSegmentation) {
  SyntheticScene scene(defaultInstruments(), so_);
  SceneRenderer renderer(so_.width, so_.height);
  cv::Mat const good = renderer.render(scene.frame(30), 30);
  auto set = [](double length) {
    return setParameter("endoscope/segmentation", "min_length_px", length, &dynamic_reconfigure::Config::doubles) == length;
  };
  ASSERT_TRUE(ros::service::waitForService("endoscope/segmentation/set_parameters", 5000));
  ASSERT_TRUE(publish(good, ros::Time(2000.0)));
  ASSERT_GE(contours_.get()->contours.size(), 1u);
  ASSERT_TRUE(set(2000.0));
  ASSERT_TRUE(publish(good, ros::Time(2000.04)));
  EXPECT_EQ(contours_.get()->contours.size(), 0u);
  ASSERT_TRUE(set(30.0));
  ASSERT_TRUE(publish(good, ros::Time(2000.08)));
  EXPECT_GE(contours_.get()->contours.size(), 1u);
}

// The breathing period (over which a trocar's own motion is shared by the axes) is tunable at run
// time, as the ventilator's rate is per patient: the server takes it and reports it back.
TEST_F(Graph, DynamicReconfigureTakesTheBreathingPeriod) {
  ASSERT_TRUE(ros::service::waitForService("endoscope/insertion_points/set_parameters", 5000));
  auto set = [](double period) {
    return setParameter("endoscope/insertion_points", "breathing_period", period, &dynamic_reconfigure::Config::doubles);
  };
  EXPECT_EQ(set(5.5), 5.5);
  EXPECT_EQ(set(0.0), 0.0);
  EXPECT_EQ(set(4.0), 4.0);
}

// A live threshold is tunable at run time within its table range (out-of-range values are
// clamped to it), and the server starts from the loaded value, not a .cfg default.
TEST_F(Graph, DynamicReconfigureTakesTheGlareFraction) {
  ASSERT_TRUE(ros::service::waitForService("endoscope/segmentation/set_parameters", 5000));
  dynamic_reconfigure::Reconfigure current;  // (an empty request reports the current values)
  ASSERT_TRUE(callService("endoscope/segmentation/set_parameters", current));
  double start = -1.0;
  for (auto const& q : current.response.config.doubles)
    if (q.name == "max_glare_fraction") start = q.value;
  EXPECT_EQ(start, 0.6);  // pipeline.test's value (the default: 0.5)
  auto set = [](double fraction) {
    return setParameter("endoscope/segmentation", "max_glare_fraction", fraction, &dynamic_reconfigure::Config::doubles);
  };
  EXPECT_EQ(set(0.3), 0.3);
  EXPECT_EQ(set(-3.0), 0.0);
  EXPECT_EQ(set(0.6), 0.6);
}

// Services: freeze keeps a trocar where it is; reset forgets them.
TEST_F(Graph, ResetAndFreezeServices) {
  SyntheticScene scene(defaultInstruments(), so_);
  SceneRenderer renderer(so_.width, so_.height);
  double t = 3000.0;
  for (int k = 0; k < 150; ++k) ASSERT_TRUE(publish(renderer.render(scene.frame(k), k), ros::Time(t += 0.04)));
  auto p = points_.get();
  ASSERT_GE(p->points.size(), 1u);
  int const id = p->points.front().id;
  FreezeInsertionPoint fz;
  fz.request.id = id;
  fz.request.freeze = true;
  ASSERT_TRUE(callService("endoscope/insertion_points/freeze", fz));
  EXPECT_TRUE(fz.response.success) << fz.response.message;
  geometry_msgs::Point const frozen = p->points.front().position;
  for (int k = 150; k < 200; ++k) ASSERT_TRUE(publish(renderer.render(scene.frame(k), k), ros::Time(t += 0.04)));
  for (auto const& q : points_.get()->points) {
    if (q.id == id) {
      EXPECT_TRUE(q.position.x == frozen.x && q.position.y == frozen.y && q.position.z == frozen.z);
    }
  }
  fz.request.id = 9999;
  ASSERT_TRUE(callService("endoscope/insertion_points/freeze", fz));
  EXPECT_FALSE(fz.response.success);
  ResetInsertionPoint rs;
  rs.request.id = -1;
  ASSERT_TRUE(callService("endoscope/insertion_points/reset", rs));
  EXPECT_TRUE(rs.response.success);
  ASSERT_TRUE(publish(renderer.render(scene.frame(200), 200), ros::Time(t += 0.04)));
  EXPECT_EQ(points_.get()->points.size(), 0u);
}

// A distorted lens: the camera_info carries plumb_bob coefficients, the images are distorted;
// the contours must be the straight lines of the rectified camera (the edge points are
// undistorted, not the image).
TEST_F(Graph, DistortedImagesGiveRectifiedContours) {
  SyntheticScene scene(defaultInstruments(), so_);
  SceneRenderer renderer(so_.width, so_.height);
  cv::Matx33d const K(so_.K(0, 0), 0, so_.K(0, 2), 0, so_.K(1, 1), so_.K(1, 2), 0, 0, 1);
  std::vector<double> const D{-0.2, 0.05, 0.0, 0.0, 0.0};
  // For each distorted pixel, where it comes from in the ideal (rectified) image.
  std::vector<cv::Point2f> grid, ideal;
  for (int v = 0; v < so_.height; ++v)
    for (int u = 0; u < so_.width; ++u) grid.emplace_back(static_cast<float>(u), static_cast<float>(v));
  cv::undistortPoints(grid, ideal, K, D, cv::noArray(), K, cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 30, 1e-6));
  cv::Mat map(so_.height, so_.width, CV_32FC2, ideal.data());
  double t = 4000.0;
  int checked = 0, within = 0, false_lines = 0;
  double worst_truth = 0.0;
  for (int k = 0; k < 60; ++k) {
    auto const views = scene.frame(k);
    cv::Mat distorted;
    cv::remap(renderer.render(views, k), distorted, map, cv::noArray(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0, 0, 0));
    ros::Time const st(t += 0.04);
    sensor_msgs::CameraInfo ci = info(st);
    ci.D = D;
    ASSERT_TRUE(publish(distorted, st, &ci));
    for (auto const& m : contours_.get()->contours) {
      double const best = nearestTruthPx(m, views);
      ++checked;
      if (best < 1.5) {
        ++within;
        worst_truth = std::max(worst_truth, best);
      } else {
        ++false_lines;
      }
    }
  }
  std::printf("[ distorted ] %d contours, %d within 1.5 px of the rectified truth (worst %.2f px)\n", checked, within, worst_truth);
  EXPECT_GT(checked, 60);
  EXPECT_GE(within, checked * 9 / 10);
}
}  // namespace

int main(int argc, char** argv) { return endo_guidance::test::runRosTests(argc, argv, "test_pipeline_graph", 2); }
