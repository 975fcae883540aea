// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The per-frame pipeline on arbitrary images: sizes 1x1 to 1920x1080, every depth and channel
// count (only 8-bit BGR is accepted, the rest must be refused with an error), content scaled up
// from a small picture in the input, a few frames in a row, parameter values the YAML
// validation accepts, and either detector. Every output must be finite.
#include <opencv2/imgproc.hpp>
#include <stdexcept>
#include <string>

#include "endo_guidance/io/yaml_config.h"
#include "endo_guidance/pipeline/pipeline.h"
#include "fuzz_input.h"

using namespace endo_guidance::perception;
using namespace endo_guidance::geometry;
using namespace endo_guidance::pipeline;
using endo_guidance::fuzz::fail;
using endo_guidance::fuzz::Input;

namespace {
// Parameters the nodes may be given, and ranges beyond what the shipped YAML uses.
struct Knob {
  char const* key;
  double lo, hi;
  bool integer;  // printed without decimals; a [0, 1] integer knob is a switch (false / true)
};
Knob const kKnobs[] = {{"radius", 0.0005, 0.02, false},
                       {"segmentation/processing_width", 32, 640, true},
                       {"segmentation/sigma_radius", 0, 8, true},
                       {"segmentation/sigma_delta", 0, 255, true},
                       {"segmentation/seed_threshold", 0, 255, true},
                       {"segmentation/max_regions", 1, 12, true},
                       {"segmentation/max_angle_deg", 0, 90, false},
                       {"segmentation/min_length_px", 0, 400, false},
                       {"segmentation/min_width_px", 0, 100, false},
                       {"segmentation/max_residual_px", 0, 20, false},
                       {"segmentation/detect_every", 0, 8, true},  // (0: the detector's own cadence)
                       {"segmentation/full_search_every", 1, 10, true},
                       {"segmentation/strip_search", 0, 1, true},
                       {"segmentation/crossing_seeds", 0, 1, true},
                       {"insertion_points/min_views", 1, 40, true},
                       {"insertion_points/max_points", 0, 6, true},
                       {"tracking/max_distance_px", 0, 200, false}};
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(std::uint8_t const* data, std::size_t size) {
  Input in(data, size);
  int const w = static_cast<int>(in.range(1, 1920)), h = static_cast<int>(in.range(1, 1080));
  int const depths[] = {CV_8U, CV_8S, CV_16U, CV_16S, CV_32F, CV_64F};
  int const type = CV_MAKETYPE(depths[in.range(0, 5)], static_cast<int>(in.range(1, 4)));
  bool const bgr = in.byte() >= 64;  // mostly the accepted type, so that the stages run
  int const frames = static_cast<int>(in.range(1, 3));
  // Parameters: a few knobs set; a set the validation refuses is not a run.
  PipelineParams params;
  for (int k = static_cast<int>(in.range(0, 4)); k > 0; --k) {
    Knob const& n = kKnobs[in.range(0, sizeof kKnobs / sizeof kKnobs[0] - 1)];
    double v = n.lo + (n.hi - n.lo) * (in.u32() / 4294967295.0);
    std::string const key = n.key;
    auto const slash = key.find('/');
    char buf[64];
    std::snprintf(buf, sizeof buf, n.integer ? "%.0f" : "%.9g", v);
    std::string const value = n.integer && n.hi == 1 ? (v > 0.5 ? "true" : "false") : buf;
    std::string const line =
        slash == std::string::npos ? key + ": " + value : key.substr(0, slash) + ": {" + key.substr(slash + 1) + ": " + value + "}";
    try {
      endo_guidance::io::parsePipelineYaml(line, params);
    } catch (std::runtime_error const&) {
      return 0;
    }
  }
  // The picture: up to 48x36 pixels from the input, scaled to w x h (nearest: edges stay sharp).
  int const pw = static_cast<int>(in.range(1, 48)), ph = static_cast<int>(in.range(1, 36));
  cv::Mat small(ph, pw, CV_8UC3);
  for (int i = 0; i < pw * ph * 3; ++i) small.data[i] = in.byte();
  cv::Mat image;
  cv::resize(small, image, cv::Size(w, h), 0, 0, in.byte() & 1 ? cv::INTER_NEAREST : cv::INTER_LINEAR);
  if (!bgr) image = cv::Mat(h, w, type, cv::Scalar::all(in.byte()));  // to be refused
  double const f = in.real(0.3, 3.0) * w;
  Eigen::Matrix3d K;
  K << f, 0, w / 2.0, 0, f, h / 2.0, 0, 0, 1;
  if (!K.allFinite() || !(f > 0.0)) return 0;  // the nodes refuse such a camera_info
  // The learned detector on a quarter of the inputs (read last: inputs that end before keep the colour one).
  if (in.byte() >= 192) params.segmentation.detector = SegmentationParams::Detector::kLearned;
  Pipeline pipeline(K, cv::Size(w, h), params);
  for (int k = 0; k < frames; ++k) {
    PipelineOutput const out = pipeline.process(image, 0.04 * k);
    if (image.type() != CV_8UC3) {
      if (out.error.empty()) fail("an image other than 8-bit BGR was accepted");
      continue;
    }
    for (auto const& o : out.instruments) {
      if (!o.pose.axis.direction().allFinite() || !o.pose.axis.moment().allFinite()) fail("axis not finite");
      for (auto const& l : o.contour.lines)
        if (!l.allFinite()) fail("contour line not finite");
      if (o.tip_c && !o.tip_c->allFinite()) fail("tip not finite");
    }
    for (auto const& p : out.insertion_points)
      if (p.estimate.ok() && !p.estimate.position.allFinite()) fail("insertion point not finite");
    if (k + 1 < frames) cv::GaussianBlur(image, image, cv::Size(3, 3), 0.0);  // the next frame differs a little
  }
  return 0;
}
