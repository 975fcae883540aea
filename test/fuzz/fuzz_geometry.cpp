// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// Geometry on arbitrary lines and axes (non-finite, degenerate, huge, parallel): cylinder pose,
// the axis through a point, insertion points in 3-D and in the image, attachment. Whatever comes
// back as valid must be finite: degenerate geometry is flagged, never guessed.
#include <vector>

#include "endo_guidance/geometry/constrained_axis.h"
#include "endo_guidance/geometry/cylinder_pose.h"
#include "endo_guidance/geometry/insertion_point.h"
#include "endo_guidance/geometry/insertion_point_image.h"
#include "endo_guidance/geometry/insertion_point_tracker.h"
#include "endo_guidance/pipeline/pipeline.h"
#include "fuzz_input.h"

using namespace endo_guidance::perception;
using namespace endo_guidance::geometry;
using namespace endo_guidance::pipeline;
using endo_guidance::fuzz::fail;
using endo_guidance::fuzz::Input;

namespace {
Eigen::Vector3d vec3(Input& in, double s) { return {in.real(-s, s), in.real(-s, s), in.real(-s, s)}; }
// Mostly near-valid axes (a shaft seen by the camera), some arbitrary.
std::optional<PluckerLine> axis(Input& in) {
  if (in.byte() < 32) return PluckerLine::fromDirectionMoment(vec3(in, 2.0), vec3(in, 0.5));
  Eigen::Vector3d const T(in.real(-0.2, 0.2), in.real(-0.2, 0.2), in.real(-0.1, 0.1));
  return PluckerLine::through(T, T + vec3(in, 0.2));
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(std::uint8_t const* data, std::size_t size) {
  Input in(data, size);
  Eigen::Matrix3d K;
  K << in.real(50, 3000), in.real(-1, 1), in.real(0, 2000), 0, in.real(50, 3000), in.real(0, 2000), 0, 0, 1;
  double const radius = in.real(0.0, 0.02);
  // Cylinder pose from two lines (and covariances), then what the pipeline does with it.
  ApparentContour c;
  for (int i = 0; i < 2; ++i) {
    c.lines[i] = Eigen::Vector3d(in.real(-1, 1), in.real(-1, 1), in.real(-2000, 2000));
    if (in.byte() & 1) c.line_covariances[i] = Eigen::Vector3d(in.real(0, 1e-4), in.real(0, 1e-4), in.real(0, 10)).asDiagonal();
  }
  c.tip_px = Eigen::Vector2d(in.real(-100, 2000), in.real(-100, 2000));
  CylinderPoseResult const r = estimateCylinderPose(K, radius, c);
  if (r.ok()) {
    if (!r.pose.axis.direction().allFinite() || !r.pose.axis.moment().allFinite() || !r.pose.covariance.allFinite())
      fail("cylinder pose ok but not finite");
    if (auto const t = backProjectOntoAxis(K, r.pose.axis, c.tip_px); t && !t->allFinite()) fail("tip not finite");
    Eigen::Vector3d const point = vec3(in, 0.3);
    Eigen::Matrix3d const pc = Eigen::Vector3d(in.real(0, 1e-4), in.real(0, 1e-4), in.real(0, 1e-4)).asDiagonal();
    if (auto const a = constrainAxisToPoint(r.pose, point, pc, in.real(0, 0.01)))
      if (!a->pose.axis.direction().allFinite() || !a->pose.axis.moment().allFinite() || !a->pivot.allFinite() ||
          !a->pose.covariance.allFinite())
        fail("axis through the point not finite");
  }
  // Insertion point from a set of axes (3-D: Eq. (3) least squares and robust) and its image.
  std::vector<PluckerLine> axes;
  std::vector<ImageLine> lines;
  int const n = static_cast<int>(in.range(0, 40));
  for (int i = 0; i < n && !in.empty(); ++i)
    if (auto const a = axis(in)) {
      axes.push_back(*a);
      if (in.byte() & 1) axes.push_back(*a);  // exact duplicates: parallel, coincident
      if (auto const l = imageOfAxis(K, *a)) lines.push_back(*l);
    }
  for (InsertionPointEstimate const& e : {intersectAxes(axes), intersectAxesRobust(axes)})
    if (e.ok() && (!e.position.allFinite() || !e.covariance.allFinite())) fail("insertion point ok but not finite");
  for (ImagePointEstimate const& e :
       {intersectImageLines(lines, Eigen::Vector2d(320, 240), 400), intersectImageLinesRobust(lines, Eigen::Vector2d(320, 240), 400)})
    if (e.ok && !e.point.allFinite()) fail("image point ok but not finite");
  // Attachment: the axes fed one by one to a set of insertion points, as the pipeline does.
  InsertionPointSet set;
  double stamp = 0.0;
  for (PluckerLine const& a : axes) {
    CylinderPose p;
    p.axis = a;
    p.distance = a.distanceToOrigin();
    bool keep = true;
    attachAxis(set, p, true, !set.points().empty(), &keep, stamp += in.real(-0.1, 0.1));
  }
  for (auto const& e : reportInsertionPoints(set, K))
    if (e.estimate.ok() && (!e.estimate.position.allFinite() || !e.image_point.allFinite())) fail("reported point not finite");
  return 0;
}
