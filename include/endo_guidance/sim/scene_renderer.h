// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#pragma once

#include <cstdint>
#include <opencv2/core.hpp>
#include <vector>

#include "endo_guidance/sim/synthetic_scene.h"

namespace endo_guidance::sim {

struct RenderOptions {
  bool black_shafts = false;     ///< black insulated shafts instead of grey metal
  bool circular_fov = false;     ///< circular endoscope field of view with black surround
  bool gauze = false;            ///< a grey, gauze-like blob on the tissue (a distractor)
  bool membranes = true;         ///< whitish, low-chroma membranes on the tissue
  bool specular = true;          ///< specular highlights on tissue and shafts
  double noise_sigma = 0.0;      ///< additive Gaussian noise, grey levels
  int jpeg_quality = 0;          ///< 0: none; else JPEG round trip at this quality
  std::uint64_t seed = 3;
};

/// The rendering of the "hard" evaluation scene (endo_guidance_eval_synthetic --scene hard, with
/// 2 mm of breathing): a gauze blob, noise sigma 4, JPEG 80.
inline RenderOptions hardRenderOptions() {
  RenderOptions o;
  o.gauze = true;
  o.noise_sigma = 4.0;
  o.jpeg_quality = 80;
  return o;
}

/// Renders the synthetic scene (one renderer for the tests, the simulator and the demo bags):
/// textured red/yellow tissue, then each visible instrument far to near: a shaded cylinder
/// (Lambert + specular stripe across the shaft, exact anti-aliased silhouette from the true
/// apparent contour, so the ground-truth lines are the image's real edges) ending at the tip,
/// and two jaws beyond it. Optional circular field of view, gauze, noise and JPEG.
class SceneRenderer {
 public:
  SceneRenderer(int width, int height, RenderOptions const& options = {});
  /// BGR image of the given views (from SyntheticScene::frame), frame index k for animation.
  /// `labels` (optional): per pixel 0 background, 1 shaft, 2 jaws (CV_8U; a pixel is the nearest
  /// instrument's part covering at least half of it, inside the field of view): exact training labels.
  cv::Mat render(std::vector<SyntheticView> const& views, int k = 0, cv::Mat* labels = nullptr) const;
  /// The same into `out` (CV_8UC3 of the renderer's size: kept when it is, e.g. a header over a
  /// message's buffer), with `scratch` as the float working image: a stream reuses both, so no
  /// frame-sized block is allocated per frame.
  void render(std::vector<SyntheticView> const& views, int k, cv::Mat& out, cv::Mat& scratch, cv::Mat* labels = nullptr) const;
  /// The visible tip of view v in frame k as render() draws it: where its jaws end, on the image
  /// axis through the shaft's tip (jaw_end_px when the view has one).
  static Eigen::Vector2d visibleTip(SyntheticView const& v, int k);
  RenderOptions const& options() const { return options_; }
  /// Coverage of the field of view (CV_32F, 1 inside, 0 outside, vignetting included).
  cv::Mat const& fieldOfView() const { return fov_; }

 private:
  int width_, height_;
  RenderOptions options_;
  cv::Mat tissue_;  // CV_32FC3, BGR 0..255
  cv::Mat fov_;     // CV_32F coverage of the field of view
};

}  // namespace endo_guidance::sim
