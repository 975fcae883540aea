// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
//
// endo_guidance_latency: what the nodelet chain adds over the core pipeline. Loads the three
// nodelets in this process (as in one manager: zero-copy), publishes rendered frames at a fixed
// rate and measures, per frame, wall time from publishing the image to receiving its
// insertion-point output (the tf camera -> trocar_<id> is sent just before it, same stamp);
// then runs the core Pipeline on the same frames and reports the difference of the medians.
// Needs a running master (scripts/latency.sh starts one).
#include <nodelet/loader.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <map>
#include <mutex>

#include "endo_guidance/InsertionPointArray.h"
#include "endo_guidance/pipeline/pipeline.h"
#include "endo_guidance/sim/scene_renderer.h"

using namespace endo_guidance;

namespace {
double pct(std::vector<double> v, double p) {
  if (v.empty()) return NAN;
  std::sort(v.begin(), v.end());
  return v[static_cast<std::size_t>(p * (v.size() - 1))];
}
}  // namespace

int main(int argc, char** argv) {
  ros::init(argc, argv, "endo_guidance_latency");
  int frames = 250;
  std::vector<double> rates{25.0, 60.0};
  for (int i = 1; i < argc; ++i)
    if (std::string(argv[i]) == "--frames" && i + 1 < argc) frames = std::atoi(argv[++i]);
  ros::NodeHandle nh;
  ros::AsyncSpinner spinner(4);
  spinner.start();
  sim::SyntheticSceneOptions so;
  sim::SyntheticScene scene(sim::defaultInstruments(), so);
  sim::SceneRenderer renderer(so.width, so.height);
  std::vector<cv::Mat> images;
  for (int k = 0; k < frames; ++k) images.push_back(renderer.render(scene.frame(k), k));
  sensor_msgs::CameraInfo info;
  info.header.frame_id = "endoscope_optical_frame";
  info.width = 640;
  info.height = 480;
  info.distortion_model = "plumb_bob";
  info.D.assign(5, 0.0);
  for (int i = 0; i < 9; ++i) info.K[i] = so.K(i / 3, i % 3);
  for (int i = 0; i < 12; ++i) info.P[i] = (i % 4 == 3) ? 0.0 : so.K(i / 4, i % 4);

  std::printf("frames: %d rendered 640x480 (3 instruments); nodelets in this process\n", frames);
  std::printf("%-8s %-28s %-28s %-22s %s\n", "rate", "chain image->trocars p50/p95", "core Pipeline p50/p95", "added p50 (ms)", "tf frames");
  for (double rate : rates) {
    nodelet::Loader loader(false);
    ros::M_string remap{{"/image", "/endoscope/image_raw"}, {"/camera_info", "/endoscope/camera_info"},
                        {"/contours", "/endoscope/contours"}, {"/axes", "/endoscope/axes"},
                        {"/insertion_points", "/endoscope/insertion_points"}, {"/instruments", "/endoscope/instruments"},
                        {"/overlay", "/endoscope/overlay"}, {"/shaft_markers", "/endoscope/shaft_markers"},
                        {"/trocar_markers", "/endoscope/trocar_markers"}};
    for (auto const& [name, type] : std::vector<std::pair<std::string, std::string>>{
             {"/segmentation", "endo_guidance/Segmentation"}, {"/cylinder_pose", "endo_guidance/CylinderPose"},
             {"/insertion_points", "endo_guidance/InsertionPoints"}})
      if (!loader.load(name, type, remap, {})) {
        std::fprintf(stderr, "cannot load %s\n", type.c_str());
        return 1;
      }
    std::mutex m;
    std::map<double, ros::WallTime> sent;
    std::vector<double> chain;
    int tf_frames = 0;
    auto sub = nh.subscribe<InsertionPointArray>("/endoscope/insertion_points", 100, [&](InsertionPointArray::ConstPtr const& p) {
      ros::WallTime const now = ros::WallTime::now();
      std::lock_guard<std::mutex> l(m);
      auto const it = sent.find(p->header.stamp.toSec());
      if (it != sent.end()) chain.push_back((now - it->second).toSec() * 1e3);
    });
    auto tfsub = nh.subscribe<tf2_msgs::TFMessage>("/tf", 100, [&](tf2_msgs::TFMessage::ConstPtr const&) {
      std::lock_guard<std::mutex> l(m);
      ++tf_frames;
    });
    ros::Publisher ip = nh.advertise<sensor_msgs::Image>("/endoscope/image_raw", 2);
    ros::Publisher cp = nh.advertise<sensor_msgs::CameraInfo>("/endoscope/camera_info", 2);
    ros::WallDuration(1.0).sleep();
    ros::WallRate r(rate);
    for (int k = 0; k < frames; ++k) {
      sensor_msgs::ImagePtr img(new sensor_msgs::Image);
      img->header.stamp = ros::Time(1000.0 + rate * 10 + k / rate);
      img->header.frame_id = info.header.frame_id;
      img->height = 480;
      img->width = 640;
      img->encoding = "bgr8";
      img->step = 640 * 3;
      img->data.assign(images[k].data, images[k].data + 640 * 480 * 3);
      sensor_msgs::CameraInfoPtr ci(new sensor_msgs::CameraInfo(info));
      ci->header.stamp = img->header.stamp;
      {
        std::lock_guard<std::mutex> l(m);
        sent[img->header.stamp.toSec()] = ros::WallTime::now();
      }
      cp.publish(ci);
      ip.publish(img);  // shared pointer: delivered in-process without serialisation
      r.sleep();
    }
    ros::WallDuration(0.5).sleep();
    // The core alone on the same frames at the same pace (caches go as cold between frames).
    pipeline::Pipeline p(so.K, {640, 480});
    std::vector<double> core_ms;
    ros::WallRate rc(rate);
    for (int k = 0; k < frames; ++k, rc.sleep()) {
      auto const t0 = std::chrono::steady_clock::now();
      p.process(images[k]);
      core_ms.push_back(std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count());
    }
    std::lock_guard<std::mutex> l(m);
    std::printf("%-8.0f %8.2f / %-8.2f (%zu)      %8.2f / %-8.2f          %-22.3f %d\n", rate, pct(chain, 0.5), pct(chain, 0.95),
                chain.size(), pct(core_ms, 0.5), pct(core_ms, 0.95), pct(chain, 0.5) - pct(core_ms, 0.5), tf_frames);
    sub.shutdown();
    tfsub.shutdown();
    for (auto const& n : loader.listLoadedNodelets()) loader.unload(n);
  }
  spinner.stop();
  return 0;
}
