// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// A nodelet run as its own node (image_proc's pattern): pipeline.launch standalone:=true starts
// build/devel/lib/endo_guidance/<name>_node (ROS remappings and private parameters as usual).
// ENDO_NODELET_TYPE is set per executable by CMake.
#include <nodelet/loader.h>
#include <ros/ros.h>

int main(int argc, char** argv) {
  ros::init(argc, argv, ENDO_NODE_NAME);
  nodelet::Loader loader(false);  // no manager services: this process hosts one nodelet
  nodelet::V_string const args(argv + 1, argv + argc);
  if (!loader.load(ros::this_node::getName(), ENDO_NODELET_TYPE, ros::names::getRemappings(), args)) {
    ROS_FATAL("could not load nodelet %s", ENDO_NODELET_TYPE);
    return 1;
  }
  ros::spin();
  return 0;
}
