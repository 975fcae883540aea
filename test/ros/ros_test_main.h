// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// main() of the rostest gtest nodes: callbacks run on an AsyncSpinner while the tests wait.
#pragma once

#include <gtest/gtest.h>
#include <ros/ros.h>
#include <string>

#include "endo_guidance/InsertionPointArray.h"

namespace endo_guidance::test {
inline int runRosTests(int argc, char** argv, char const* node_name, int threads = 2) {
  testing::InitGoogleTest(&argc, argv);
  ros::init(argc, argv, node_name);
  ros::AsyncSpinner spinner(threads);
  spinner.start();
  int const r = RUN_ALL_TESTS();
  spinner.stop();
  return r;
}

/// A service call that survives a transport failure on a loaded machine (seen once: the server
/// handled the request, the client got false): waits for the service, then tries up to three
/// times -- only for idempotent calls. The server's answer is checked by the caller.
template <class S>
bool callService(std::string const& name, S& srv) {
  if (!ros::service::waitForService(name, 5000)) return false;
  for (int attempt = 0; attempt < 3; ++attempt) {
    if (ros::service::call(name, srv)) return true;
    ros::Duration(0.2).sleep();
  }
  return false;
}

/// Waits (up to timeout_s of wall time) until the pipeline reports `count` well-conditioned
/// insertion points; returns the last array (null if none came) and sets *well.
inline endo_guidance::InsertionPointArray::ConstPtr waitForTrocars(ros::NodeHandle& nh, int count, int* well,
                                                                   double timeout_s = 60.0) {
  endo_guidance::InsertionPointArray::ConstPtr est;
  *well = 0;
  for (ros::WallTime t0 = ros::WallTime::now(); (ros::WallTime::now() - t0).toSec() < timeout_s && *well < count;) {
    est = ros::topic::waitForMessage<endo_guidance::InsertionPointArray>("endoscope/insertion_points", nh, ros::Duration(5.0));
    *well = 0;
    if (est)
      for (auto const& p : est->points) *well += p.well_conditioned;
  }
  return est;
}
}  // namespace endo_guidance::test
