// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <cstdio>
#include <fstream>

#include "endo_guidance/io/yaml_config.h"

using namespace endo_guidance::perception;
using namespace endo_guidance::geometry;
using namespace endo_guidance::pipeline;
namespace io = endo_guidance::io;

namespace {
std::string write(std::string const& name, std::string const& text) {
  std::string const path = testing::TempDir() + name;
  std::ofstream(path) << text;
  return path;
}
std::string const kCamera =
    "image_width: 640\nimage_height: 480\ncamera_name: c\n"
    "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [500, 0, 319.5, 0, 510, 239.5, 0, 0, 1]\n"
    "distortion_model: plumb_bob\ndistortion_coefficients:\n  rows: 1\n  cols: 5\n  data: [0.1, 0, 0, 0, 0]\n"
    "projection_matrix:\n  rows: 3\n  cols: 4\n  data: [480, 0, 320, 0, 0, 490, 240, 0, 0, 0, 1, 0]\n";
}  // namespace

TEST(YamlConfig, CameraInfoYaml) {
  auto const c = io::loadCameraYaml(write("cam.yaml", kCamera));
  EXPECT_EQ(c.width, 640);
  EXPECT_EQ(c.K(1, 1), 510.0);
  EXPECT_TRUE(c.hasDistortion());
  EXPECT_EQ(c.rectifiedK()(0, 0), 480.0);  // P's intrinsics for the rectified image
  std::string zero = kCamera;
  zero.replace(zero.find("[500,"), 5, "[0,");
  EXPECT_THROW(io::loadCameraYaml(write("zero.yaml", zero)), std::runtime_error);
  EXPECT_THROW(io::loadCameraYaml(write("nosize.yaml", "camera_matrix: {data: [1,0,0,0,1,0,0,0,1]}\n")), std::runtime_error);
  EXPECT_THROW(io::loadCameraYaml("/nonexistent/cam.yaml"), std::runtime_error);
}

TEST(YamlConfig, PipelineParamsAndTheShippedDefaults) {
  PipelineParams p;
  io::loadPipelineYaml(write("p.yaml", "radius: 0.0025\nsegmentation:\n  grow_thresholds: [10, 20]\n"
                                       "insertion_points:\n  memory_views: 100\n"), p);
  EXPECT_EQ(p.radius, 0.0025);
  EXPECT_EQ(p.segmentation.regions.thresholds, (std::vector<int>{10, 20}));
  EXPECT_EQ(p.insertion_points.tracker.memory_views, 100.0);
  EXPECT_THROW(io::loadPipelineYaml(write("bad.yaml", "segmentation:\n  sigma_radiuss: 2\n"), p), std::runtime_error);
  // Growth levels that cannot be indexed or ordered are refused.
  for (char const* bad : {"[]", "[20, 10]", "[10, 10]", "[10, 300]"})
    EXPECT_THROW(io::loadPipelineYaml(write("bad.yaml", std::string("segmentation:\n  grow_thresholds: ") + bad + "\n"), p), std::runtime_error)
        << bad;
  EXPECT_THROW(io::loadPipelineYaml(write("bad.yaml", "segmentation:\n  grow_background_fractions: [0.4, 1.5]\n"), p), std::runtime_error);
  // Values the stages cannot work with are refused with the key's name (a zero processing width
  // divided by zero in the segmentation).
  for (char const* bad : {"radius: 0\n", "radius: -0.004\n", "segmentation:\n  processing_width: 0\n",
                          "segmentation:\n  sigma_radius: -1\n", "segmentation:\n  detect_every: 0\n", "segmentation:\n  resought_min_entry_sine: 1.5\n",
                          "segmentation:\n  resought_min_tip_depth_px: -1\n",
                          "segmentation:\n  resought_max_widening: 0.5\n",
                          "segmentation:\n  strip_full_res_outside_quantile: 1.5\n",
                          "segmentation:\n  strip_retry_min_halfwidth_px: -1\n",
                          "segmentation:\n  brightness_fallback_contrast: -2\n",
                          "segmentation:\n  full_search_every: 0\n", "segmentation:\n  max_regions: 0\n",
                          "segmentation:\n  full_search_max_every: 0\n", "segmentation:\n  refused_area_change: 1.5\n",
                          "segmentation:\n  seed_threshold: 300\n", "pose:\n  min_distance: 3.0\n",
                          "insertion_points:\n  max_points: -1\n", "insertion_points:\n  breathing_period: -4\n"}) {
    PipelineParams q;
    try {
      io::loadPipelineYaml(write("bad.yaml", bad), q);
      ADD_FAILURE() << "accepted: " << bad;
    } catch (std::runtime_error const& e) {
      EXPECT_NE(std::string(e.what()).find("must be"), std::string::npos) << e.what();
    }
  }
  // config/pipeline.yaml holds exactly the code defaults.
  PipelineParams const defaults;
  PipelineParams shipped;
  io::loadPipelineYaml(ENDO_GUIDANCE_SOURCE_DIR "/config/pipeline.yaml", shipped);
  EXPECT_EQ(shipped.radius, defaults.radius);
  EXPECT_EQ(shipped.segmentation.regions.thresholds, defaults.segmentation.regions.thresholds);
  EXPECT_EQ(shipped.segmentation.seeds.threshold, defaults.segmentation.seeds.threshold);
  EXPECT_EQ(shipped.segmentation.contours.max_residual_px, defaults.segmentation.contours.max_residual_px);
  EXPECT_EQ(shipped.segmentation.contours.min_fill, defaults.segmentation.contours.min_fill);
  EXPECT_EQ(shipped.segmentation.contours.min_elongation, defaults.segmentation.contours.min_elongation);
  EXPECT_EQ(shipped.segmentation.contours.max_widening, defaults.segmentation.contours.max_widening);
  EXPECT_EQ(shipped.segmentation.sigma_delta, defaults.segmentation.sigma_delta);
  EXPECT_EQ(shipped.insertion_points.tracker.memory_views, defaults.insertion_points.tracker.memory_views);
  EXPECT_EQ(shipped.insertion_points.tracker.gate_max, defaults.insertion_points.tracker.gate_max);
  EXPECT_EQ(shipped.insertion_points.tracker.breathing_period, defaults.insertion_points.tracker.breathing_period);
  EXPECT_EQ(shipped.pose.min_distance, defaults.pose.min_distance);
  EXPECT_EQ(shipped.segmentation.seeds.relative_threshold, defaults.segmentation.seeds.relative_threshold);
  EXPECT_EQ(shipped.segmentation.seeds.run_floor, defaults.segmentation.seeds.run_floor);
  EXPECT_EQ(shipped.segmentation.seeds.dark_border_level, defaults.segmentation.seeds.dark_border_level);
  EXPECT_EQ(shipped.segmentation.regions.background_fractions, defaults.segmentation.regions.background_fractions);
  EXPECT_EQ(shipped.segmentation.strip.enabled, defaults.segmentation.strip.enabled);
  EXPECT_EQ(shipped.segmentation.crossing_seeds, defaults.segmentation.crossing_seeds);
  EXPECT_EQ(shipped.segmentation.detector, defaults.segmentation.detector);
  EXPECT_EQ(shipped.segmentation.learned.model, defaults.segmentation.learned.model);
  EXPECT_EQ(shipped.segmentation.learned.threads, defaults.segmentation.learned.threads);
  EXPECT_EQ(shipped.segmentation.level_memory_px, defaults.segmentation.level_memory_px);
  EXPECT_EQ(shipped.segmentation.full_search_every, defaults.segmentation.full_search_every);
  EXPECT_EQ(shipped.segmentation.strip_search_max_every, defaults.segmentation.strip_search_max_every);
  EXPECT_EQ(shipped.segmentation.full_search_max_every, defaults.segmentation.full_search_max_every);
  EXPECT_EQ(shipped.segmentation.refused_area_change, defaults.segmentation.refused_area_change);
  EXPECT_EQ(shipped.segmentation.resought_min_entry_sine, defaults.segmentation.resought_min_entry_sine);
  EXPECT_EQ(shipped.segmentation.resought_min_tip_depth_px, defaults.segmentation.resought_min_tip_depth_px);
  EXPECT_EQ(shipped.segmentation.resought_max_widening, defaults.segmentation.resought_max_widening);
  EXPECT_EQ(shipped.segmentation.contours.extend_max_misses, defaults.segmentation.contours.extend_max_misses);
  EXPECT_EQ(shipped.segmentation.contours.edge_lobe_floor, defaults.segmentation.contours.edge_lobe_floor);
  EXPECT_EQ(shipped.segmentation.contours.brightness_fallback_contrast, defaults.segmentation.contours.brightness_fallback_contrast);
  EXPECT_EQ(shipped.segmentation.tracking.detect_every, defaults.segmentation.tracking.detect_every);
  EXPECT_EQ(shipped.segmentation.tracking.max_width_change, defaults.segmentation.tracking.max_width_change);
  EXPECT_EQ(shipped.segmentation.tracking.coarse_step_px, defaults.segmentation.tracking.coarse_step_px);
  EXPECT_EQ(shipped.segmentation.tracking.tip_reach_px, defaults.segmentation.tracking.tip_reach_px);
  using SP = StripSearchParams;
  for (double SP::*m : {&SP::max_angle_deg, &SP::min_response, &SP::min_inside_low, &SP::max_inside_outside_ratio,
                        &SP::min_length_ratio, &SP::max_full_res_ratio, &SP::max_full_res_ratio_matte,
                        &SP::max_specular_fraction, &SP::full_res_outside_quantile, &SP::retry_min_halfwidth_px})
    EXPECT_EQ(shipped.segmentation.strip.*m, defaults.segmentation.strip.*m);
  PipelineParams off;
  io::loadPipelineYaml(write("s.yaml", "segmentation:\n  strip_search: false\n  strip_min_length_ratio: 0.7\n  strip_search_max_every: 40\n  crossing_seeds: false\n"), off);
  EXPECT_FALSE(off.segmentation.strip.enabled);
  EXPECT_FALSE(off.segmentation.crossing_seeds);
  EXPECT_EQ(off.segmentation.strip.min_length_ratio, 0.7);
  EXPECT_EQ(off.segmentation.strip_search_max_every, 40);
  PipelineParams on;
  io::loadPipelineYaml(write("b.yaml", "segmentation:\n  brightness_fallback_contrast: 8\n"), on);
  EXPECT_EQ(on.segmentation.contours.brightness_fallback_contrast, 8.0);
}

// The detector switch: read, spelled out in errors, its learned parameters validated.
TEST(YamlConfig, DetectorSwitch) {
  PipelineParams p;
  io::loadPipelineYaml(write("d.yaml", "segmentation:\n  detector: learned\n  learned_model: /x/m.yaml\n  learned_threads: 2\n"), p);
  EXPECT_EQ(p.segmentation.detector, SegmentationParams::Detector::kLearned);
  EXPECT_EQ(p.segmentation.learned.model, "/x/m.yaml");
  EXPECT_EQ(p.segmentation.learned.threads, 2);
  EXPECT_STREQ(io::toString(p.segmentation.detector), "learned");
  io::loadPipelineYaml(write("c.yaml", "segmentation:\n  detector: colour\n"), p);
  EXPECT_EQ(p.segmentation.detector, SegmentationParams::Detector::kColour);
  PipelineParams q;
  EXPECT_THROW(io::loadPipelineYaml(write("e.yaml", "segmentation:\n  detector: hough\n"), q), std::runtime_error);
  EXPECT_THROW(io::loadPipelineYaml(write("t.yaml", "segmentation:\n  learned_threads: 0\n"), q), std::runtime_error);
}
