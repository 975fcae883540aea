// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
//
// Speed of the per-frame pipeline and of each segmentation stage, single thread, at 640x480,
// 720x576 and 1920x1080, each reported as a ratio to cv::cvtColor(BGR -> HSV) of the same
// frame measured in the same run (never asserted: machines are noisy).
// Run: scripts/bench.sh   (or build/devel/lib/endo_guidance/endo_guidance_bench_pipeline)
#include <benchmark/benchmark.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <map>
#include <string>
#include <opencv2/core/utility.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include "endo_guidance/perception/colour_feature.h"
#include "endo_guidance/perception/image_reduction.h"
#include "endo_guidance/perception/learned_shaft_detector.h"
#include "endo_guidance/perception/sigma_filter.h"
#include "endo_guidance/perception/strip_search.h"
#include "endo_guidance/pipeline/pipeline.h"
#include "endo_guidance/sim/scene_renderer.h"
#include "colour_params.h"
#include "hough_baseline.h"
#include "ratio_reporter.h"

using namespace endo_guidance::perception;
using namespace endo_guidance::geometry;
using namespace endo_guidance::sim;
using namespace endo_guidance::pipeline;

namespace {

struct Frames {
  std::vector<cv::Mat> images;
  Eigen::Matrix3d K;
};

// The default scene at the given size (K scaled from 640x480).
SyntheticSceneOptions sceneAt(int w, int h) {
  SyntheticSceneOptions so;
  double const s = w / 640.0;
  so.width = w;
  so.height = h;
  so.K << 500 * s, 0, (w - 1) / 2.0, 0, 500 * s, (h - 1) / 2.0, 0, 0, 1;
  return so;
}

// 48 rendered frames of the default scene at the given size.
Frames const& frames(int w, int h) {
  static std::map<int, Frames> cache;
  Frames& f = cache[w];
  if (f.images.empty()) {
    SyntheticSceneOptions const so = sceneAt(w, h);
    SyntheticScene scene(defaultInstruments(), so);
    SceneRenderer r(w, h, RenderOptions{});
    // Consecutive frames, as a video (the segmentation carries each shaft's level across frames).
    for (int k = 0; k < 48; ++k) f.images.push_back(r.render(scene.frame(k), k));
    f.K = so.K;
  }
  return f;
}

int const kSizes[3][2] = {{640, 480}, {720, 576}, {1920, 1080}};

// The rows the docs give as the colour method's name it (the default detector is the learned one).
using endo_guidance::test::colourPipelineParams;

void BM_HSV(benchmark::State& st) {
  auto const& f = frames(static_cast<int>(st.range(0)), static_cast<int>(st.range(1)));
  cv::Mat hsv;
  std::size_t i = 0;
  for (auto _ : st) {
    cv::cvtColor(f.images[i++ % f.images.size()], hsv, cv::COLOR_BGR2HSV);
    benchmark::DoNotOptimize(hsv.data);
  }
}

void BM_Pipeline(benchmark::State& st) {
  auto const& f = frames(static_cast<int>(st.range(0)), static_cast<int>(st.range(1)));
  Pipeline p(f.K, f.images[0].size(), colourPipelineParams());
  for (auto const& im : f.images) p.process(im);  // warm: insertion points, levels
  std::size_t i = 0;
  for (auto _ : st) {
    auto out = p.process(f.images[i++ % f.images.size()]);
    benchmark::DoNotOptimize(out);
  }
}

// The same, paired: every iteration converts the frame to HSV and runs the method on it
// (`process(frame)`: the pipeline, or the baseline), each timed apart, so that both see the same
// phase of a noisy machine; `ratio` is the sum of the method's times (`method_us` per frame) over
// the sum of the HSV times (the figure the README quotes). The ratios of separate benchmarks
// (above) moved by up to 40 % between runs here, the paired one by a few %.
template <class Process>
void pairedWithHSV(benchmark::State& st, Frames const& f, Process&& process) {
  cv::Mat hsv;
  double t_hsv = 0.0, t_pipe = 0.0;
  std::size_t i = 0;
  using Clock = std::chrono::steady_clock;
  auto us = [](Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double, std::micro>(b - a).count(); };
  for (auto _ : st) {
    // The frame's first reader fetches it from memory: the order alternates so neither gains.
    bool const hsv_first = (i % 2) == 0;
    cv::Mat const& im = f.images[i++ % f.images.size()];
    if (!hsv_first) {
      auto const t0 = Clock::now();
      process(im);
      t_pipe += us(t0, Clock::now());
    }
    auto const t1 = Clock::now();
    cv::cvtColor(im, hsv, cv::COLOR_BGR2HSV);
    benchmark::DoNotOptimize(hsv.data);
    t_hsv += us(t1, Clock::now());
    if (hsv_first) {
      auto const t2 = Clock::now();
      process(im);
      t_pipe += us(t2, Clock::now());
    }
  }
  double const n = static_cast<double>(st.iterations());
  st.counters["hsv_us"] = t_hsv / n;
  st.counters["method_us"] = t_pipe / n;  // the pipeline or the baseline
  st.counters["ratio"] = t_hsv > 0.0 ? t_pipe / t_hsv : 0.0;
}

void pipelinePairedWithHSV(benchmark::State& st, PipelineParams const& params) {
  auto const& f = frames(static_cast<int>(st.range(0)), static_cast<int>(st.range(1)));
  Pipeline p(f.K, f.images[0].size(), params);
  for (auto const& im : f.images) p.process(im);  // warm: insertion points, levels
  pairedWithHSV(st, f, [&](cv::Mat const& im) { benchmark::DoNotOptimize(p.process(im)); });
}

void BM_PipelinePairedWithHSV(benchmark::State& st) { pipelinePairedWithHSV(st, colourPipelineParams()); }

// The plain OpenCV baseline (Canny + Hough on chroma; src/tools/hough_baseline.h), for
// comparison: it finds shafts only, no pose or insertion points.
void BM_HoughBaselinePairedWithHSV(benchmark::State& st) {
  auto const& f = frames(static_cast<int>(st.range(0)), static_cast<int>(st.range(1)));
  pairedWithHSV(st, f, [](cv::Mat const& im) { benchmark::DoNotOptimize(endo_guidance::tools::detectShaftsHough(im)); });
}

// The same with contour tracking between detection frames (detect_every 4: a speed mode, not the
// default; see contour_tracking.h).
void BM_PipelineTrackingPairedWithHSV(benchmark::State& st) {
  PipelineParams p = colourPipelineParams();
  p.segmentation.tracking.detect_every = 4;
  pipelinePairedWithHSV(st, p);
}

void BM_Stage_Resize(benchmark::State& st) {
  auto const& f = frames(static_cast<int>(st.range(0)), static_cast<int>(st.range(1)));
  int const s = std::max(1, static_cast<int>(std::lround(f.images[0].cols / 320.0)));
  cv::Mat small;
  for (auto _ : st) reduceImage(f.images[0], s, small);
}

void BM_Stage_ColourFeature(benchmark::State& st) {
  auto const& f = frames(static_cast<int>(st.range(0)), static_cast<int>(st.range(1)));
  int const s = std::max(1, static_cast<int>(std::lround(f.images[0].cols / 320.0)));
  cv::Mat small, feat;
  reduceImage(f.images[0], s, small);
  ColourFeature const cf;
  for (auto _ : st) cf.compute(small, feat);
}

void BM_Stage_SigmaFilter(benchmark::State& st) {
  auto const& f = frames(static_cast<int>(st.range(0)), static_cast<int>(st.range(1)));
  int const s = std::max(1, static_cast<int>(std::lround(f.images[0].cols / 320.0)));
  cv::Mat small, feat, out;
  reduceImage(f.images[0], s, small);
  ColourFeature().compute(small, feat);
  for (auto _ : st) sigmaFilter(feat, out, 1, 10);
}

void BM_Stage_Segmentation(benchmark::State& st) {
  auto const& f = frames(static_cast<int>(st.range(0)), static_cast<int>(st.range(1)));
  InstrumentSegmenter seg(colourPipelineParams().segmentation);
  for (auto const& im : f.images) seg.process(im);
  std::size_t i = 0;
  for (auto _ : st) benchmark::DoNotOptimize(seg.process(f.images[i++ % f.images.size()]));
}

// The strip search from every seed of a frame (full search, as on a seed's first frame; a tracked
// shaft is searched only about its last sides), including the Sobel of the feature and its
// packing for the ray walks.
void BM_Stage_StripSearch(benchmark::State& st) {
  auto const& f = frames(static_cast<int>(st.range(0)), static_cast<int>(st.range(1)));
  int const s = std::max(1, static_cast<int>(std::lround(f.images[0].cols / 320.0)));
  cv::Mat small, feat, filt, gx, gy;
  reduceImage(f.images[0], s, small);
  ColourFeature().compute(small, feat);
  sigmaFilter(feat, filt, 1, 10);
  FieldOfView const fov = detectFieldOfView(small);
  std::vector<Seed> const seeds = findSeeds(filt, fov);
  for (auto _ : st) {
    cv::spatialGradient(filt, gx, gy, 3);
    RayField const field = packRayField(gx, gy, fov);  // once per frame, as the segmentation does
    for (auto const& sd : seeds) benchmark::DoNotOptimize(searchStrip(filt, field, fov, sd, 45, s, {}, {}));
  }
  st.counters["seeds"] = static_cast<double>(seeds.size());
}

// ------------------------------------------------------------------ real frames
// The rendered scene above is what the ratio target is measured on; real frames cost
// more (seeds that are refused, strip searches, regions that leak). The shared EndoVis data
// (ENDO_GUIDANCE_DATA, else the ../shared/data this program was built beside; skipped, saying
// so, when absent).
std::filesystem::path dataDir() {
  if (char const* e = std::getenv("ENDO_GUIDANCE_DATA")) return e;
#ifdef ENDO_GUIDANCE_SHARED_DATA
  return ENDO_GUIDANCE_SHARED_DATA;
#else
  return "../shared/data";
#endif
}

// The first `max_frames` frames of robotic Dataset n (720x576, H264), decoded once; K assumed
// (fx = fy = 700 px, as endo_guidance_eval_real: the sequences have no intrinsics).
Frames const& roboticFrames(int n, std::size_t max_frames) {
  static std::map<int, Frames> cache;
  Frames& f = cache[n];
  if (f.images.empty()) {
    cv::VideoCapture cap((dataDir() / "endovis15_robotic" / ("Dataset" + std::to_string(n)) / "Video.avi").string());
    cv::Mat im;
    while (f.images.size() < max_frames && cap.read(im)) f.images.push_back(im.clone());
    if (!f.images.empty()) f.K << 700, 0, (f.images[0].cols - 1) / 2.0, 0, 700, (f.images[0].rows - 1) / 2.0, 0, 0, 1;
  }
  return f;
}

// The in-vivo stills of both operations (640x480), sorted by name.
Frames const& invivoStills() {
  static Frames f;
  if (f.images.empty()) {
    std::vector<std::filesystem::path> files;
    for (char const* op : {"OP1", "OP2"}) {
      std::filesystem::path const raw = dataDir() / "endovis15_rigid_invivo" / op / "Raw";
      if (!std::filesystem::is_directory(raw)) continue;
      for (auto const& e : std::filesystem::directory_iterator(raw)) files.push_back(e.path());
    }
    std::sort(files.begin(), files.end());
    for (auto const& p : files) {
      cv::Mat const im = cv::imread(p.string(), cv::IMREAD_COLOR);
      if (!im.empty()) f.images.push_back(im);
    }
  }
  return f;
}

// A robotic sequence as a video: the pipeline sees its frames in order (from the first again
// after the last), paired with the HSV conversion of each (pairedWithHSV()).
void BM_RealVideoPairedWithHSV(benchmark::State& st) {
  auto const& f = roboticFrames(static_cast<int>(st.range(0)), 150);
  if (f.images.empty()) {
    st.SkipWithError(("real data absent: " + (dataDir() / "endovis15_robotic").string()).c_str());
    return;
  }
  Pipeline p(f.K, f.images[0].size(), colourPipelineParams());
  double strips = 0.0, full = 0.0, shafts = 0.0, calls = 0.0;
  pairedWithHSV(st, f, [&](cv::Mat const& im) {
    auto const out = p.process(im);
    strips += out.segmentation.strip_searches;
    full += out.segmentation.full_searches;
    shafts += static_cast<double>(out.instruments.size());
    calls += 1.0;
  });
  st.counters["frames"] = static_cast<double>(f.images.size());
  st.counters["strip_searches"] = strips / std::max(1.0, calls);  // per frame
  st.counters["full_searches"] = full / std::max(1.0, calls);     // seeds grown at every level, per frame
  st.counters["shafts"] = shafts / std::max(1.0, calls);          // reported per frame
}

// The in-vivo stills, each on its own (the segmentation's memory of the last frame forgotten:
// InstrumentSegmenter::reset()), paired with the HSV conversion of each.
void BM_RealStillsSegmentationPairedWithHSV(benchmark::State& st) {
  auto const& f = invivoStills();
  if (f.images.empty()) {
    st.SkipWithError(("real data absent: " + (dataDir() / "endovis15_rigid_invivo").string()).c_str());
    return;
  }
  InstrumentSegmenter seg(colourPipelineParams().segmentation);
  double strips = 0.0, calls = 0.0;
  pairedWithHSV(st, f, [&](cv::Mat const& im) {
    seg.reset();
    strips += seg.process(im).strip_searches;
    calls += 1.0;
  });
  st.counters["strip_searches"] = strips / std::max(1.0, calls);  // per still
  st.counters["frames"] = static_cast<double>(f.images.size());
}

// ------------------------------------------------------------------ learned detector
// The learned detector (models/shaft_net.yaml, or the model ENDO_GUIDANCE_BENCH_MODEL names, to
// weigh a candidate against it) with `threads` OpenCV threads (the HSV reference runs in the same
// pool). OpenCV's thread count is global: restored to 1 afterwards.
std::string benchModel() {
  char const* e = std::getenv("ENDO_GUIDANCE_BENCH_MODEL");
  return e && *e ? e : defaultShaftModel();
}

PipelineParams learnedParams(int threads, int detect_every) {
  PipelineParams pp;
  pp.segmentation.detector = SegmentationParams::Detector::kLearned;
  pp.segmentation.learned.model = benchModel();
  pp.segmentation.learned.threads = threads;
  pp.segmentation.tracking.detect_every = detect_every;
  return pp;
}

// The network alone (ShaftNet::probabilities()) on the robotic video's frames.
void BM_LearnedNetworkPairedWithHSV(benchmark::State& st) {
  auto const& f = roboticFrames(1, 150);
  if (f.images.empty()) {
    st.SkipWithError(("real data absent: " + (dataDir() / "endovis15_robotic").string()).c_str());
    return;
  }
  ShaftNet net(benchModel(), static_cast<int>(st.range(0)));
  pairedWithHSV(st, f, [&](cv::Mat const& im) { benchmark::DoNotOptimize(net.probabilities(im).shaft.data); });
  cv::setNumThreads(1);
}

// The whole pipeline with the learned detector on a robotic sequence as a video, the network
// every `detect_every` frames (contour tracking between).
void BM_LearnedRealVideoPairedWithHSV(benchmark::State& st) {
  auto const& f = roboticFrames(static_cast<int>(st.range(0)), 150);
  if (f.images.empty()) {
    st.SkipWithError(("real data absent: " + (dataDir() / "endovis15_robotic").string()).c_str());
    return;
  }
  Pipeline p(f.K, f.images[0].size(), learnedParams(static_cast<int>(st.range(1)), static_cast<int>(st.range(2))));
  double shafts = 0.0, tracked = 0.0, calls = 0.0;
  pairedWithHSV(st, f, [&](cv::Mat const& im) {
    auto const out = p.process(im);
    shafts += static_cast<double>(out.instruments.size());
    tracked += out.segmentation.tracked;
    calls += 1.0;
  });
  st.counters["shafts"] = shafts / std::max(1.0, calls);    // reported per frame
  st.counters["tracked"] = tracked / std::max(1.0, calls);  // fraction of frames without the network
  cv::setNumThreads(1);
}

// The in-vivo stills with the learned detector, each on its own (the network every still).
void BM_LearnedRealStillsPairedWithHSV(benchmark::State& st) {
  auto const& f = invivoStills();
  if (f.images.empty()) {
    st.SkipWithError(("real data absent: " + (dataDir() / "endovis15_rigid_invivo").string()).c_str());
    return;
  }
  InstrumentSegmenter seg(learnedParams(static_cast<int>(st.range(0)), 1).segmentation);
  pairedWithHSV(st, f, [&](cv::Mat const& im) {
    seg.reset();
    benchmark::DoNotOptimize(seg.process(im).contours.size());
  });
  cv::setNumThreads(1);
}

// The learned detector's stage after its network alone (shaftsOfProbability(): side pairs,
// contour fit, tips) on the stills, the network's probabilities and the reduced frame computed
// beforehand (640 x 480 at half scale, as the detector runs them).
void BM_LearnedLineStagePairedWithHSV(benchmark::State& st) {
  auto const& f = invivoStills();
  if (f.images.empty()) {
    st.SkipWithError(("real data absent: " + (dataDir() / "endovis15_rigid_invivo").string()).c_str());
    return;
  }
  struct Still {
    cv::Mat small;
    FieldOfView fov;
    ShaftProbabilities p;
  };
  static std::map<uchar const*, Still> stills;  // per image (its pixels' address)
  if (stills.empty()) {
    ShaftNet net(benchModel(), 1);
    for (cv::Mat const& im : f.images) {
      Still& s = stills[im.data];
      reduceImage(im, 2, s.small);
      s.fov = detectFieldOfView(s.small);
      ShaftProbabilities const q = net.probabilities(im);
      cv::resize(q.shaft, s.p.shaft, s.small.size(), 0, 0, cv::INTER_LINEAR);
      cv::resize(q.instrument, s.p.instrument, s.small.size(), 0, 0, cv::INTER_LINEAR);
    }
  }
  SegmentationParams const sp = learnedParams(1, 1).segmentation;
  std::vector<Eigen::Vector3d> const no_trocars;
  cv::Mat labels;
  double shafts = 0.0, calls = 0.0;
  pairedWithHSV(st, f, [&](cv::Mat const& im) {
    Still const& s = stills.at(im.data);
    DetectionFrame const frame{im, s.small, s.fov, static_cast<double>(cv::countNonZero(s.fov.mask)), 2, no_trocars, 1};
    shafts += static_cast<double>(shaftsOfProbability(frame, s.p, sp, labels).contours.size());
    calls += 1.0;
  });
  st.counters["shafts"] = shafts / std::max(1.0, calls);  // per still
}

// The simulator's cost per frame: rendering three instruments on textured tissue (its frame
// rate is bounded by 1 / this).
void BM_SimulatorRender(benchmark::State& st) {
  int const w = static_cast<int>(st.range(0)), h = static_cast<int>(st.range(1));
  SyntheticScene scene(defaultInstruments(), sceneAt(w, h));
  SceneRenderer r(w, h, RenderOptions{});
  int k = 0;
  for (auto _ : st) benchmark::DoNotOptimize(r.render(scene.frame(k), k).data), ++k;
}

void sizes(benchmark::internal::Benchmark* b) {
  for (auto const& s : kSizes) b->Args({s[0], s[1]});
  b->ArgNames({"w", "h"});
  b->Unit(benchmark::kMicrosecond);
}
BENCHMARK(BM_HSV)->Apply(sizes);
BENCHMARK(BM_Pipeline)->Apply(sizes);
BENCHMARK(BM_PipelinePairedWithHSV)->Apply(sizes);
BENCHMARK(BM_PipelineTrackingPairedWithHSV)->Apply(sizes);
BENCHMARK(BM_HoughBaselinePairedWithHSV)->Apply(sizes);
BENCHMARK(BM_Stage_Resize)->Apply(sizes);
BENCHMARK(BM_Stage_ColourFeature)->Apply(sizes);
BENCHMARK(BM_Stage_SigmaFilter)->Apply(sizes);
BENCHMARK(BM_Stage_Segmentation)->Apply(sizes);
BENCHMARK(BM_Stage_StripSearch)->Apply(sizes);
BENCHMARK(BM_SimulatorRender)->Apply(sizes);
BENCHMARK(BM_RealVideoPairedWithHSV)->Arg(1)->Arg(2)->ArgName("endovis_robotic_dataset")->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_RealStillsSegmentationPairedWithHSV)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_LearnedNetworkPairedWithHSV)->Arg(1)->Arg(2)->ArgName("threads")->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_LearnedRealVideoPairedWithHSV)
    ->ArgsProduct({{1, 2}, {1, 2}, {1, 4, 8}})
    ->ArgNames({"endovis_robotic_dataset", "threads", "detect_every"})
    ->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_LearnedLineStagePairedWithHSV)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_LearnedRealStillsPairedWithHSV)->Arg(1)->Arg(2)->ArgName("threads")->Unit(benchmark::kMicrosecond);

}  // namespace

int main(int argc, char** argv) {
  // Each result divided by BM_HSV at the same size.
  endo_guidance::bench::RatioReporter rep(
      "Ratio to one cv::cvtColor(BGR->HSV) of the same frame, same run (single thread):",
      [](std::string const& n) { return "BM_HSV" + n.substr(n.find('/')); });
  return endo_guidance::bench::runBenchmarks(argc, argv, rep);
}
