// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <cstdio>
#include <map>
#include <set>

#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "endo_guidance/pipeline/pipeline.h"
#include "endo_guidance/sim/scene_renderer.h"

using namespace endo_guidance::perception;
using namespace endo_guidance::geometry;
using namespace endo_guidance::sim;
using namespace endo_guidance::pipeline;

TEST(Pipeline, BadFramesAreReportedAndSkipped) {
  SyntheticSceneOptions so;
  Pipeline p(so.K, {640, 480});
  EXPECT_FALSE(p.process(cv::Mat()).error.empty());
  EXPECT_FALSE(p.process(cv::Mat(480, 640, CV_8U)).error.empty());
  auto const wrong = p.process(cv::Mat(240, 320, CV_8UC3, cv::Scalar(1, 2, 3)));
  EXPECT_NE(wrong.error.find("differs"), std::string::npos);
  EXPECT_TRUE(wrong.instruments.empty());
  EXPECT_TRUE(p.process(cv::Mat(480, 640, CV_8UC3, cv::Scalar(60, 70, 170))).error.empty());
}

// Trocars recovered from rendered video; with a gauze-like blob in view, nothing but the
// instruments is reported once the trocars are known; nothing non-finite is ever output.
TEST(Pipeline, TrocarsFromRenderedVideoAndNoGauze) {
  SyntheticSceneOptions so;
  SyntheticScene scene(defaultInstruments(), so);
  RenderOptions ro;
  ro.gauze = true;
  SceneRenderer renderer(so.width, so.height, ro);
  Pipeline p(so.K, {so.width, so.height});
  int late_false = 0;
  PipelineOutput out;
  for (int k = 0; k < 220; ++k) {
    auto const views = scene.frame(k);
    out = p.process(renderer.render(views, k));
    ASSERT_TRUE(out.error.empty());
    for (auto const& o : out.instruments) {
      EXPECT_TRUE(o.pose.axis.direction().allFinite() && o.pose.axis.moment().allFinite() && o.pose.covariance.allFinite());
      if (k < 120) continue;
      bool ok = false;
      for (auto const& v : views) {
        Eigen::Vector3d ta = v.truth.lines[0] - v.truth.lines[1];
        ta /= ta.head<2>().norm();
        Eigen::Vector2d const m = 0.5 * (o.contour.entry_px + o.contour.tip_px);
        ok |= 0.5 * (std::abs(ta.dot(Eigen::Vector3d(o.contour.entry_px.x(), o.contour.entry_px.y(), 1))) +
                     std::abs(ta.dot(Eigen::Vector3d(m.x(), m.y(), 1)))) < 12.0;
      }
      late_false += !ok;
    }
    for (auto const& q : out.insertion_points) EXPECT_TRUE(q.estimate.position.allFinite() && q.image_point.allFinite());
  }
  ASSERT_EQ(out.insertion_points.size(), 3u);
  for (std::size_t i = 0; i < scene.size(); ++i) {
    double best = 1e9;
    for (auto const& q : out.insertion_points) best = std::min(best, (q.estimate.position - scene.meanTrocar(static_cast<int>(i))).norm());
    std::printf("[ rendered, gauze, 220 frames ] trocar %zu error %.2f mm\n", i, best * 1e3);
    EXPECT_LT(best, 0.0015);
  }
  EXPECT_EQ(late_false, 0);
}

// reset(): after a video (insertion points found, seed levels and tracks remembered) the next
// frame is processed exactly as by a new Pipeline, and no insertion point is left; without it the
// same frame comes out otherwise (the seed search focused by the trocars, attachments, track ids).
// A distorted lens (plumb_bob): the frames are segmented as they are and each contour refitted to
// its rectified edge points (pointRectifier()); the contours are then the straight lines of the
// rectified camera, which the same frames without the rectifier miss.
TEST(Pipeline, DistortedFramesGiveRectifiedContours) {
  SyntheticSceneOptions so;
  SyntheticScene scene(defaultInstruments(), so);
  SceneRenderer renderer(so.width, so.height, RenderOptions{});
  cv::Matx33d const K(so.K(0, 0), 0, so.K(0, 2), 0, so.K(1, 1), so.K(1, 2), 0, 0, 1);
  std::vector<double> const D{-0.2, 0.05, 0.0, 0.0, 0.0};
  std::vector<cv::Point2f> grid, ideal;  // for each distorted pixel, where it comes from in the ideal image
  for (int v = 0; v < so.height; ++v)
    for (int u = 0; u < so.width; ++u) grid.emplace_back(static_cast<float>(u), static_cast<float>(v));
  cv::undistortPoints(grid, ideal, K, D, cv::noArray(), K, cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 30, 1e-6));
  cv::Mat const map(so.height, so.width, CV_32FC2, ideal.data());
  Pipeline rectified(so.K, {so.width, so.height}, {}, pointRectifier(K, cv::Mat(D).reshape(1, 1), cv::Matx33d::eye(), K, {so.width, so.height}));
  Pipeline raw(so.K, {so.width, so.height});
  auto nearestTruthPx = [](ApparentContour const& c, std::vector<SyntheticView> const& views) {
    double best = 1e9;
    for (auto const& v : views) {
      double e = 0.0;
      for (int s = 0; s < 2; ++s)
        for (auto const& q : {v.truth.entry_px, v.truth.tip_px})
          e = std::max(e, std::abs(c.lines[s].dot(footOnLine(v.truth.lines[s], q).homogeneous())));
      best = std::min(best, e);
    }
    return best;
  };
  int n[2] = {0, 0}, within[2] = {0, 0};
  for (int k = 0; k < 40; ++k) {
    auto const views = scene.frame(k);
    cv::Mat distorted;
    cv::remap(renderer.render(views, k), distorted, map, cv::noArray(), cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar(0, 0, 0));
    int i = 0;
    for (Pipeline* p : {&rectified, &raw}) {
      PipelineOutput const out = p->process(distorted);
      ASSERT_TRUE(out.error.empty());
      for (auto const& o : out.instruments) ++n[i], within[i] += nearestTruthPx(o.contour, views) < 1.5;
      ++i;
    }
  }
  std::printf("[ distorted ] rectified: %d of %d contours within 1.5 px of the rectified truth; without the rectifier %d of %d\n",
              within[0], n[0], within[1], n[1]);
  EXPECT_GT(n[0], 40);
  EXPECT_GE(within[0], n[0] * 9 / 10);
  EXPECT_LT(within[1], n[1] * 7 / 10);
}

TEST(Pipeline, ResetForgetsEveryFrame) {
  SyntheticSceneOptions so;
  SyntheticScene scene(defaultInstruments(), so);
  SceneRenderer renderer(so.width, so.height, RenderOptions{});
  Pipeline p(so.K, {so.width, so.height});
  // Frames 0-79, then 200 (a jump: the shafts there get new track ids), then the still is 201
  // (the segmentation's memory of 200 applies to it).
  for (int k = 0; k < 80; ++k) ASSERT_TRUE(p.process(renderer.render(scene.frame(k), k)).error.empty());
  ASSERT_TRUE(p.process(renderer.render(scene.frame(200), 200)).error.empty());
  cv::Mat const still = renderer.render(scene.frame(201), 201);
  Pipeline carried = p;
  PipelineOutput const with_memory = carried.process(still);
  ASSERT_FALSE(with_memory.insertion_points.empty());
  p.reset();
  PipelineOutput const after = p.process(still);
  PipelineOutput const fresh = Pipeline(so.K, {so.width, so.height}).process(still);
  EXPECT_TRUE(after.insertion_points.empty());
  ASSERT_EQ(after.instruments.size(), fresh.instruments.size());
  ASSERT_GE(after.instruments.size(), 2u);
  for (std::size_t i = 0; i < after.instruments.size(); ++i) {
    InstrumentObservation const &a = after.instruments[i], &b = fresh.instruments[i];
    EXPECT_EQ(a.contour.lines, b.contour.lines) << i;
    EXPECT_EQ(a.contour.tip_px, b.contour.tip_px) << i;
    EXPECT_EQ(a.track, b.track) << i;
    EXPECT_EQ(a.insertion_point, b.insertion_point) << i;
    EXPECT_EQ(a.pose.axis.direction(), b.pose.axis.direction()) << i;
  }
  // The segmentation's own memory forgotten too: the same regions grown, at the same levels.
  ASSERT_EQ(after.segmentation.regions.size(), fresh.segmentation.regions.size());
  for (std::size_t i = 0; i < after.segmentation.regions.size(); ++i) {
    EXPECT_EQ(after.segmentation.regions[i].threshold, fresh.segmentation.regions[i].threshold) << i;
    EXPECT_EQ(after.segmentation.regions[i].area, fresh.segmentation.regions[i].area) << i;
  }
  EXPECT_EQ(after.segmentation.strip_searches, fresh.segmentation.strip_searches);
  bool differs = with_memory.instruments.size() != fresh.instruments.size() ||
                 with_memory.segmentation.regions.size() != fresh.segmentation.regions.size();
  for (std::size_t i = 0; !differs && i < fresh.instruments.size(); ++i)
    differs = with_memory.instruments[i].insertion_point != fresh.instruments[i].insertion_point ||
              with_memory.instruments[i].track != fresh.instruments[i].track;
  EXPECT_TRUE(differs) << "the frame after a video should come out otherwise without reset()";
}

// Shaft identities: each synthetic instrument keeps one track id while it moves; a shaft that
// appears elsewhere gets a new id.
TEST(ShaftTracking, IdsFollowTheInstruments) {
  SyntheticScene scene(defaultInstruments());
  ShaftTracker tracker;
  std::map<int, int> id_of;  // instrument -> track id
  int switches = 0;
  for (int k = 0; k < 100; ++k) {
    auto const views = scene.frame(k);
    std::vector<ApparentContour> c;
    for (auto const& v : views) c.push_back(v.truth);
    tracker.assign(c);
    std::set<int> ids;
    for (std::size_t i = 0; i < views.size(); ++i) {
      ids.insert(c[i].track_id);
      auto const it = id_of.find(views[i].instrument);
      if (it != id_of.end() && it->second != c[i].track_id) ++switches;
      id_of[views[i].instrument] = c[i].track_id;
    }
    EXPECT_EQ(ids.size(), views.size());  // distinct shafts, distinct ids
  }
  EXPECT_EQ(switches, 0);
  EXPECT_GE(id_of.size(), 2u);
  // A shaft far from every previous one starts a new track.
  std::vector<ApparentContour> far{scene.frame(100).front().truth};
  int const before = far.front().track_id;
  far.front().lines = {*lineThrough({600, 0}, {600, 400}), *lineThrough({620, 400}, {620, 0})};
  far.front().entry_px = {610, 0};
  far.front().tip_px = {610, 400};
  tracker.reset();
  tracker.assign(far);
  EXPECT_NE(far.front().track_id, before);
}
