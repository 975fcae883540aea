// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
//
// Speed of the geometric core, reported (never asserted) as absolute times and as ratios to a
// reference operation measured in the same run: cv::cvtColor(BGR -> HSV) of a 640x480 frame.
// Run: build/devel/lib/endo_guidance/endo_guidance_bench   (or scripts/bench.sh)
#include <benchmark/benchmark.h>

#include <map>
#include <opencv2/imgproc.hpp>
#include <random>

#include "endo_guidance/geometry/constrained_axis.h"
#include "endo_guidance/geometry/cylinder_pose.h"
#include "endo_guidance/geometry/insertion_point.h"
#include "endo_guidance/geometry/insertion_point_tracker.h"
#include "cylinder_pose_conic.h"
#include "endo_guidance/sim/synthetic_scene.h"
#include "ratio_reporter.h"

using namespace endo_guidance::geometry;
using namespace endo_guidance::sim;
using endo_guidance::test::estimateCylinderPoseConic;

namespace {

std::vector<SyntheticView> const& views() {
  static std::vector<SyntheticView> v = [] {
    SyntheticSceneOptions so;
    so.line_noise_px = 0.5;
    SyntheticScene scene(defaultInstruments(), so);
    std::vector<SyntheticView> out;
    for (int k = 0; k < 400; ++k)
      for (auto const& x : scene.frame(k)) out.push_back(x);
    return out;
  }();
  return v;
}

std::vector<PluckerLine> const& axesOf(int instrument) {
  static std::map<int, std::vector<PluckerLine>> cache;
  auto& v = cache[instrument];
  if (v.empty())
    for (auto const& x : views())
      if (x.instrument == instrument) {
        auto const r = estimateCylinderPose(SyntheticSceneOptions{}.K, x.radius, x.measured);
        if (r.ok()) v.push_back(r.pose.axis);
      }
  return v;
}

void BM_Reference_HSV_640x480(benchmark::State& st) {
  cv::Mat bgr(480, 640, CV_8UC3), hsv;
  cv::randu(bgr, 0, 255);
  cv::setNumThreads(1);
  for (auto _ : st) {
    cv::cvtColor(bgr, hsv, cv::COLOR_BGR2HSV);
    benchmark::DoNotOptimize(hsv.data);
  }
}
BENCHMARK(BM_Reference_HSV_640x480);

void BM_CylinderPose(benchmark::State& st) {
  auto const& v = views();
  CylinderPoseOptions o;
  o.compute_covariance = st.range(0) != 0;
  std::size_t i = 0;
  Eigen::Matrix3d const K = SyntheticSceneOptions{}.K;
  for (auto _ : st) {
    auto const& x = v[i++ % v.size()];
    auto r = estimateCylinderPose(K, x.radius, x.measured, o);
    benchmark::DoNotOptimize(r);
  }
}
BENCHMARK(BM_CylinderPose)->Arg(0)->Arg(1)->ArgName("covariance");

// The measured axis fused with its (true, 1 mm uncertain) trocar: per attached shaft and frame
// once the trocar is located.
void BM_ConstrainedAxis(benchmark::State& st) {
  auto const& v = views();
  Eigen::Matrix3d const K = SyntheticSceneOptions{}.K;
  std::vector<std::pair<CylinderPose, Eigen::Vector3d>> in;
  for (std::size_t i = 0; i < 500 && i < v.size(); ++i) {
    auto const r = estimateCylinderPose(K, v[i].radius, v[i].measured);
    if (r.ok()) in.emplace_back(r.pose, v[i].trocar_c);
  }
  Eigen::Matrix3d const S = 1e-6 * Eigen::Matrix3d::Identity();
  std::size_t i = 0;
  for (auto _ : st) {
    auto const& [pose, trocar] = in[i++ % in.size()];
    auto f = constrainAxisToPoint(pose, trocar, S, 0.001);
    benchmark::DoNotOptimize(f);
  }
}
BENCHMARK(BM_ConstrainedAxis);

void BM_CylinderPoseConic(benchmark::State& st) {
  auto const& v = views();
  std::size_t i = 0;
  Eigen::Matrix3d const K = SyntheticSceneOptions{}.K;
  for (auto _ : st) {
    auto const& x = v[i++ % v.size()];
    auto r = estimateCylinderPoseConic(K, x.radius, x.measured.lines[0], x.measured.lines[1]);
    benchmark::DoNotOptimize(r);
  }
}
BENCHMARK(BM_CylinderPoseConic);

void BM_InsertionPointTrackerUpdate(benchmark::State& st) {
  auto const& a = axesOf(0);
  InsertionPointTracker t;
  for (auto const& x : a) t.update(x);  // warm (initialised)
  std::size_t i = 0;
  for (auto _ : st) {
    auto u = t.update(a[i++ % a.size()]);
    benchmark::DoNotOptimize(u);
  }
}
BENCHMARK(BM_InsertionPointTrackerUpdate);

void BM_InsertionPointSetUpdate3(benchmark::State& st) {
  std::vector<PluckerLine> all;
  for (int i = 0; i < 3; ++i) all.insert(all.end(), axesOf(i).begin(), axesOf(i).end());
  InsertionPointSet set;
  for (auto const& x : all) set.update(x);
  std::size_t i = 0;
  for (auto _ : st) benchmark::DoNotOptimize(set.update(all[i++ % all.size()]));
}
BENCHMARK(BM_InsertionPointSetUpdate3);

void BM_IntersectAxesBatch(benchmark::State& st) {
  auto a = axesOf(0);
  a.resize(std::min<std::size_t>(a.size(), static_cast<std::size_t>(st.range(0))));
  for (auto _ : st) benchmark::DoNotOptimize(intersectAxes(a));
}
BENCHMARK(BM_IntersectAxesBatch)->Arg(50)->Arg(300);

void BM_IntersectAxesRobust(benchmark::State& st) {
  auto a = axesOf(0);
  a.resize(std::min<std::size_t>(a.size(), static_cast<std::size_t>(st.range(0))));
  for (auto _ : st) benchmark::DoNotOptimize(intersectAxesRobust(a));
}
BENCHMARK(BM_IntersectAxesRobust)->Arg(50)->Arg(300);

}  // namespace

int main(int argc, char** argv) {
  endo_guidance::bench::RatioReporter rep("Ratio to one cv::cvtColor(BGR->HSV) of a 640x480 frame, same run:",
                                          [](std::string const&) { return std::string("BM_Reference_HSV_640x480"); });
  return endo_guidance::bench::runBenchmarks(argc, argv, rep);
}
