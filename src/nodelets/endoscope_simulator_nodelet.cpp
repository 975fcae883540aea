// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// endo_guidance/EndoscopeSimulator: a stationary endoscope looking at the instruments of the
// RcmDriver. Renders (core SceneRenderer, the one of the tests and bags) the shafts whose poses
// it reads on tf (base -> <prefix>trocar_k, <prefix>instrument_k_tip), and publishes image_raw +
// camera_info (optional lens distortion) and the ground truth: truth/axes, truth/insertion_points
// (optical frame), truth/camera_pose (in the base). The camera pose in the base is a parameter
// the vision nodes never see.
#include <boost/make_shared.hpp>
#include <geometry_msgs/PoseStamped.h>
#include <image_transport/image_transport.h>
#include <nodelet/nodelet.h>
#include <pluginlib/class_list_macros.hpp>
#include <ros/ros.h>
#include <std_srvs/SetBool.h>
#include <tf2_eigen/tf2_eigen.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/static_transform_broadcaster.h>
#include <tf2_ros/transform_listener.h>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include <atomic>
#include <memory>

#include "endo_guidance/InsertionPointArray.h"
#include "endo_guidance/InstrumentAxisArray.h"
#include "endo_guidance/ros/conversions.h"
#include "endo_guidance/sim/scene_renderer.h"
#include "endo_guidance/sim/synthetic_scene.h"

namespace endo_guidance {

class EndoscopeSimulatorNodelet : public nodelet::Nodelet {
 public:
  void onInit() override;

 private:
  bool loadCamera(sim::RenderOptions& ro);
  void advertise();
  void tick(ros::WallTimerEvent const&);
  sensor_msgs::ImagePtr frameMessage();

  ros::NodeHandle nh_, pnh_;
  std::unique_ptr<image_transport::ImageTransport> it_;
  image_transport::CameraPublisher camera_pub_;
  ros::Publisher truth_axes_pub_, truth_points_pub_, truth_pose_pub_;
  std::unique_ptr<tf2_ros::Buffer> buffer_;
  std::unique_ptr<tf2_ros::TransformListener> listener_;
  std::unique_ptr<tf2_ros::StaticTransformBroadcaster> static_tf_;
  ros::WallTimer timer_;
  ros::ServiceServer occlude_srv_;
  std::atomic<bool> occluded_{false};  // e.g. smoke or a fogged lens: no instrument is drawn
  sensor_msgs::CameraInfo info_;
  Eigen::Matrix3d K_;
  Eigen::Isometry3d base_to_camera_ = Eigen::Isometry3d::Identity();
  std::unique_ptr<sim::SceneRenderer> renderer_;
  cv::Mat distortion_map_;
  // Frame messages, reused once nobody else holds one (an intra-process subscriber keeps a
  // reference; remote ones are served a copy serialised at publish), and the renderer's working
  // images: a stream allocates no frame-sized block per frame (the soak's memory, reliability.md).
  std::vector<sensor_msgs::ImagePtr> frames_;
  cv::Mat scratch_, rendered_;
  std::vector<std::string> arms_;
  std::string prefix_, base_frame_, camera_frame_;
  double rate_ = 25.0, radius_ = 0.004, jaw_length_ = 0.012, breathing_amplitude_ = 0.0, breathing_period_ = 4.0;
  Eigen::Vector3d breathing_direction_ = Eigen::Vector3d(0.2, -1.0, 0.3).normalized();
  int frame_ = 0;
  ros::WallTime start_;
};

void EndoscopeSimulatorNodelet::onInit() {
  nh_ = getNodeHandle();
  pnh_ = getPrivateNodeHandle();
  sim::RenderOptions ro;
  if (!loadCamera(ro)) return;
  renderer_ = std::make_unique<sim::SceneRenderer>(static_cast<int>(info_.width), static_cast<int>(info_.height), ro);
  advertise();
  start_ = ros::WallTime::now();
  timer_ = nh_.createWallTimer(ros::WallDuration(1.0 / rate_), &EndoscopeSimulatorNodelet::tick, this);
  NODELET_INFO_STREAM("EndoscopeSimulator: " << info_.width << "x" << info_.height << " at " << rate_ << " Hz, " << arms_.size()
                                             << " arm(s)");
}

// The camera, the scene's options and the lens distortion's map from the parameters; false
// (reported) when they are invalid.
bool EndoscopeSimulatorNodelet::loadCamera(sim::RenderOptions& ro) {
  int width = 640, height = 480;
  double fx = 500, fy = 500, cx = -1, cy = -1;
  pnh_.param("width", width, 640);
  pnh_.param("height", height, 480);
  pnh_.param("rate", rate_, 25.0);
  pnh_.param("fx", fx, 500.0);
  pnh_.param("fy", fy, 500.0);
  pnh_.param("cx", cx, (width - 1) / 2.0);
  pnh_.param("cy", cy, (height - 1) / 2.0);
  pnh_.param("radius", radius_, 0.004);
  pnh_.param("jaw_length", jaw_length_, 0.012);
  pnh_.param("breathing_amplitude", breathing_amplitude_, 0.0);
  pnh_.param("breathing_period", breathing_period_, 4.0);
  pnh_.param<std::string>("frame_prefix", prefix_, "");
  pnh_.param<std::string>("base_frame", base_frame_, "robot_base");
  pnh_.param<std::string>("camera_frame", camera_frame_, "endoscope_optical_frame");
  std::vector<double> D, xyz{0, 0, 0}, rpy{0, 0, 0};
  pnh_.param("distortion", D, std::vector<double>(5, 0.0));
  pnh_.param("camera_xyz", xyz, xyz);
  pnh_.param("camera_rpy", rpy, rpy);
  pnh_.param("arms", arms_, std::vector<std::string>{"arm_0"});
  pnh_.param("black_shafts", ro.black_shafts, false);
  pnh_.param("circular_fov", ro.circular_fov, false);
  pnh_.param("gauze", ro.gauze, false);
  pnh_.param("noise_sigma", ro.noise_sigma, 0.0);
  pnh_.param("jpeg_quality", ro.jpeg_quality, 0);
  if (width < 64 || height < 48 || !(rate_ > 0.0) || !(fx > 0.0) || !(fy > 0.0) || !(radius_ > 0.0) || xyz.size() != 3 ||
      rpy.size() != 3 || D.size() != 5) {
    NODELET_FATAL("EndoscopeSimulator: bad parameters (size >= 64x48, rate, fx, fy, radius > 0, camera_xyz/rpy of 3, distortion of 5)");
    return false;
  }
  K_ << fx, 0, cx, 0, fy, cy, 0, 0, 1;
  base_to_camera_.translation() = Eigen::Vector3d(xyz[0], xyz[1], xyz[2]);
  base_to_camera_.linear() = (Eigen::AngleAxisd(rpy[2], Eigen::Vector3d::UnitZ()) * Eigen::AngleAxisd(rpy[1], Eigen::Vector3d::UnitY()) *
                              Eigen::AngleAxisd(rpy[0], Eigen::Vector3d::UnitX()))
                                 .toRotationMatrix();
  info_.header.frame_id = camera_frame_;
  info_.width = static_cast<std::uint32_t>(width);
  info_.height = static_cast<std::uint32_t>(height);
  info_.distortion_model = "plumb_bob";
  info_.D = D;
  info_.K = {fx, 0, cx, 0, fy, cy, 0, 0, 1};
  info_.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  info_.P = {fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1, 0};
  if (ros_io::hasDistortion(info_)) {
    // Each distorted pixel samples the ideal (rectified) rendering where it comes from.
    std::vector<cv::Point2f> grid, ideal;
    for (int v = 0; v < height; ++v)
      for (int u = 0; u < width; ++u) grid.emplace_back(static_cast<float>(u), static_cast<float>(v));
    cv::Matx33d const Kc(fx, 0, cx, 0, fy, cy, 0, 0, 1);
    cv::undistortPoints(grid, ideal, Kc, D, cv::noArray(), Kc, cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 30, 1e-6));
    distortion_map_ = cv::Mat(height, width, CV_32FC2, ideal.data()).clone();
  }
  return true;
}

// The camera's pose (static tf and truth), the image and truth topics, the occlusion service.
void EndoscopeSimulatorNodelet::advertise() {
  buffer_ = std::make_unique<tf2_ros::Buffer>();
  listener_ = std::make_unique<tf2_ros::TransformListener>(*buffer_, nh_);
  static_tf_ = std::make_unique<tf2_ros::StaticTransformBroadcaster>();
  auto t = tf2::eigenToTransform(base_to_camera_);
  t.header.stamp = ros::Time::now();
  t.header.frame_id = base_frame_;
  t.child_frame_id = camera_frame_;
  static_tf_->sendTransform(t);
  it_ = std::make_unique<image_transport::ImageTransport>(nh_);
  camera_pub_ = it_->advertiseCamera("image_raw", 2);
  truth_axes_pub_ = nh_.advertise<InstrumentAxisArray>("truth/axes", 5);
  truth_points_pub_ = nh_.advertise<InsertionPointArray>("truth/insertion_points", 5);
  truth_pose_pub_ = nh_.advertise<geometry_msgs::PoseStamped>("truth/camera_pose", 1, true);
  geometry_msgs::PoseStamped pose;
  pose.header = t.header;
  pose.pose = tf2::toMsg(base_to_camera_);
  truth_pose_pub_.publish(pose);
  occlude_srv_ = pnh_.advertiseService<std_srvs::SetBool::Request, std_srvs::SetBool::Response>(
      "occlude", [this](std_srvs::SetBool::Request& req, std_srvs::SetBool::Response& res) {
        occluded_ = req.data;
        res.success = true;
        res.message = req.data ? "instruments hidden" : "instruments visible";
        return true;
      });
}

void EndoscopeSimulatorNodelet::tick(ros::WallTimerEvent const&) {
  // Read once, before the stamp: a frame is drawn with all instruments or none (the flag may be
  // set while it is drawn), and one stamped after the occlude call returned has none.
  bool const occluded = occluded_;
  ros::Time const stamp = ros::Time::now();
  double const t = (ros::WallTime::now() - start_).toSec();
  Eigen::Vector3d const breathing =
      breathing_amplitude_ * std::sin(2.0 * M_PI * t / breathing_period_) * breathing_direction_;  // camera frame
  std::vector<sim::SyntheticView> views;
  InstrumentAxisArray::Ptr axes(new InstrumentAxisArray);
  InsertionPointArray::Ptr points(new InsertionPointArray);
  axes->header.stamp = points->header.stamp = stamp;
  axes->header.frame_id = points->header.frame_id = camera_frame_;
  Eigen::Isometry3d const camera_from_base = base_to_camera_.inverse();
  for (std::size_t i = 0; i < arms_.size(); ++i) {
    std::string const idx = std::to_string(i);
    Eigen::Isometry3d trocar_b, tip_b;
    try {
      trocar_b = tf2::transformToEigen(buffer_->lookupTransform(base_frame_, prefix_ + "trocar_" + idx, ros::Time(0)));
      tip_b = tf2::transformToEigen(buffer_->lookupTransform(base_frame_, prefix_ + "instrument_" + idx + "_tip", ros::Time(0)));
    } catch (tf2::TransformException const& e) {
      ROS_WARN_STREAM_THROTTLE(5.0, "EndoscopeSimulator: no pose of " << arms_[i] << " yet: " << e.what());
      continue;
    }
    Eigen::Vector3d const trocar_c = camera_from_base * trocar_b.translation() + breathing;
    Eigen::Vector3d const tip_c = camera_from_base * tip_b.translation() + breathing;
    pipeline::InsertionPointReport r;
    r.id = static_cast<int>(i);
    r.estimate.status = geometry::InsertionPointStatus::kOk;
    r.estimate.position = trocar_c;
    r.image_point = K_ * trocar_c;
    r.well_conditioned = true;
    r.located = true;  // the truth
    InsertionPoint p;
    if (ros_io::toMsg(r, p)) points->points.push_back(p);
    auto const view = sim::viewOfInstrument(K_, static_cast<int>(info_.width), static_cast<int>(info_.height), trocar_c, tip_c,
                                             radius_, static_cast<int>(i), jaw_length_);
    if (!view) continue;  // tip out of view
    if (!occluded) views.push_back(*view);
    geometry::CylinderPose pose;
    pose.axis = view->axis;
    pose.distance = view->axis.distanceToOrigin();
    InstrumentAxis a;
    // The visible tip: the end of the jaws, jaw_length beyond the shaft's end (the driver's tip frame).
    Eigen::Vector3d const jaw_end = tip_c + jaw_length_ * view->axis.direction();
    if (ros_io::toMsg(pose, radius_, 0.0, jaw_end, a)) {
      a.insertion_point_id = static_cast<int>(i);
      a.track_id = static_cast<int>(i);
      axes->axes.push_back(a);
    }
  }
  sensor_msgs::ImagePtr const msg = frameMessage();
  msg->header.stamp = stamp;
  msg->header.frame_id = camera_frame_;
  msg->header.seq = static_cast<std::uint32_t>(frame_);
  msg->height = info_.height;
  msg->width = info_.width;
  msg->encoding = "bgr8";
  msg->is_bigendian = 0;
  msg->step = info_.width * 3;
  msg->data.resize(static_cast<std::size_t>(msg->step) * msg->height);
  cv::Mat out(static_cast<int>(msg->height), static_cast<int>(msg->width), CV_8UC3, msg->data.data(), msg->step);
  if (distortion_map_.empty()) {
    renderer_->render(views, frame_, out, scratch_);
  } else {
    renderer_->render(views, frame_, rendered_, scratch_);
    cv::remap(rendered_, out, distortion_map_, cv::noArray(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0, 0, 0));
  }
  ++frame_;
  sensor_msgs::CameraInfoPtr info(new sensor_msgs::CameraInfo(info_));
  info->header.stamp = stamp;
  camera_pub_.publish(msg, info);
  truth_axes_pub_.publish(axes);
  truth_points_pub_.publish(points);
}

sensor_msgs::ImagePtr EndoscopeSimulatorNodelet::frameMessage() {
  for (auto const& m : frames_)
    if (m.use_count() == 1) return m;
  auto m = boost::make_shared<sensor_msgs::Image>();
  if (frames_.size() < 8) frames_.push_back(m);  // (more held at once: a slow subscriber's queue; not pooled)
  return m;
}

}  // namespace endo_guidance

PLUGINLIB_EXPORT_CLASS(endo_guidance::EndoscopeSimulatorNodelet, nodelet::Nodelet)
