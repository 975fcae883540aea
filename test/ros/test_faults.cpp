// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// rostest (test/ros/faults.test): faults injected into the running closed loop. This node relays
// the simulated endoscope (sim_camera/*) to the pipeline (endoscope/*) and the driver's joint
// states to the servo (relayed/joint_states), and breaks them while the servo drives arm_0:
//   an image stall of 2 s, stale joint states, a 10x burst of frames, a camera mode change
//   (640x480 -> 800x600, K scaled), the vision chain's nodelet manager killed (it respawns), and
//   another camera (focal lengths +10 %).
// Each must end with a clear diagnostics message, a safe state (a zero command within the bound,
// the arm at rest, no motion on stale data or an old trocar id) and recovery without a restart.
// (A mode change may cost one stop: the first frames in the new mode can move the tip estimate
// beyond max_jump; the servo must go on within 0.5 s.)
// Measured reaction times are printed as "[ faults ]" lines (docs/reliability.md).
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Log.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <sensor_msgs/JointState.h>
#include <std_srvs/Trigger.h>
#include <tf2_eigen/tf2_eigen.h>
#include <tf2_ros/transform_listener.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <atomic>
#include <cmath>
#include <csignal>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <mutex>
#include <opencv2/imgproc.hpp>
#include <set>
#include <thread>

#include <sys/types.h>

#include <cv_bridge/cv_bridge.h>

#include "endo_guidance/InsertionPointArray.h"
#include "endo_guidance/InstrumentAxisArray.h"
#include "endo_guidance/ServoState.h"
#include "endo_guidance/ServoTarget.h"
#include "ros_test_main.h"

using namespace endo_guidance;

namespace {

std::string const kCamera = "endoscope_optical_frame";
double wall() { return ros::WallTime::now().toSec(); }

double percentile(std::vector<double> v, double p) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  return v[std::min(v.size() - 1, static_cast<std::size_t>(p * v.size()))];
}

// The relay between the simulated endoscope and the pipeline, and between the driver's joint
// states and the servo, with the faults it injects.
class Relay {
 public:
  enum class Images { kPass, kStall, kBurst };
  explicit Relay(ros::NodeHandle& nh) {
    image_pub_ = nh.advertise<sensor_msgs::Image>("endoscope/image_raw", 5);
    info_pub_ = nh.advertise<sensor_msgs::CameraInfo>("endoscope/camera_info", 5);
    joints_pub_ = nh.advertise<sensor_msgs::JointState>("relayed/joint_states", 10);
    image_sub_ = nh.subscribe("sim_camera/image_raw", 5, &Relay::imageCb, this);
    info_sub_ = nh.subscribe("sim_camera/camera_info", 5, &Relay::infoCb, this);
    joints_sub_ = nh.subscribe("joint_states", 10, &Relay::jointsCb, this);
  }
  ~Relay() { setImages(Images::kPass); }

  void setImages(Images mode) {
    {
      std::lock_guard<std::mutex> l(m_);
      mode_ = mode;
    }
    if (mode == Images::kBurst && !burst_.joinable()) burst_ = std::thread([this] { burst(); });
    if (mode != Images::kBurst && burst_.joinable()) burst_.join();
  }
  void setJointsStalled(bool on) { joints_stalled_ = on; }
  /// Image scale (a camera mode: K scaled with it) and focal-length factor (another camera).
  void setCamera(double scale, double focal) {
    std::lock_guard<std::mutex> l(m_);
    scale_ = scale, focal_ = focal;
  }
  double lastImageSent() const { return last_sent_; }
  double lastJointsSent() const { return last_joints_sent_; }
  long imagesSent() const { return sent_; }

 private:
  sensor_msgs::CameraInfo transform(sensor_msgs::CameraInfo info) const {
    double const s = scale_;
    info.width = static_cast<unsigned>(std::lround(info.width * s));
    info.height = static_cast<unsigned>(std::lround(info.height * s));
    for (int i : {0, 4}) info.K[i] *= s * focal_;
    for (int i : {2, 5}) info.K[i] = (info.K[i] + 0.5) * s - 0.5;
    for (int i : {0, 5}) info.P[i] *= s * focal_;
    for (int i : {2, 6}) info.P[i] = (info.P[i] + 0.5) * s - 0.5;
    return info;
  }
  sensor_msgs::ImagePtr transform(sensor_msgs::Image const& image) const {
    auto cv = cv_bridge::toCvCopy(image);
    if (scale_ != 1.0) cv::resize(cv->image, cv->image, cv::Size(), scale_, scale_, cv::INTER_LINEAR);
    return cv->toImageMsg();
  }
  void imageCb(sensor_msgs::Image::ConstPtr const& im) {
    std::lock_guard<std::mutex> l(m_);
    last_image_ = im;
    if (mode_ != Images::kPass || im->header.stamp <= last_stamp_) return;  // (after a burst: never back in time)
    send(*im, im->header.stamp);
  }
  // Sends one frame with the given stamp, camera_info first (the pipeline pairs them by stamp).
  // Called with m_ held.
  void send(sensor_msgs::Image const& image, ros::Time const& stamp) {
    last_stamp_ = stamp;
    auto out = transform(image);
    out->header.stamp = stamp;
    if (last_info_) {
      auto info = transform(*last_info_);
      info.header = out->header;
      info_pub_.publish(info);
    }
    image_pub_.publish(out);
    last_sent_ = wall();
    ++sent_;
  }
  void infoCb(sensor_msgs::CameraInfo::ConstPtr const& info) {
    std::lock_guard<std::mutex> l(m_);
    last_info_ = info;
  }
  void jointsCb(sensor_msgs::JointState::ConstPtr const& js) {
    if (joints_stalled_) return;
    joints_pub_.publish(js);
    last_joints_sent_ = wall();
  }
  // 10x the frame rate: the newest frame again and again, each with a new stamp.
  void burst() {
    for (;;) {
      {
        std::lock_guard<std::mutex> l(m_);
        if (mode_ != Images::kBurst) return;
        if (last_image_ && last_info_) send(*last_image_, ros::Time::now());
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(4));  // 250 Hz
    }
  }

  ros::Publisher image_pub_, info_pub_, joints_pub_;
  ros::Subscriber image_sub_, info_sub_, joints_sub_;
  std::mutex m_;
  Images mode_ = Images::kPass;
  std::thread burst_;
  sensor_msgs::Image::ConstPtr last_image_;
  sensor_msgs::CameraInfo::ConstPtr last_info_;
  ros::Time last_stamp_;
  double scale_ = 1.0, focal_ = 1.0;
  std::atomic<bool> joints_stalled_{false};
  std::atomic<double> last_joints_sent_{0.0};
  std::atomic<double> last_sent_{0.0};
  std::atomic<long> sent_{0};
};

// What the test watches: the servo's decisions, the arm, the pipeline's output and diagnostics.
struct Watch {
  std::mutex m;
  struct Decision {
    double t;
    bool commanding;  // a non-zero command (else a stop, with its reason)
    int id;
    std::string reason;
  };
  std::vector<Decision> decisions;
  std::vector<std::pair<double, bool>> arm_at_rest;  // (wall time, arm_0 at rest)
  std::vector<std::pair<double, double>> outputs;    // (wall time, latency s) of endoscope/instruments
  std::vector<std::pair<double, std::string>> diagnostics;  // (wall time, "name: message")
  InsertionPointArray::ConstPtr points;
  double points_t = 0.0;

  std::vector<std::string> unknown_parameters;  // "node: message" of the nodes' unknown-parameter warnings

  ros::Subscriber state_sub, joints_sub, out_sub, diag_sub, points_sub, log_sub;
  explicit Watch(ros::NodeHandle& nh) {
    log_sub = nh.subscribe<rosgraph_msgs::Log>("/rosout", 500, [this](rosgraph_msgs::Log::ConstPtr const& l) {
      std::lock_guard<std::mutex> lk(m);
      if (l->msg.find("unknown parameter") != std::string::npos) unknown_parameters.push_back(l->name + ": " + l->msg);
    });
    state_sub = nh.subscribe<ServoState>("visual_servo/state", 200, [this](ServoState::ConstPtr const& s) {
      std::lock_guard<std::mutex> l(m);
      decisions.push_back({wall(), s->reason.empty() && s->active, s->insertion_point_id, s->reason});
    });
    joints_sub = nh.subscribe<sensor_msgs::JointState>("joint_states", 200, [this](sensor_msgs::JointState::ConstPtr const& js) {
      std::lock_guard<std::mutex> l(m);
      arm_at_rest.emplace_back(wall(), std::abs(js->velocity.at(0)) + std::abs(js->velocity.at(1)) + std::abs(js->velocity.at(2)) < 1e-9);
    });
    out_sub = nh.subscribe<InstrumentAxisArray>("endoscope/instruments", 200, [this](InstrumentAxisArray::ConstPtr const& a) {
      std::lock_guard<std::mutex> l(m);
      outputs.emplace_back(wall(), (ros::Time::now() - a->header.stamp).toSec());
    });
    points_sub = nh.subscribe<InsertionPointArray>("endoscope/insertion_points", 5, [this](InsertionPointArray::ConstPtr const& p) {
      std::lock_guard<std::mutex> l(m);
      points = p, points_t = wall();
    });
    diag_sub = nh.subscribe<diagnostic_msgs::DiagnosticArray>("/diagnostics", 100, [this](diagnostic_msgs::DiagnosticArray::ConstPtr const& d) {
      std::lock_guard<std::mutex> l(m);
      for (auto const& s : d->status) diagnostics.emplace_back(wall(), s.name + ": " + s.message);
    });
  }
  /// First stop after t0 (wall time; NAN if none).
  double firstStop(double t0) {
    std::lock_guard<std::mutex> l(m);
    for (auto const& d : decisions)
      if (d.t > t0 && !d.commanding) return d.t;
    return NAN;
  }
  double lastCommand(double t0) {  // NAN: none after t0
    std::lock_guard<std::mutex> l(m);
    for (auto it = decisions.rbegin(); it != decisions.rend() && it->t > t0; ++it)
      if (it->commanding) return it->t;
    return NAN;
  }
  double firstCommand(double t0, int id = -1) {
    std::lock_guard<std::mutex> l(m);
    for (auto const& d : decisions)
      if (d.t > t0 && d.commanding && (id < 0 || d.id == id)) return d.t;
    return NAN;
  }
  int commandsBetween(double t0, double t1) {
    std::lock_guard<std::mutex> l(m);
    return static_cast<int>(std::count_if(decisions.begin(), decisions.end(),
                                          [&](Decision const& d) { return d.t > t0 && d.t < t1 && d.commanding; }));
  }
  /// Longest time without a non-zero command in [t0, t1] (stops in between included).
  double longestCommandGap(double t0, double t1) {
    std::lock_guard<std::mutex> l(m);
    double prev = t0, gap = 0.0;
    for (auto const& d : decisions) {
      if (d.t < t0 || d.t > t1 || !d.commanding) continue;
      gap = std::max(gap, d.t - prev);
      prev = d.t;
    }
    return std::max(gap, t1 - prev);
  }
  /// The distinct reasons of the stops in (t0, t1).
  std::string stopsBetween(double t0, double t1) {
    std::lock_guard<std::mutex> l(m);
    std::set<std::string> r;
    for (auto const& d : decisions)
      if (d.t > t0 && d.t < t1 && !d.commanding) r.insert(d.reason);
    std::string out;
    for (auto const& x : r) out += (out.empty() ? "" : "; ") + x;
    return out.empty() ? "none" : out;
  }
  std::string lastReason() {
    std::lock_guard<std::mutex> l(m);
    return decisions.empty() ? std::string("no decision") : decisions.back().reason;
  }
  double armAtRest(double t0) {
    std::lock_guard<std::mutex> l(m);
    for (auto const& [t, rest] : arm_at_rest)
      if (t > t0 && rest) return t;
    return NAN;
  }
  double lastOutputBefore(double t0) {
    std::lock_guard<std::mutex> l(m);
    double last = NAN;
    for (auto const& [t, lat] : outputs)
      if (t <= t0) last = t;
    return last;
  }
  double firstOutputAfter(double t0) {
    std::lock_guard<std::mutex> l(m);
    for (auto const& [t, lat] : outputs)
      if (t > t0) return t;
    return NAN;
  }
  std::vector<double> latencies(double t0, double t1) {
    std::lock_guard<std::mutex> l(m);
    std::vector<double> v;
    for (auto const& [t, lat] : outputs)
      if (t > t0 && t < t1) v.push_back(lat);
    return v;
  }
  /// Wall time of the first diagnostics after t0 containing `text` (NAN: none within timeout).
  double waitForDiagnostic(std::string const& text, double t0, double timeout = 5.0) {
    for (double const end = wall() + timeout; wall() < end; ros::WallDuration(0.02).sleep()) {
      std::lock_guard<std::mutex> l(m);
      for (auto const& [t, s] : diagnostics)
        if (t > t0 && s.find(text) != std::string::npos) return t;
    }
    return NAN;
  }
  /// The newest insertion points received after t0 (null if none).
  InsertionPointArray::ConstPtr lastPoints(double t0 = 0.0) {
    std::lock_guard<std::mutex> l(m);
    return points_t > t0 ? points : nullptr;
  }
};

class Faults : public ::testing::Test {
 protected:
  void SetUp() override {
    listener_ = std::make_unique<tf2_ros::TransformListener>(buffer_);
    relay_ = std::make_unique<Relay>(nh_);
    watch_ = std::make_unique<Watch>(nh_);
    target_pub_ = nh_.advertise<ServoTarget>("visual_servo/target", 2, true);
  }
  /// Waits (from now) for the three trocars located with the scripted motion over; returns the
  /// estimated id of arm_0's (the located point nearest the truth, within tolerance m), or -1.
  int locateArm0(double timeout = 60.0, double tolerance = 0.01) {
    double const t0 = wall();
    for (double const end = t0 + timeout; wall() < end; ros::WallDuration(0.2).sleep()) {
      auto const est = watch_->lastPoints(t0);
      auto const truth = ros::topic::waitForMessage<InsertionPointArray>("endoscope/truth/insertion_points", nh_, ros::Duration(1.0));
      auto const js = ros::topic::waitForMessage<sensor_msgs::JointState>("joint_states", nh_, ros::Duration(1.0));
      if (!est || !truth || truth->points.empty() || !js) continue;
      double arm1_rate = 0.0;  // the scripted surgeon is done when arm_1 stands still
      for (std::size_t i = 0; i < js->name.size() && i < js->velocity.size(); ++i)
        if (js->name[i].rfind("arm_1_", 0) == 0) arm1_rate += std::abs(js->velocity[i]);
      int located = 0, id = -1;
      double best = tolerance;
      Eigen::Vector3d const T0(truth->points[0].position.x, truth->points[0].position.y, truth->points[0].position.z);
      for (auto const& p : est->points) {
        if (!p.located) continue;
        ++located;
        double const d = (Eigen::Vector3d(p.position.x, p.position.y, p.position.z) - T0).norm();
        if (d < best) best = d, id = p.id;
      }
      if (located >= 3 && id >= 0 && arm1_rate < 1e-9) return id;
    }
    return -1;
  }
  /// A target for arm_0 through trocar id near where it is (15 mm in or out, 3 deg aside, so that
  /// it stays in view and clear of the other instruments); true once the servo commands motion.
  bool drive(int id) {
    double jaw = 0.0;
    ros::param::get("/endoscope_simulator/jaw_length", jaw);
    for (int attempt = 0; attempt < 3; ++attempt) {
      Eigen::Vector3d T, tip;
      try {
        T = tf2::transformToEigen(buffer_.lookupTransform(kCamera, "sim/trocar_0", ros::Time(0), ros::Duration(2.0))).translation();
        tip = tf2::transformToEigen(buffer_.lookupTransform(kCamera, "sim/instrument_0_tip", ros::Time(0), ros::Duration(2.0))).translation();
      } catch (tf2::TransformException const& e) {
        std::printf("[ faults ] no arm_0 tf: %s\n", e.what());
        return false;
      }
      Eigen::Vector3d const dir = (tip - T).normalized();
      double const depth = (tip - T).norm();
      Eigen::Vector3d const aside = dir.cross(Eigen::Vector3d::UnitZ()).normalized();
      flip_ = !flip_;
      Eigen::Vector3d const d2 = Eigen::AngleAxisd(flip_ ? 0.05 : -0.05, aside) * dir;
      Eigen::Vector3d const P = T + (depth + jaw + (depth < 0.14 ? 0.015 : -0.015)) * d2;
      double const t0 = wall();
      publishTipTarget(id, P);
      for (double const end = t0 + 2.0; wall() < end; ros::WallDuration(0.02).sleep())
        if (watch_->firstCommand(t0, id) > 0.0 && watch_->commandsBetween(t0, wall()) >= 5) return true;
      std::printf("[ faults ] the servo did not move to its target (attempt %d): %s\n", attempt + 1, watch_->lastReason().c_str());
    }
    return false;
  }
  /// A TIP_3D target for the instrument through trocar id, P in the camera frame.
  void publishTipTarget(int id, Eigen::Vector3d const& P) {
    ServoTarget t;
    t.header.stamp = ros::Time::now();
    t.header.frame_id = kCamera;
    t.mode = ServoTarget::TIP_3D;
    t.insertion_point_id = id;
    t.tip.x = P.x(), t.tip.y = P.y(), t.tip.z = P.z();
    target_pub_.publish(t);
  }
  /// arm_0's (pan, tilt, depth) now.
  Eigen::Vector3d arm0Joints() {
    auto const js = ros::topic::waitForMessage<sensor_msgs::JointState>("joint_states", nh_, ros::Duration(1.0));
    Eigen::Vector3d q = Eigen::Vector3d::Constant(NAN);
    static char const* const names[3] = {"arm_0_pan", "arm_0_tilt", "arm_0_insertion"};
    for (std::size_t i = 0; js && i < js->name.size() && i < js->position.size(); ++i)
      for (int j = 0; j < 3; ++j)
        if (js->name[i] == names[j]) q(j) = js->position[i];
    return q;
  }
  /// Where the scripted surgeon's run from the start takes arm_0 from q: the integral of its rates,
  /// q_j + A_j (sin(w_j D + j) - sin(j)) (MotionScript, arm 0).
  static Eigen::Vector3d afterScript(Eigen::Vector3d q) {
    std::vector<double> A{0.12, 0.12, 0.012, 0.3}, period{7.0, 5.3, 9.1, 11.0};
    double D = 20.0;
    ros::param::get("/motion_script/amplitude", A);
    ros::param::get("/motion_script/period", period);
    ros::param::get("/motion_script/duration", D);
    for (int j = 0; j < 3; ++j) q(j) += A[j] * (std::sin(2.0 * M_PI / period[j] * D + j) - std::sin(static_cast<double>(j)));
    return q;
  }
  /// Drives arm_0 (through trocar id) to the joints q and waits until it is there (or timeout):
  /// so that the scripted surgeon, run again, leaves it where it left it the first time (in view).
  bool driveToJoints(int id, Eigen::Vector3d const& q, double timeout = 6.0) {
    double jaw = 0.0;
    ros::param::get("/endoscope_simulator/jaw_length", jaw);
    Eigen::Isometry3d cT;
    try {
      cT = tf2::transformToEigen(buffer_.lookupTransform(kCamera, "sim/trocar_0", ros::Time(0), ros::Duration(2.0)));
    } catch (tf2::TransformException const&) {
      return false;
    }
    Eigen::Vector3d const dir = (Eigen::AngleAxisd(q(0), Eigen::Vector3d::UnitY()) * Eigen::AngleAxisd(q(1), Eigen::Vector3d::UnitX())) *
                                Eigen::Vector3d::UnitZ();
    Eigen::Vector3d const P = cT * ((q(2) + jaw) * dir);
    publishTipTarget(id, P);
    for (double const end = wall() + timeout; wall() < end; ros::WallDuration(0.1).sleep())
      if ((arm0Joints() - q).norm() < 0.01) return true;
    return false;
  }
  /// The pid of the vision chain's nodelet manager (-1: none, or more than one).
  static pid_t visionManagerPid() {
    FILE* const p = ::popen("pgrep -f '__name:=endo_guidance_manage[r]'", "r");
    if (!p) return -1;
    long pid = -1, n = 0;
    for (long x; std::fscanf(p, "%ld", &x) == 1; ++n) pid = x;
    ::pclose(p);
    return n == 1 ? static_cast<pid_t>(pid) : -1;
  }
  bool restartScript() {
    std_srvs::Trigger srv;
    return test::callService("motion_script/restart", srv) && srv.response.success;
  }

  ros::NodeHandle nh_;
  tf2_ros::Buffer buffer_;
  std::unique_ptr<tf2_ros::TransformListener> listener_;
  std::unique_ptr<Relay> relay_;
  std::unique_ptr<Watch> watch_;
  ros::Publisher target_pub_;
  bool flip_ = false;
};

// One control period (0.04 s) of the servo and its watchdog tick (0.01 s), with margin for a
// loaded machine: the zero command must come within two periods of the last data + a tick.
constexpr double kPeriod = 0.04, kTick = 0.01, kSlack = 0.05;

TEST_F(Faults, EachFaultEndsSafeAndRecovers) {
  int id = locateArm0();
  ASSERT_GE(id, 0) << "the pipeline did not locate the three trocars";
  std::printf("[ faults ] trocars located; arm_0's is %d\n", id);
  // Before each re-location (5, 6) arm_0 is driven to where a run of the script from there
  // leaves it where the first one did: in view, so that the servo can take it again.
  Eigen::Vector3d const after_explore = arm0Joints();
  Eigen::Vector3d const before_script = after_explore - (afterScript(after_explore) - after_explore);

  // 1. The image topic stalls for 2 s, then resumes.
  ASSERT_TRUE(drive(id)) << "the servo did not move arm_0";
  double t0 = wall();
  relay_->setImages(Relay::Images::kStall);
  ros::WallDuration(0.1).sleep();
  double const last_image = relay_->lastImageSent();
  double const stop1 = watch_->firstStop(t0);
  double const diag_servo1 = watch_->waitForDiagnostic("stopped: no camera measurement", t0);
  double const diag_seg1 = watch_->waitForDiagnostic("(stalled)", t0, 3.0);
  ros::WallDuration(std::max(0.0, t0 + 2.0 - wall())).sleep();
  double const rest1 = watch_->armAtRest(stop1);
  EXPECT_EQ(watch_->commandsBetween(stop1, wall()), 0) << "the servo moved during the stall";
  double const t_resume = wall();
  relay_->setImages(Relay::Images::kPass);
  ros::WallDuration(1.0).sleep();
  double const again1 = watch_->firstCommand(t_resume);
  std::printf("[ faults ] image stall 2 s: zero command %.0f ms after the last frame, arm at rest %.0f ms later; "
              "diagnostics: servo %.2f s, segmentation 'stalled' %.2f s; moving again %.2f s after resume\n",
              (stop1 - last_image) * 1e3, (rest1 - stop1) * 1e3, diag_servo1 - t0, diag_seg1 - t0, again1 - t_resume);
  EXPECT_LT(stop1 - last_image, 2 * kPeriod + kTick + kSlack);
  EXPECT_LT(rest1 - stop1, 0.5);
  EXPECT_FALSE(std::isnan(diag_servo1));
  EXPECT_FALSE(std::isnan(diag_seg1));
  EXPECT_LT(again1 - t_resume, 1.0);

  // 2. The robot's joint states go stale for 1 s.
  ASSERT_TRUE(drive(id));
  t0 = wall();
  relay_->setJointsStalled(true);
  ros::WallDuration(0.6).sleep();
  // Timed from the last joint state forwarded: a late-delivered one (a loaded machine) is fresh
  // on arrival, and a gap before the stall may have stopped the servo already.
  double const last_joints = relay_->lastJointsSent();
  double const last_command = watch_->lastCommand(t0);
  double const stop2 = watch_->firstStop(std::isnan(last_command) ? t0 : last_command);
  double const diag_servo2 = watch_->waitForDiagnostic("joint states", t0);
  ros::WallDuration(std::max(0.0, t0 + 1.0 - wall())).sleep();
  EXPECT_EQ(watch_->commandsBetween(stop2, wall()), 0) << "the servo moved on stale joint states";
  double const t_resume2 = wall();
  relay_->setJointsStalled(false);
  ros::WallDuration(1.0).sleep();
  double const again2 = watch_->firstCommand(t_resume2);
  std::printf("[ faults ] stale joint states: zero command %.0f ms after the last one forwarded (joint_timeout 200 ms); "
              "diagnostics %.2f s; moving again %.2f s after\n",
              (stop2 - last_joints) * 1e3, diag_servo2 - t0, again2 - t_resume2);
  std::printf("[ faults ] stops while the joint states were stale: %s\n", watch_->stopsBetween(t0, wall()).c_str());
  EXPECT_LT(stop2 - last_joints, 0.2 + kTick + kSlack);
  if (!std::isnan(last_command)) {
    EXPECT_LT(last_command - last_joints, 0.2 + kSlack) << "commanded on stale joint states";
  }
  EXPECT_FALSE(std::isnan(diag_servo2));
  EXPECT_LT(again2 - t_resume2, 1.0);

  // 3. A burst of 10x the frame rate for 2 s: bounded queues, the newest frame wins, latency recovers.
  ASSERT_TRUE(drive(id));
  ros::WallDuration(1.0).sleep();
  double const b0 = wall();
  long const sent0 = relay_->imagesSent();
  relay_->setImages(Relay::Images::kBurst);
  ros::WallDuration(2.0).sleep();
  relay_->setImages(Relay::Images::kPass);
  double const b1 = wall();
  long const burst_in = relay_->imagesSent() - sent0;
  ros::WallDuration(3.0).sleep();
  auto const before = watch_->latencies(b0 - 2.0, b0), during = watch_->latencies(b0, b1 + 0.2),
             after = watch_->latencies(b1 + 1.0, b1 + 3.0);
  double const max_during = during.empty() ? NAN : *std::max_element(during.begin(), during.end());
  std::printf("[ faults ] burst 10x for 2 s: %ld frames in, %zu processed; latency p50 %.0f ms before, at most %.0f ms during, "
              "p50 %.0f ms after\n",
              burst_in, during.size(), percentile(before, 0.5) * 1e3, max_during * 1e3, percentile(after, 0.5) * 1e3);
  EXPECT_GT(burst_in, 300);
  EXPECT_LT(max_during, 0.3) << "queues grew: latency not bounded";
  EXPECT_LT(percentile(after, 0.5), 2.0 * percentile(before, 0.5) + 0.01) << "latency did not recover";

  // 4. A new mode of the same camera (640x480 -> 800x600, K scaled): the trocars and their ids
  // are kept, and the servo goes on.
  ASSERT_TRUE(drive(id));
  t0 = wall();
  relay_->setCamera(1.25, 1.0);
  double const diag_seg4 = watch_->waitForDiagnostic("image size changed", t0);
  double const diag_ip4 = watch_->waitForDiagnostic("insertion points kept", t0);
  ros::WallDuration(std::max(0.0, t0 + 2.0 - wall())).sleep();
  auto const points4 = watch_->lastPoints();
  bool kept = false;
  for (auto const& p : points4->points) kept |= p.id == id && p.located;
  double const gap4 = watch_->longestCommandGap(t0, wall());
  std::printf("[ faults ] camera mode 640x480 -> 800x600: trocar %d %s; diagnostics: segmentation %.2f s, insertion points %.2f s; "
              "longest time without a servo command %.0f ms; stops: %s\n",
              id, kept ? "kept" : "LOST", diag_seg4 - t0, diag_ip4 - t0, gap4 * 1e3, watch_->stopsBetween(t0, wall()).c_str());
  EXPECT_TRUE(kept);
  EXPECT_FALSE(std::isnan(diag_seg4));
  EXPECT_FALSE(std::isnan(diag_ip4));
  EXPECT_LT(gap4, 0.5) << "the servo did not go on after the mode change";
  relay_->setCamera(1.0, 1.0);  // and back
  ros::WallDuration(1.0).sleep();

  // 5. The vision chain's nodelet manager killed mid-run (SIGKILL): the servo stops, the driver
  // holds, the chain respawns and re-locates the trocars (under new ids).
  EXPECT_TRUE(driveToJoints(id, before_script));
  ASSERT_TRUE(drive(id));
  // The pid is found first, so that t0 is the instant of the kill (a shell + pkill on a loaded
  // machine can take a second, during which the chain still runs).
  pid_t const manager = visionManagerPid();
  ASSERT_GT(manager, 0) << "no vision manager to kill";
  t0 = wall();
  ASSERT_EQ(::kill(manager, SIGKILL), 0) << "could not kill the vision manager (pid " << manager << ")";
  ros::WallDuration(0.5).sleep();
  double const stop5 = watch_->firstStop(t0 - 0.05);
  double const last_out = watch_->lastOutputBefore(std::isnan(stop5) ? t0 + 0.05 : stop5);  // (in flight at the kill included)
  double const rest5 = watch_->armAtRest(stop5);
  double const back5 = [&]() -> double {
    for (double const end = t0 + 30.0; wall() < end; ros::WallDuration(0.05).sleep())
      if (double const b = watch_->firstOutputAfter(t0 + 0.3); !std::isnan(b)) return b;
    return NAN;
  }();
  ASSERT_FALSE(std::isnan(back5)) << "the vision chain did not come back";
  EXPECT_TRUE(restartScript());
  int const id5 = locateArm0(60.0);
  double const relocated5 = wall();
  std::printf("[ faults ] vision manager killed: zero command %.0f ms after its last output, arm at rest %.0f ms later; chain back "
              "%.1f s after; trocars re-located %.1f s after (arm_0's: %d -> %d)\n",
              (stop5 - last_out) * 1e3, (rest5 - stop5) * 1e3, back5 - t0, relocated5 - t0, id, id5);
  EXPECT_LT(stop5 - last_out, 2 * kPeriod + kTick + kSlack);
  EXPECT_LT(rest5 - stop5, 0.5);
  EXPECT_EQ(watch_->commandsBetween(stop5, relocated5), 0) << "the servo moved before a new target";
  {
    std::lock_guard<std::mutex> l(watch_->m);  // a respawned nodelet reads its own reconfigure mirror: no false alarm
    EXPECT_TRUE(watch_->unknown_parameters.empty()) << watch_->unknown_parameters.size() << " unknown-parameter warnings, the first: "
                                                    << watch_->unknown_parameters.front();
  }
  ASSERT_GE(id5, 0) << "the trocars were not re-located";
  EXPECT_GT(id5, id) << "a trocar id was reused";
  id = id5;

  // 6. Another camera (focal lengths +10 %): the trocars are reset under new ids; the servo
  // stops at once and never moves on the old id.
  EXPECT_TRUE(driveToJoints(id, before_script));
  ASSERT_TRUE(drive(id));
  t0 = wall();
  relay_->setCamera(1.0, 1.1);
  ros::WallDuration(0.5).sleep();
  double const stop6 = watch_->firstStop(t0);
  double const diag_ip6 = watch_->waitForDiagnostic("insertion points reset", t0);
  EXPECT_TRUE(restartScript());
  int const id6 = locateArm0(60.0, 0.05);  // (the trocars are now estimated with the wrong K)
  double const relocated6 = wall();
  std::printf("[ faults ] another camera: zero command %.0f ms after; insertion points diagnostics %.2f s; re-located %.1f s after "
              "(arm_0's: %d -> %d)\n",
              (stop6 - t0) * 1e3, diag_ip6 - t0, relocated6 - t0, id, id6);
  EXPECT_LT(stop6 - t0, 0.3);
  EXPECT_FALSE(std::isnan(diag_ip6));
  EXPECT_EQ(watch_->commandsBetween(stop6, relocated6), 0) << "the servo moved on an old trocar id";
  ASSERT_GE(id6, 0);
  EXPECT_GT(id6, id);
  EXPECT_TRUE(drive(id6)) << "the servo did not move again on the new trocar";
}

}  // namespace

int main(int argc, char** argv) { return endo_guidance::test::runRosTests(argc, argv, "test_faults", 3); }
