// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// rostest (test/ros/bag_faults.test): a compressed surgery bag with one truncated JPEG, played in
// a loop with --clock. The truncated frame is reported by the segmentation (ERROR, not decoded
// grey and processed); at each loop the clock jumps back, both stateful stages say so and reset,
// and the trocars are located again under new ids. Prints "[ bag faults ]" lines.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <rosgraph_msgs/Clock.h>

#include <atomic>
#include <cmath>
#include <mutex>
#include <set>
#include <vector>

#include "endo_guidance/InsertionPointArray.h"
#include "ros_test_main.h"

using namespace endo_guidance;

namespace {

double wall() { return ros::WallTime::now().toSec(); }

TEST(BagFaults, CorruptFrameReportedClockJumpRecovered) {
  ros::NodeHandle nh;
  std::mutex m;
  std::vector<std::tuple<double, int, std::string>> diagnostics;  // (wall time, level, "name: message")
  std::vector<std::pair<double, std::set<int>>> located;          // (wall time, located ids)
  std::atomic<double> jump{0.0}, last_clock{0.0};
  auto clock_sub = nh.subscribe<rosgraph_msgs::Clock>("/clock", 100, [&](rosgraph_msgs::Clock::ConstPtr const& c) {
    double const t = c->clock.toSec();
    if (t + 1.0 < last_clock && jump == 0.0) jump = wall();
    last_clock = t;
  });
  auto diag_sub = nh.subscribe<diagnostic_msgs::DiagnosticArray>("/diagnostics", 100, [&](diagnostic_msgs::DiagnosticArray::ConstPtr const& d) {
    std::lock_guard<std::mutex> l(m);
    for (auto const& s : d->status) diagnostics.emplace_back(wall(), s.level, s.name + ": " + s.message);
  });
  auto points_sub = nh.subscribe<InsertionPointArray>("endoscope/insertion_points", 10, [&](InsertionPointArray::ConstPtr const& p) {
    std::set<int> ids;
    for (auto const& x : p->points)
      if (x.located) ids.insert(x.id);
    std::lock_guard<std::mutex> l(m);
    located.emplace_back(wall(), ids);
  });
  auto said = [&](std::string const& text, double after, int level = -1) -> double {
    std::lock_guard<std::mutex> l(m);
    for (auto const& [t, lvl, s] : diagnostics)
      if (t > after && (level < 0 || lvl == level) && s.find(text) != std::string::npos) return t;
    return NAN;
  };
  double const t0 = wall();
  // One loop of the bag is 10 s (+ the player's delay): wait for the jump, then for the trocars.
  while (jump == 0.0 && wall() < t0 + 40.0) ros::WallDuration(0.1).sleep();
  ASSERT_GT(jump, 0.0) << "the clock never jumped back (is the bag looping?)";
  std::set<int> before;
  {
    std::lock_guard<std::mutex> l(m);
    for (auto const& [t, ids] : located)
      if (t < jump) before.insert(ids.begin(), ids.end());
  }
  ASSERT_GE(before.size(), 3u) << "the trocars were not located in the first loop";
  double relocated = NAN;
  for (double const end = jump + 30.0; std::isnan(relocated) && wall() < end; ros::WallDuration(0.1).sleep()) {
    std::lock_guard<std::mutex> l(m);
    for (auto const& [t, ids] : located)
      if (t > jump && ids.size() >= 3 && *ids.begin() > *before.rbegin()) relocated = t;
  }
  ros::WallDuration(1.5).sleep();  // the diagnostics' period
  double const corrupt = said("truncated JPEG (no end-of-image marker)", t0, diagnostic_msgs::DiagnosticStatus::ERROR);
  double const seg_jump = said("segmentation: time went backwards", jump - 0.5);
  double const ip_jump = said("insertion_points: time went backwards", jump - 0.5);
  std::printf("[ bag faults ] truncated JPEG reported as an ERROR: %s; clock jump back: segmentation %.2f s, insertion points "
              "%.2f s after; trocars re-located under new ids %.1f s after the jump (%zu ids before, from %d after)\n",
              std::isnan(corrupt) ? "no" : "yes", seg_jump - jump, ip_jump - jump, relocated - jump, before.size(),
              *before.rbegin() + 1);
  EXPECT_FALSE(std::isnan(corrupt)) << "the truncated frame was not reported";
  EXPECT_FALSE(std::isnan(seg_jump));
  EXPECT_FALSE(std::isnan(ip_jump));
  EXPECT_FALSE(std::isnan(relocated)) << "the trocars were not located again after the jump, under new ids";
}

}  // namespace

int main(int argc, char** argv) { return endo_guidance::test::runRosTests(argc, argv, "test_bag_faults"); }
