// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/ros/conversions.h"

#include <yaml-cpp/yaml.h>

#include <algorithm>
#include <cmath>
#include <memory>
#include <image_geometry/pinhole_camera_model.h>
#include <opencv2/calib3d.hpp>

#include "endo_guidance/io/yaml_config.h"
#include "endo_guidance/perception/rectification.h"

namespace endo_guidance::ros_io {

namespace {
template <class T>
bool finite(T const& x) {
  return std::all_of(std::begin(x), std::end(x), [](double v) { return std::isfinite(v); });
}
geometry_msgs::Point point(Eigen::Vector2d const& p) {
  geometry_msgs::Point q;
  q.x = p.x();
  q.y = p.y();
  return q;
}
}  // namespace

std::string validateCameraInfo(sensor_msgs::CameraInfo const& info, int width, int height) {
  if (info.width == 0 || info.height == 0) return "camera_info has a zero image size";
  if (!finite(info.K) || !(info.K[0] > 0.0) || !(info.K[4] > 0.0))
    return "camera_info has a zero or invalid camera matrix K (uncalibrated camera?)";
  if (!finite(info.P) || (info.P[0] != 0.0 && !(info.P[5] > 0.0)) || info.P[0] < 0.0)
    return "camera_info has an invalid projection matrix P";
  // Pinhole form (sensor_msgs/CameraInfo): K = [fx s cx; 0 fy cy; 0 0 1], P likewise when set,
  // focal lengths of at most 1e6 px (the inverse is used on every pixel).
  auto pinhole = [](double fx, double fy, double l0, double l1, double l2, double w) {
    return fx <= 1e6 && fy <= 1e6 && fx >= 1e-3 && fy >= 1e-3 && l0 == 0.0 && l1 == 0.0 && l2 == 0.0 && w == 1.0;
  };
  if (!pinhole(info.K[0], info.K[4], info.K[3], info.K[6], info.K[7], info.K[8]))
    return "camera_info's K is not a pinhole camera matrix ([fx s cx; 0 fy cy; 0 0 1], focal lengths in [1e-3, 1e6] px)";
  if (info.P[0] > 0.0 && !pinhole(info.P[0], info.P[5], info.P[4], info.P[8], info.P[9], info.P[10]))
    return "camera_info's P is not a pinhole projection matrix ([fx' s cx' tx; 0 fy' cy' ty; 0 0 1 0])";
  if (!finite(info.D)) return "camera_info has non-finite distortion coefficients";
  if (hasDistortion(info) && info.distortion_model != "plumb_bob" && info.distortion_model != "rational_polynomial")
    return "camera_info distortion model '" + info.distortion_model + "' is not supported";
  if (width > 0 && height > 0 && (static_cast<int>(info.width) != width || static_cast<int>(info.height) != height))
    return "image size " + std::to_string(width) + "x" + std::to_string(height) + " differs from camera_info's " +
           std::to_string(info.width) + "x" + std::to_string(info.height);
  return {};
}

Eigen::Matrix3d rectifiedK(sensor_msgs::CameraInfo const& info) {
  Eigen::Matrix3d K;
  if (info.P[0] > 0.0 && info.P[5] > 0.0)
    K << info.P[0], info.P[1], info.P[2], info.P[4], info.P[5], info.P[6], info.P[8], info.P[9], info.P[10];
  else
    K << info.K[0], info.K[1], info.K[2], info.K[3], info.K[4], info.K[5], info.K[6], info.K[7], info.K[8];
  return K;
}

bool hasDistortion(sensor_msgs::CameraInfo const& info) {
  return std::any_of(info.D.begin(), info.D.end(), [](double d) { return d != 0.0; });
}

bool sameCameraScale(sensor_msgs::CameraInfo const& a, sensor_msgs::CameraInfo const& b, double tolerance) {
  if (a.width == 0 || a.height == 0 || b.width == 0 || b.height == 0) return false;
  if (a.distortion_model != b.distortion_model || a.D != b.D || a.R != b.R || a.header.frame_id != b.header.frame_id) return false;
  double const sx = static_cast<double>(b.width) / a.width, sy = static_cast<double>(b.height) / a.height;
  // One 3x3 block (row stride `stride`): focal lengths relative, principal point within tolerance x size.
  auto same = [&](double const* ka, double const* kb, int stride) {
    double const fx = ka[0] * sx, fy = ka[stride + 1] * sy;
    double const cx = (ka[2] + 0.5) * sx - 0.5, cy = (ka[stride + 2] + 0.5) * sy - 0.5;
    return std::abs(kb[0] - fx) <= tolerance * std::abs(fx) && std::abs(kb[stride + 1] - fy) <= tolerance * std::abs(fy) &&
           std::abs(kb[2] - cx) <= tolerance * b.width && std::abs(kb[stride + 2] - cy) <= tolerance * b.height &&
           std::abs(kb[1] - ka[1] * sx) <= tolerance * std::abs(fx);
  };
  bool const p_set = a.P[0] != 0.0 || b.P[0] != 0.0;
  return same(a.K.data(), b.K.data(), 3) && (!p_set || same(a.P.data(), b.P.data(), 4));
}

std::function<Eigen::Vector2d(Eigen::Vector2d const&)> rectifier(sensor_msgs::CameraInfo const& info) {
  // image_geometry holds the camera model (K, D, R, P with its defaults for unset R and P).
  image_geometry::PinholeCameraModel model;
  model.fromCameraInfo(info);
  cv::Matx34d const P = model.projectionMatrix();
  cv::Matx33d Pr(P(0, 0), P(0, 1), P(0, 2), P(1, 0), P(1, 1), P(1, 2), P(2, 0), P(2, 1), P(2, 2));
  if (!(Pr(0, 0) > 0.0 && Pr(1, 1) > 0.0)) Pr = model.intrinsicMatrix();  // P unset: the rectified camera keeps K (as rectifiedK())
  return perception::pointRectifier(model.intrinsicMatrix(), model.distortionCoeffs(), model.rotationMatrix(), Pr,
                                    cv::Size(static_cast<int>(info.width), static_cast<int>(info.height)));
}

bool toMsg(geometry::ApparentContour const& c, endo_guidance::ApparentContour& m) {
  for (int s = 0; s < 2; ++s) {
    if (!c.lines[s].allFinite() || !c.line_covariances[s].allFinite() || !std::isfinite(c.line_residual_px[s])) return false;
    m.lines[s].a = c.lines[s].x();
    m.lines[s].b = c.lines[s].y();
    m.lines[s].c = c.lines[s].z();
    Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(m.lines[s].covariance.data()) = c.line_covariances[s];
    m.line_residual_px[s] = c.line_residual_px[s];
  }
  if (!c.entry_px.allFinite() || !c.tip_px.allFinite() || !std::isfinite(c.residual_px)) return false;
  m.residual_px = c.residual_px;
  m.entry_px = point(c.entry_px);
  m.tip_px = point(c.tip_px);
  m.insertion_point_id = c.insertion_point_id;
  m.track_id = c.track_id;
  return true;
}

geometry::ApparentContour fromMsg(endo_guidance::ApparentContour const& m) {
  geometry::ApparentContour c;
  for (int s = 0; s < 2; ++s) {
    c.lines[s] = Eigen::Vector3d(m.lines[s].a, m.lines[s].b, m.lines[s].c);
    c.line_covariances[s] = Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor> const>(m.lines[s].covariance.data());
    c.line_residual_px[s] = m.line_residual_px[s];
  }
  c.residual_px = m.residual_px;
  c.entry_px = {m.entry_px.x, m.entry_px.y};
  c.tip_px = {m.tip_px.x, m.tip_px.y};
  c.insertion_point_id = m.insertion_point_id;
  c.track_id = m.track_id;
  return c;
}

namespace {
// A finite axis and its covariance into a PluckerLine message and a row-major 6x6 array.
bool axisToMsg(geometry::CylinderPose const& pose, endo_guidance::PluckerLine& line, boost::array<double, 36>& covariance) {
  Eigen::Vector3d const& d = pose.axis.direction();
  Eigen::Vector3d const& mo = pose.axis.moment();
  if (!d.allFinite() || !mo.allFinite() || !pose.covariance.allFinite()) return false;
  line.direction.x = d.x();
  line.direction.y = d.y();
  line.direction.z = d.z();
  line.moment.x = mo.x();
  line.moment.y = mo.y();
  line.moment.z = mo.z();
  Eigen::Map<Eigen::Matrix<double, 6, 6, Eigen::RowMajor>>(covariance.data()) = pose.covariance;
  return true;
}
}  // namespace

bool toMsg(geometry::CylinderPose const& pose, double radius, double residual_px, std::optional<Eigen::Vector3d> const& tip,
           endo_guidance::InstrumentAxis& m) {
  if (!std::isfinite(radius) || !std::isfinite(residual_px) || !axisToMsg(pose, m.axis, m.covariance)) return false;
  m.radius = radius;
  m.residual_px = residual_px;
  m.tip_valid = tip && tip->allFinite();
  if (m.tip_valid) {
    m.tip.x = tip->x();
    m.tip.y = tip->y();
    m.tip.z = tip->z();
  }
  return true;
}

bool setThrough(geometry::CylinderPose const& through, endo_guidance::InstrumentAxis& m) {
  endo_guidance::PluckerLine line;
  boost::array<double, 36> covariance{};
  m.through_valid = axisToMsg(through, line, covariance);
  if (m.through_valid) {
    m.axis_through = line;
    m.covariance_through = covariance;
  }
  return m.through_valid;
}

namespace {
// axisToMsg() back: nullopt unless the direction is unit, the moment orthogonal to it and both finite.
std::optional<geometry::CylinderPose> axisFromMsg(endo_guidance::PluckerLine const& line, boost::array<double, 36> const& covariance) {
  Eigen::Vector3d const d(line.direction.x, line.direction.y, line.direction.z);
  Eigen::Vector3d const mo(line.moment.x, line.moment.y, line.moment.z);
  if (!d.allFinite() || !mo.allFinite() || std::abs(d.norm() - 1.0) > 1e-6 || std::abs(d.dot(mo)) > 1e-6 * (1.0 + mo.norm()))
    return std::nullopt;
  auto const axis = geometry::PluckerLine::fromDirectionMoment(d, mo);
  if (!axis) return std::nullopt;
  geometry::CylinderPose p;
  p.axis = *axis;
  p.covariance = Eigen::Map<Eigen::Matrix<double, 6, 6, Eigen::RowMajor> const>(covariance.data());
  p.distance = p.axis.moment().norm();
  if (!p.covariance.allFinite()) p.covariance.setZero();
  return p;
}
}  // namespace

std::optional<geometry::CylinderPose> fromMsg(endo_guidance::InstrumentAxis const& m) { return axisFromMsg(m.axis, m.covariance); }

std::optional<geometry::CylinderPose> throughFromMsg(endo_guidance::InstrumentAxis const& m) {
  if (!m.through_valid) return std::nullopt;
  return axisFromMsg(m.axis_through, m.covariance_through);
}

bool toMsg(pipeline::InsertionPointReport const& r, endo_guidance::InsertionPoint& m) {
  auto const& e = r.estimate;
  if (!e.position.allFinite() || !e.covariance.allFinite() || !r.image_point.allFinite() || !std::isfinite(e.rms_distance) ||
      !std::isfinite(e.conditioning))
    return false;
  m.id = r.id;
  m.position.x = e.position.x();
  m.position.y = e.position.y();
  m.position.z = e.position.z();
  Eigen::Map<Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(m.covariance.data()) = e.covariance;
  for (int i = 0; i < 3; ++i) m.image_point[i] = r.image_point[i];
  m.views = static_cast<std::uint32_t>(e.views);
  m.rms_distance = e.rms_distance;
  m.conditioning = e.conditioning;
  m.well_conditioned = r.well_conditioned;
  m.located = r.located;
  return true;
}

namespace {
YAML::Node toYaml(XmlRpc::XmlRpcValue& v) {
  switch (v.getType()) {
    case XmlRpc::XmlRpcValue::TypeBoolean: return YAML::Node(static_cast<bool>(v));
    case XmlRpc::XmlRpcValue::TypeInt: return YAML::Node(static_cast<int>(v));
    case XmlRpc::XmlRpcValue::TypeDouble: return YAML::Node(static_cast<double>(v));
    case XmlRpc::XmlRpcValue::TypeString: return YAML::Node(static_cast<std::string>(v));
    case XmlRpc::XmlRpcValue::TypeArray: {
      YAML::Node n(YAML::NodeType::Sequence);
      for (int i = 0; i < v.size(); ++i) n.push_back(toYaml(v[i]));
      return n;
    }
    case XmlRpc::XmlRpcValue::TypeStruct: {
      YAML::Node n(YAML::NodeType::Map);
      for (auto& kv : v) n[kv.first] = toYaml(kv.second);
      return n;
    }
    default: return YAML::Node();
  }
}
}  // namespace

std::vector<std::string> loadPipelineParams(ros::NodeHandle const& nh, pipeline::PipelineParams& params,
                                            std::vector<std::string> const& own) {
  XmlRpc::XmlRpcValue all;
  if (!nh.getParam(nh.getNamespace(), all) || all.getType() != XmlRpc::XmlRpcValue::TypeStruct) return {};
  YAML::Node root(YAML::NodeType::Map);
  for (auto& kv : all)
    if (std::find(own.begin(), own.end(), kv.first) == own.end()) root[kv.first] = toYaml(kv.second);
  return io::applyPipelineParams(root, params);
}

}  // namespace endo_guidance::ros_io
