// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/ros/markers.h"

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <cmath>

namespace endo_guidance::ros_io {

namespace {
geometry_msgs::Point pt(Eigen::Vector3d const& p) {
  geometry_msgs::Point q;
  q.x = p.x();
  q.y = p.y();
  q.z = p.z();
  return q;
}
visualization_msgs::Marker base(std_msgs::Header const& header, char const* ns, int id, int type, float r, float g, float b,
                                float a) {
  visualization_msgs::Marker m;
  m.header = header;
  m.ns = ns;
  m.id = id;
  m.type = type;
  m.action = visualization_msgs::Marker::ADD;
  m.pose.orientation.w = 1.0;
  m.color.r = r;
  m.color.g = g;
  m.color.b = b;
  m.color.a = a;
  return m;
}
void setOrientation(visualization_msgs::Marker& m, Eigen::Quaterniond const& q) {
  m.pose.orientation.x = q.x();
  m.pose.orientation.y = q.y();
  m.pose.orientation.z = q.z();
  m.pose.orientation.w = q.w();
}
}  // namespace

visualization_msgs::Marker deleteAll(std_msgs::Header const& header) {
  visualization_msgs::Marker m;
  m.header = header;
  m.action = visualization_msgs::Marker::DELETEALL;
  return m;
}

void appendShaftMarkers(std::vector<visualization_msgs::Marker>& out, std_msgs::Header const& header, int index,
                        geometry::CylinderPose const& pose, double radius, std::optional<Eigen::Vector3d> const& tip, double length) {
  Eigen::Vector3d const d = pose.axis.direction();
  Eigen::Vector3d const p0 = d.cross(pose.axis.moment());  // axis point closest to the optical centre
  double const t_tip = tip ? d.dot(*tip - p0) : 0.0;
  Eigen::Vector3d const a = p0 + (t_tip - length) * d, b = p0 + t_tip * d;
  auto cyl = base(header, "shafts", index, visualization_msgs::Marker::CYLINDER, 0.6f, 0.7f, 0.8f, 0.6f);
  cyl.pose.position = pt(0.5 * (a + b));
  setOrientation(cyl, Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), d));
  cyl.scale.x = cyl.scale.y = 2.0 * radius;
  cyl.scale.z = length;
  out.push_back(cyl);
  auto arrow = base(header, "shaft_directions", index, visualization_msgs::Marker::ARROW, 1.0f, 0.8f, 0.0f, 1.0f);
  arrow.points = {pt(b - 0.03 * d), pt(b)};
  arrow.scale.x = 0.002;
  arrow.scale.y = 0.004;
  arrow.scale.z = 0.006;
  out.push_back(arrow);
  // Contour generators: in the cross-section through p0 the optical centre is at distance
  // delta = |p0| from the axis; the tangents from it touch the circle at +-acos(r / delta) from
  // the direction toward the centre.
  double const delta = p0.norm();
  if (delta > radius) {
    Eigen::Vector3d const w = -p0 / delta, v = d.cross(w);
    double const c = radius / delta, s = std::sqrt(1.0 - c * c);
    auto gen = base(header, "contour_generators", index, visualization_msgs::Marker::LINE_LIST, 0.1f, 1.0f, 0.3f, 1.0f);
    gen.scale.x = 0.0006;
    for (double sign : {-1.0, 1.0}) {
      Eigen::Vector3d const off = radius * (c * w + sign * s * v);
      gen.points.push_back(pt(a + off));
      gen.points.push_back(pt(b + off));
    }
    out.push_back(gen);
  }
}

void appendTrocarMarkers(std::vector<visualization_msgs::Marker>& out, std_msgs::Header const& header,
                         pipeline::InsertionPointReport const& point, std::vector<Eigen::Vector3d> const& attached_points) {
  Eigen::Vector3d const& X = point.estimate.position;
  // Located (published on tf): bright; well conditioned only (not yet a frame): amber; else dim.
  float const g = point.located ? 0.9f : point.well_conditioned ? 0.6f : 0.3f;
  auto sphere = base(header, "trocars", point.id, visualization_msgs::Marker::SPHERE, 1.0f, g, 0.1f, 1.0f);
  sphere.pose.position = pt(X);
  sphere.scale.x = sphere.scale.y = sphere.scale.z = 0.006;
  out.push_back(sphere);
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(point.estimate.covariance);
  if (es.info() == Eigen::Success && es.eigenvalues().minCoeff() >= 0.0) {
    auto ell = base(header, "trocar_covariances", point.id, visualization_msgs::Marker::SPHERE, 1.0f, g, 0.1f, 0.25f);
    ell.pose.position = pt(X);
    Eigen::Matrix3d R = es.eigenvectors();
    if (R.determinant() < 0) R.col(2) = -R.col(2);
    setOrientation(ell, Eigen::Quaterniond(R));
    // 3 sigma, at most 10 cm (an ill-conditioned point is elongated along the axes).
    ell.scale.x = std::min(0.1, 6.0 * std::sqrt(es.eigenvalues()(0)));
    ell.scale.y = std::min(0.1, 6.0 * std::sqrt(es.eigenvalues()(1)));
    ell.scale.z = std::min(0.1, 6.0 * std::sqrt(es.eigenvalues()(2)));
    out.push_back(ell);
  }
  auto text = base(header, "trocar_labels", point.id, visualization_msgs::Marker::TEXT_VIEW_FACING, 1.0f, 1.0f, 1.0f, 1.0f);
  text.pose.position = pt(X + Eigen::Vector3d(0, -0.01, 0));
  text.scale.z = 0.01;
  text.text = "trocar_" + std::to_string(point.id) +
              (point.located ? "" : point.well_conditioned ? " (not located yet)" : " (ill-conditioned)");
  out.push_back(text);
  if (!attached_points.empty()) {
    auto lines = base(header, "trocar_axes", point.id, visualization_msgs::Marker::LINE_LIST, 1.0f, g, 0.1f, 0.8f);
    lines.scale.x = 0.0005;
    for (auto const& q : attached_points) {
      lines.points.push_back(pt(X));
      lines.points.push_back(pt(q));
    }
    out.push_back(lines);
  }
}

void appendThroughMarker(std::vector<visualization_msgs::Marker>& out, std_msgs::Header const& header, int index,
                         geometry::ConstrainedAxis const& through, std::optional<Eigen::Vector3d> const& tip) {
  Eigen::Vector3d const d = through.pose.axis.direction();
  Eigen::Vector3d const p0 = d.cross(through.pose.axis.moment());  // axis point closest to the optical centre
  Eigen::Vector3d const a = p0 + d.dot(through.pivot - p0) * d;     // the pivot's foot (the pivot, up to the fit)
  Eigen::Vector3d const b = tip ? Eigen::Vector3d(p0 + d.dot(*tip - p0) * d) : p0;
  if (!a.allFinite() || !b.allFinite()) return;
  auto line = base(header, "axes_through", index, visualization_msgs::Marker::LINE_LIST, 0.1f, 0.9f, 1.0f, 1.0f);
  line.scale.x = 0.0008;
  line.points = {pt(a), pt(b)};
  out.push_back(line);
}

}  // namespace endo_guidance::ros_io
