// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
//
// endo_guidance_synthetic: runs the geometric core on the built-in synthetic surgery (three
// instruments pivoting about out-of-view trocars): apparent contours with noise -> cylinder
// pose -> insertion points (robust, recursive) -> attachment, and prints the estimated
// insertion points against the truth. Exit code 1 with --check TOL if a trocar is off by more
// than TOL metres (or missing).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>

#include "endo_guidance/geometry/cylinder_pose.h"
#include "endo_guidance/geometry/insertion_point.h"
#include "endo_guidance/geometry/insertion_point_image.h"
#include "endo_guidance/geometry/insertion_point_tracker.h"
#include "endo_guidance/sim/scene_renderer.h"
#include "endo_guidance/sim/synthetic_scene.h"

#include <cv_bridge/cv_bridge.h>
#include <rosbag/bag.h>
#include <sensor_msgs/CameraInfo.h>

#include <filesystem>
#include <random>
#include <fstream>
#include <opencv2/imgcodecs.hpp>

using namespace endo_guidance::geometry;
using namespace endo_guidance::sim;

namespace {
void usage() {
  std::puts(
      "usage: endo_guidance_synthetic [--frames N] [--noise PX] [--breathing M] [--seed S] [--check TOL_M]\n"
      "  --frames N     frames at 25 Hz (default 500)\n"
      "  --noise PX     sigma of the contour-line endpoints, pixels (default 0.5)\n"
      "  --breathing M  peak trocar motion, metres (default 0.002)\n"
      "  --seed S       noise seed (default 42)\n"
      "  --check TOL_M  exit 1 unless every trocar is found within TOL_M of its mean position\n"
      "  --write-sequence DIR  render the sequence instead: DIR/frames/NNNNNN.png, DIR/camera.yaml\n"
      "  --write-training DIR  render training frames instead, each with its own rendering (black or grey shafts,\n"
      "                        circular view, gauze, membranes, highlights, noise, JPEG; seeded by --seed):\n"
      "                        DIR/NNNNNN.png and DIR/NNNNNN_labels.png (0 background, 1 shaft, 2 jaws)\n"
      "                 (ROS camera_info YAML) and DIR/truth.yaml (mean trocars, metres)\n"
      "  --write-bag FILE  render the sequence into a bag instead (LZ4): /endoscope/image_raw (bgr8),\n"
      "                 /endoscope/camera_info, frame endoscope_optical_frame, 25 Hz from t = 1000 s;\n"
      "                 the truth goes to FILE's name with .truth.yaml\n"
      "  --scene clean|hard|black_circular  rendering for --write-sequence/--write-bag (default clean)\n"
      "  --noise-sweep  print pose and insertion-point errors for line noise 0..1 px (no breathing)");
}

void writeTruth(std::ostream& truth, SyntheticScene const& scene) {
  truth << "# mean trocar positions, camera optical frame, metres\ntrocars:\n";
  for (std::size_t i = 0; i < scene.size(); ++i) {
    Eigen::Vector3d const& T = scene.meanTrocar(static_cast<int>(i));
    truth << "  - [" << T.x() << ", " << T.y() << ", " << T.z() << "]\n";
  }
  truth << "radius: " << defaultInstruments()[0].radius << "\n";
}

// A simulated surgery as a camera driver would record it (replay.launch's input).
// Training frames for the learned shaft mask (scripts/train_shaft_net.py): every 7th frame of the
// scene, each rendered with its own randomly drawn options, with its exact labels.
int writeTraining(std::string const& dir, SyntheticScene& scene, int frames, unsigned long seed) {
  namespace fs = std::filesystem;
  fs::create_directories(dir);
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<double> U(0.0, 1.0);
  for (int i = 0; i < frames; ++i) {
    RenderOptions o;
    o.black_shafts = U(rng) < 0.3;
    o.circular_fov = U(rng) < 0.3;
    o.gauze = U(rng) < 0.4;
    o.membranes = U(rng) < 0.7;
    o.specular = U(rng) < 0.8;
    o.noise_sigma = 6.0 * U(rng);
    o.jpeg_quality = U(rng) < 0.5 ? static_cast<int>(40 + 55 * U(rng)) : 0;
    o.seed = rng();
    int const k = 7 * i;
    SceneRenderer const renderer(scene.options().width, scene.options().height, o);
    cv::Mat labels;
    cv::Mat const image = renderer.render(scene.frame(k), k, &labels);
    char name[32];
    std::snprintf(name, sizeof name, "%06d", i);
    if (!cv::imwrite((fs::path(dir) / (std::string(name) + ".png")).string(), image) ||
        !cv::imwrite((fs::path(dir) / (std::string(name) + "_labels.png")).string(), labels)) {
      std::fprintf(stderr, "cannot write to %s\n", dir.c_str());
      return 1;
    }
  }
  std::printf("wrote %d training frames with labels to %s\n", frames, dir.c_str());
  return 0;
}

void writeBag(std::string const& path, SyntheticScene& scene, SyntheticSceneOptions const& so, RenderOptions const& ro,
              int frames) {
  auto const parent = std::filesystem::path(path).parent_path();
  if (!parent.empty()) std::filesystem::create_directories(parent);
  rosbag::Bag bag(path, rosbag::bagmode::Write);
  bag.setCompression(rosbag::compression::LZ4);
  SceneRenderer renderer(so.width, so.height, ro);
  sensor_msgs::CameraInfo info;
  info.header.frame_id = "endoscope_optical_frame";
  info.width = static_cast<std::uint32_t>(so.width);
  info.height = static_cast<std::uint32_t>(so.height);
  info.distortion_model = "plumb_bob";
  info.D.assign(5, 0.0);
  for (int i = 0; i < 9; ++i) info.K[i] = so.K(i / 3, i % 3);
  info.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  for (int i = 0; i < 12; ++i) info.P[i] = (i % 4 == 3) ? 0.0 : so.K(i / 4, i % 4);
  for (int k = 0; k < frames; ++k) {
    ros::Time const t(1000.0 + k / so.fps);
    cv_bridge::CvImage img;
    img.header.stamp = t;
    img.header.frame_id = info.header.frame_id;
    img.header.seq = static_cast<std::uint32_t>(k);
    img.encoding = "bgr8";
    img.image = renderer.render(scene.frame(k), k);
    info.header.stamp = t;
    info.header.seq = img.header.seq;
    bag.write("/endoscope/image_raw", t, img.toImageMsg());
    bag.write("/endoscope/camera_info", t, info);
  }
  bag.close();
}
}  // namespace

int main(int argc, char** argv) {
  int frames = 500;
  double noise = 0.5, breathing = 0.002, check = -1.0;
  unsigned long seed = 42;
  std::string write_dir, write_bag, write_training, scene_name = "clean";
  bool sweep = false;
  for (int i = 1; i < argc; ++i) {
    std::string const a = argv[i];
    auto next = [&](char const* name) -> char const* {
      if (i + 1 >= argc) {
        std::fprintf(stderr, "missing value for %s\n", name);
        std::exit(2);
      }
      return argv[++i];
    };
    if (a == "--frames") frames = std::atoi(next("--frames"));
    else if (a == "--noise") noise = std::atof(next("--noise"));
    else if (a == "--breathing") breathing = std::atof(next("--breathing"));
    else if (a == "--seed") seed = std::strtoul(next("--seed"), nullptr, 10);
    else if (a == "--check") check = std::atof(next("--check"));
    else if (a == "--write-sequence") write_dir = next("--write-sequence");
    else if (a == "--write-training") write_training = next("--write-training");
    else if (a == "--scene") scene_name = next("--scene");
    else if (a == "--write-bag") write_bag = next("--write-bag");
    else if (a == "--noise-sweep") sweep = true;
    else if (a == "-h" || a == "--help") {
      usage();
      return 0;
    } else {
      std::fprintf(stderr, "unknown argument '%s'\n", a.c_str());
      usage();
      return 2;
    }
  }
  if (frames <= 0 || !(noise >= 0.0) || !(breathing >= 0.0)) {
    std::fprintf(stderr, "frames must be > 0, noise and breathing >= 0\n");
    return 2;
  }

  if (sweep) {
    // Errors of the geometric core against line noise (endpoint noise of each contour line).
    std::printf("%-8s %-22s %-22s %-26s %-22s\n", "noise px", "direction p50/p95 deg", "distance p50/p95 %",
                "trocar after N frames, mm", "trocar plain Eq.(3), mm");
    for (double sn : {0.0, 0.1, 0.25, 0.5, 1.0}) {
      SyntheticSceneOptions o;
      o.line_noise_px = sn;
      o.seed = seed;
      SyntheticScene sc(defaultInstruments(), o);
      std::vector<double> dir, dist;
      std::vector<InsertionPointTracker> trk(sc.size());
      std::vector<std::vector<PluckerLine>> axes(sc.size());
      for (int k = 0; k < frames; ++k)
        for (SyntheticView const& v : sc.frame(k)) {
          CylinderPoseResult const r = estimateCylinderPose(o.K, v.radius, v.measured);
          if (!r.ok()) continue;
          dir.push_back(std::atan2(r.pose.axis.direction().cross(v.axis.direction()).norm(),
                                   r.pose.axis.direction().dot(v.axis.direction())) * 180.0 / M_PI);
          dist.push_back(100.0 * std::abs(r.pose.distance - v.axis.distanceToOrigin()) / v.axis.distanceToOrigin());
          trk[v.instrument].update(r.pose.axis, r.pose.covariance);
          axes[v.instrument].push_back(r.pose.axis);
        }
      auto q = [](std::vector<double> x, double p) -> double {
        if (x.empty()) return NAN;
        std::sort(x.begin(), x.end());
        return x[static_cast<std::size_t>(p * (x.size() - 1))];
      };
      std::string tr, pl;
      for (std::size_t i = 0; i < sc.size(); ++i) {
        char b[32];
        std::snprintf(b, sizeof b, "%.2f ", (trk[i].estimate().position - sc.meanTrocar(static_cast<int>(i))).norm() * 1e3);
        tr += b;
        std::snprintf(b, sizeof b, "%.2f ", (intersectAxes(axes[i]).position - sc.meanTrocar(static_cast<int>(i))).norm() * 1e3);
        pl += b;
      }
      std::printf("%-8.2f %6.3f / %-13.3f %6.3f / %-13.3f %-26s %-22s\n", sn, q(dir, 0.5), q(dir, 0.95), q(dist, 0.5),
                  q(dist, 0.95), tr.c_str(), pl.c_str());
    }
    std::printf("(%d frames at 25 Hz, %zu instruments, 640x480, f = 500 px, 8 mm shafts 10-17 cm away)\n", frames,
                defaultInstruments().size());
    return 0;
  }
  SyntheticSceneOptions so;
  so.line_noise_px = noise;
  so.breathing_amplitude = breathing;
  so.seed = seed;
  SyntheticScene scene(defaultInstruments(), so);
  if (!write_training.empty()) return writeTraining(write_training, scene, frames, seed);
  if (!write_dir.empty() || !write_bag.empty()) {
    // The embedded default sequence of the README's main command.
    RenderOptions ro;
    if (scene_name == "hard") {
      ro = hardRenderOptions();
    } else if (scene_name == "black_circular") {
      ro.black_shafts = true;
      ro.circular_fov = true;
    } else if (scene_name != "clean") {
      std::fprintf(stderr, "unknown scene '%s'\n", scene_name.c_str());
      return 2;
    }
    namespace fs = std::filesystem;
    if (!write_bag.empty()) {
      try {
        writeBag(write_bag, scene, so, ro, frames);
      } catch (std::exception const& e) {
        std::fprintf(stderr, "cannot write the bag: %s\n", e.what());
        return 1;
      }
      std::string const truth_path = fs::path(write_bag).replace_extension(".truth.yaml").string();
      std::ofstream truth(truth_path);
      writeTruth(truth, scene);
      std::printf("wrote %d frames (%s scene) to %s, truth to %s\n", frames, scene_name.c_str(), write_bag.c_str(), truth_path.c_str());
      return 0;
    }
    fs::create_directories(fs::path(write_dir) / "frames");
    SceneRenderer renderer(so.width, so.height, ro);
    for (int k = 0; k < frames; ++k) {
      char name[32];
      std::snprintf(name, sizeof name, "%06d.png", k);
      cv::imwrite((fs::path(write_dir) / "frames" / name).string(), renderer.render(scene.frame(k), k));
    }
    std::ofstream cam(fs::path(write_dir) / "camera.yaml");
    Eigen::Matrix3d const& K = so.K;
    cam << "image_width: " << so.width << "\nimage_height: " << so.height << "\ncamera_name: endo_guidance_synthetic\n"
        << "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [" << K(0, 0) << ", 0, " << K(0, 2) << ", 0, " << K(1, 1) << ", "
        << K(1, 2) << ", 0, 0, 1]\n"
        << "distortion_model: plumb_bob\ndistortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [0, 0, 0, 0, 0]\n"
        << "rectification_matrix:\n  rows: 3\n  cols: 3\n  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]\n"
        << "projection_matrix:\n  rows: 3\n  cols: 4\n  data: [" << K(0, 0) << ", 0, " << K(0, 2) << ", 0, 0, " << K(1, 1)
        << ", " << K(1, 2) << ", 0, 0, 0, 1, 0]\n";
    std::ofstream truth(fs::path(write_dir) / "truth.yaml");
    writeTruth(truth, scene);
    std::printf("wrote %d frames (%s scene) with camera.yaml and truth.yaml to %s\n", frames, scene_name.c_str(), write_dir.c_str());
    return 0;
  }
  InsertionPointSet set;

  std::printf("endo_guidance synthetic sequence: %d frames %dx%d, %zu instruments, line noise %.2f px, "
              "breathing %.1f mm\n",
              frames, so.width, so.height, scene.size(), noise, breathing * 1e3);
  std::size_t views = 0, poses = 0, attached = 0, correct = 0;
  double t_pose = 0.0, t_ip = 0.0;
  for (int k = 0; k < frames; ++k) {
    for (SyntheticView const& v : scene.frame(k)) {
      ++views;
      auto const t0 = std::chrono::steady_clock::now();
      CylinderPoseResult const r = estimateCylinderPose(so.K, v.radius, v.measured);
      auto const t1 = std::chrono::steady_clock::now();
      if (!r.ok()) continue;
      ++poses;
      int const id = set.update(r.pose.axis, r.pose.covariance);
      auto const t2 = std::chrono::steady_clock::now();
      t_pose += std::chrono::duration<double>(t1 - t0).count();
      t_ip += std::chrono::duration<double>(t2 - t1).count();
      if (id >= 0 && set.find(id)) {
        ++attached;
        // Correct if it went to the estimated point nearest to this instrument's true trocar.
        int nearest = -1;
        double bd = 1e9;
        for (auto const& p : set.points()) {
          double const e = (p.tracker.estimate().position - scene.meanTrocar(v.instrument)).norm();
          if (p.tracker.estimate().ok() && e < bd) {
            bd = e;
            nearest = p.id;
          }
        }
        correct += nearest == id ? 1 : 0;
      }
    }
  }
  std::printf("views %zu, poses %zu, attached %zu (%.1f %% of poses, %.1f %% to the right trocar)\n", views, poses,
              attached, 100.0 * attached / std::max<std::size_t>(poses, 1),
              100.0 * correct / std::max<std::size_t>(attached, 1));
  std::printf("mean time: cylinder pose %.2f us, insertion-point update %.2f us (wall clock, indicative)\n\n",
              1e6 * t_pose / std::max<std::size_t>(poses, 1), 1e6 * t_ip / std::max<std::size_t>(poses, 1));

  bool ok = true;
  std::printf("%-8s %-28s %-28s %9s %6s %8s %8s %s\n", "trocar", "true mean (mm)", "estimated (mm)", "error mm",
              "views", "rms mm", "spread", "image point (px)");
  for (std::size_t i = 0; i < scene.size(); ++i) {
    Eigen::Vector3d const T = scene.meanTrocar(static_cast<int>(i));
    InsertionPointSet::Entry const* best = nullptr;
    double be = 1e9;
    for (auto const& p : set.points()) {
      double const e = (p.tracker.estimate().position - T).norm();
      if (p.tracker.estimate().ok() && e < be) {
        be = e;
        best = &p;
      }
    }
    if (!best) {
      std::printf("%-8zu (%7.1f %7.1f %7.1f)    not found\n", i, T.x() * 1e3, T.y() * 1e3, T.z() * 1e3);
      ok = false;
      continue;
    }
    InsertionPointEstimate const& e = best->tracker.estimate();
    Eigen::Vector3d const ip = projectPointHomogeneous(so.K, e.position);
    char img[64];
    if (std::abs(ip.z()) > 1e-12) std::snprintf(img, sizeof img, "(%.0f, %.0f)", ip.x() / ip.z(), ip.y() / ip.z());
    else std::snprintf(img, sizeof img, "at infinity");
    std::printf("%-8zu (%7.1f %7.1f %7.1f)  (%7.1f %7.1f %7.1f)  %9.3f %6zu %8.3f %7.1f° %s%s\n", i, T.x() * 1e3,
                T.y() * 1e3, T.z() * 1e3, e.position.x() * 1e3, e.position.y() * 1e3, e.position.z() * 1e3, be * 1e3,
                e.views, e.rms_distance * 1e3, std::asin(e.conditioning) * 180.0 / M_PI, img,
                best->tracker.wellConditioned() ? "" : "  (ill-conditioned)");
    if (check > 0.0 && be > check) ok = false;
  }
  if (set.points().size() != scene.size()) {
    std::printf("\n%zu insertion points estimated for %zu instruments\n", set.points().size(), scene.size());
    if (check > 0.0) ok = false;
  }
  if (check > 0.0) std::printf("\ncheck (every trocar within %.1f mm): %s\n", check * 1e3, ok ? "PASS" : "FAIL");
  return (check > 0.0 && !ok) ? 1 : 0;
}
