// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <cstdio>
#include <cmath>
#include <fstream>
#include <iterator>
#include <set>
#include <type_traits>

#include "endo_guidance/io/parameter_table.h"
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
                          "segmentation:\n  sigma_radius: -1\n", "segmentation:\n  detect_every: -1\n", "segmentation:\n  resought_min_entry_sine: 1.5\n",
                          "segmentation:\n  resought_min_tip_depth_px: -1\n",
                          "segmentation:\n  resought_max_widening: 0.5\n",
                          "segmentation:\n  strip_full_res_outside_quantile: 1.5\n",
                          "segmentation:\n  strip_retry_min_halfwidth_px: -1\n",
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
  // config/pipeline.yaml holds exactly the code defaults: read back, every value prints as its default.
  PipelineParams shipped;
  io::loadPipelineYaml(ENDO_GUIDANCE_SOURCE_DIR "/config/pipeline.yaml", shipped);
  EXPECT_EQ(io::pipelineYaml(shipped), io::pipelineYaml());
  PipelineParams changed;
  changed.segmentation.sigma_delta = 11;
  EXPECT_NE(io::pipelineYaml(changed), io::pipelineYaml());  // (the comparison sees a change)
  PipelineParams off;
  io::loadPipelineYaml(write("s.yaml", "segmentation:\n  strip_search: false\n  strip_min_length_ratio: 0.7\n  strip_search_max_every: 40\n  crossing_seeds: false\n"), off);
  EXPECT_FALSE(off.segmentation.strip.enabled);
  EXPECT_FALSE(off.segmentation.crossing_seeds);
  EXPECT_EQ(off.segmentation.strip.min_length_ratio, 0.7);
  EXPECT_EQ(off.segmentation.strip_search_max_every, 40);
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

namespace {
std::string readFile(std::string const& path) {
  std::ifstream in(path);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}
}  // namespace

// The files that come from the parameter table are what it gives (else: scripts/write_parameter_files.sh).
TEST(YamlConfig, ParameterFilesMatchTheTable) {
  EXPECT_EQ(readFile(ENDO_GUIDANCE_SOURCE_DIR "/config/pipeline.yaml"), io::pipelineYaml())
      << "config/pipeline.yaml is not the parameter table's: run scripts/write_parameter_files.sh";
  EXPECT_EQ(readFile(ENDO_GUIDANCE_SOURCE_DIR "/cfg/Segmentation.cfg"), io::reconfigureCfg(io::Live::kSegmentation))
      << "cfg/Segmentation.cfg is not the parameter table's: run scripts/write_parameter_files.sh";
  EXPECT_EQ(readFile(ENDO_GUIDANCE_SOURCE_DIR "/cfg/InsertionPoints.cfg"), io::reconfigureCfg(io::Live::kInsertionPoints))
      << "cfg/InsertionPoints.cfg is not the parameter table's: run scripts/write_parameter_files.sh";
}

// Every key once; every default inside its own range (a table line that refuses its default
// would make every start fail); a value just outside the range is refused with the key's name.
TEST(YamlConfig, TheTableHoldsItsDefaults) {
  PipelineParams p;
  std::set<std::string> keys;
  int checked = 0;
  io::forEachPipelineParam(p, [&](io::ParamInfo const& info, auto&& field) {
    using T = std::decay_t<decltype(field)>;
    EXPECT_TRUE(keys.insert(info.key).second) << info.key;
    EXPECT_LE(info.min, info.max) << info.key;
    if constexpr (std::is_same_v<T, double> || std::is_same_v<T, int>) {
      EXPECT_GE(static_cast<double>(field), info.min) << info.key;
      EXPECT_LE(static_cast<double>(field), info.max) << info.key;
      std::string const key(info.key);
      auto const slash = key.find('/');
      double const beyond = info.max + std::max(1.0, std::abs(info.max));
      std::string const yaml = slash == std::string::npos ? key + ": " + std::to_string(beyond) + "\n"
                                                          : key.substr(0, slash) + ":\n  " + key.substr(slash + 1) + ": " +
                                                                std::to_string(std::is_same_v<T, int> ? std::floor(beyond) : beyond) + "\n";
      PipelineParams q;
      try {
        io::parsePipelineYaml(std::is_same_v<T, int> ? yaml.substr(0, yaml.find('.')) + "\n" : yaml, q);
        ADD_FAILURE() << "accepted beyond its range: " << yaml;
      } catch (std::runtime_error const& e) {
        EXPECT_NE(std::string(e.what()).find(info.key), std::string::npos) << e.what();
      }
      ++checked;
    }
  });
  EXPECT_GE(keys.size(), 60u);
  EXPECT_GE(checked, 50);
}
