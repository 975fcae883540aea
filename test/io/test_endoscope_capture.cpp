// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include <gtest/gtest.h>

#include <opencv2/imgproc.hpp>
#include <opencv2/videoio.hpp>

#include <deque>
#include <thread>

#include "endo_guidance/io/endoscope_capture.h"

namespace io = endo_guidance::io;
using Status = io::EndoscopeCapture::Status;

namespace {
// Frame k: its index written in its first pixel row (and the fill), so repeats can be told.
cv::Mat numbered(int k) {
  cv::Mat m(48, 64, CV_8UC3, cv::Scalar(k % 256, (k * 7) % 256, 40));
  m.at<cv::Vec3b>(0, 0) = cv::Vec3b(static_cast<uchar>(k & 255), static_cast<uchar>(k >> 8), 1);
  return m;
}
int indexOf(cv::Mat const& m) { return m.at<cv::Vec3b>(0, 0)[0] + 256 * m.at<cv::Vec3b>(0, 0)[1]; }

// A scripted device: each open() pops the next entry of `sessions` (-1: the open fails; n: n
// frames are served, then grab() fails as when the cable is pulled). `repeat` serves each
// frame twice (a grabber that re-sends its buffer).
struct FakeSource : io::FrameSource {
  std::deque<int> sessions;
  int served = 0, left = 0, next_index = 0, opens = 0;
  bool repeat = false, is_open = false, odd = false;
  bool open(io::CaptureParams const&, std::string& error) override {
    ++opens;
    int const n = sessions.empty() ? -1 : sessions.front();
    if (!sessions.empty()) sessions.pop_front();
    if (n < 0) {
      error = "no device";
      return false;
    }
    left = n;
    is_open = true;
    return true;
  }
  bool grab() override {
    if (!is_open || left == 0) return false;
    --left;
    return true;
  }
  bool retrieve(cv::Mat& f) override {
    f = numbered(next_index);
    if (!repeat || (odd = !odd) == false) ++next_index;
    return true;
  }
  double fps() const override { return 0.0; }
  void close() override { is_open = false; }
  std::string describe() const override { return "fake"; }
};

io::CaptureParams params(std::string source, double min_s = 0.01, double max_s = 0.04) {
  io::CaptureParams p;
  p.source = std::move(source);
  p.reconnect_min_s = min_s;
  p.reconnect_max_s = max_s;
  return p;
}
}  // namespace

TEST(EndoscopeCapture, SourceKinds) {
  EXPECT_EQ(io::sourceKind("0"), io::SourceKind::kDevice);
  EXPECT_EQ(io::sourceKind("/dev/video2"), io::SourceKind::kDevice);
  EXPECT_EQ(io::sourceKind("rtsp://10.0.0.2/endoscope"), io::SourceKind::kStream);
  EXPECT_EQ(io::sourceKind("/data/surgery.avi"), io::SourceKind::kFile);
  EXPECT_EQ(io::sourceKind("12a"), io::SourceKind::kFile);
}

TEST(EndoscopeCapture, BadParametersSaySo) {
  auto p = params("0");
  p.pixel_format = "MJPEG";
  EXPECT_THROW(io::validate(p), std::invalid_argument);
  p = params("");
  EXPECT_THROW(io::validate(p), std::invalid_argument);
  p = params("0");
  p.width = 640;  // height missing
  EXPECT_THROW(io::validate(p), std::invalid_argument);
  p = params("0", 1.0, 0.5);
  EXPECT_THROW(io::validate(p), std::invalid_argument);
  EXPECT_NO_THROW(io::validate(params("0")));
}

TEST(EndoscopeCapture, BackoffDoublesUpToItsMaximumAndResets) {
  io::Backoff b(0.5, 3.0);
  EXPECT_EQ(b.next(), 0.5);
  EXPECT_EQ(b.next(), 1.0);
  EXPECT_EQ(b.next(), 2.0);
  EXPECT_EQ(b.next(), 3.0);
  EXPECT_EQ(b.next(), 3.0);
  b.reset();
  EXPECT_EQ(b.next(), 0.5);
}

// The device is absent at start, serves 3 frames, disappears, fails twice, comes back: every
// frame arrives once and in order, the failures wait their backoff, one reconnection counted.
TEST(EndoscopeCapture, ReconnectsWhenTheDeviceComesBackAndNeverRepeatsAFrame) {
  auto src = std::make_unique<FakeSource>();
  FakeSource* fake = src.get();
  fake->sessions = {-1, 3, -1, -1, 4};
  io::EndoscopeCapture cap(params("/dev/video7"), std::move(src));
  std::vector<int> got;
  int grabs = 0;
  auto const t0 = std::chrono::steady_clock::now();
  for (int i = 0; i < 2000 && got.size() < 7; ++i) {
    cv::Mat f;
    Status const s = cap.next(f, [&] { ++grabs; });
    if (s == Status::kFrame) got.push_back(indexOf(f));
    if (s == Status::kDisconnected) {
      EXPECT_FALSE(cap.connected());
      EXPECT_FALSE(cap.lastError().empty());
      EXPECT_LE(cap.retryIn(), 0.04 + 1e-3);
      std::this_thread::sleep_for(std::chrono::milliseconds(2));
    }
  }
  double const waited = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  ASSERT_EQ(got, (std::vector<int>{0, 1, 2, 3, 4, 5, 6}));
  EXPECT_EQ(grabs, 7);
  EXPECT_EQ(cap.reconnects(), 1u);
  EXPECT_EQ(cap.frames(), 7u);
  EXPECT_EQ(fake->opens, 5);
  // Failed opens: 0.01 s at start; after the loss 0.01 (grab failed) + 0.02 + 0.04 s.
  EXPECT_GE(waited, 0.01 + 0.01 + 0.02 + 0.04 - 0.005);
  EXPECT_TRUE(cap.connected());
}

TEST(EndoscopeCapture, ARepeatedBufferIsDroppedNotPublished) {
  auto src = std::make_unique<FakeSource>();
  src->sessions = {6};
  src->repeat = true;
  io::EndoscopeCapture cap(params("0"), std::move(src));
  std::vector<int> got;
  for (int i = 0; i < 6; ++i) {
    cv::Mat f;
    if (cap.next(f) == Status::kFrame) got.push_back(indexOf(f));
  }
  EXPECT_EQ(got, (std::vector<int>{0, 1, 2}));
  EXPECT_EQ(cap.duplicates(), 3u);
}

TEST(EndoscopeCapture, AFileStopsAtItsEndOrLoops) {
  auto src = std::make_unique<FakeSource>();
  src->sessions = {3};
  io::EndoscopeCapture stop(params("surgery.avi"), std::move(src));
  cv::Mat f;
  for (int i = 0; i < 3; ++i) EXPECT_EQ(stop.next(f), Status::kFrame);
  EXPECT_EQ(stop.next(f), Status::kEnded);
  EXPECT_EQ(stop.next(f), Status::kEnded);
  EXPECT_EQ(stop.lastError(), "end of file");

  auto src2 = std::make_unique<FakeSource>();
  src2->sessions = {2, 2, 2};
  auto p = params("surgery.avi");
  p.loop = true;
  io::EndoscopeCapture loop(p, std::move(src2));
  int frames = 0;
  for (int i = 0; i < 6; ++i) frames += loop.next(f) == Status::kFrame;
  EXPECT_EQ(frames, 6);  // the end of one pass opens the next at once: no frame slot is lost
  EXPECT_EQ(loop.loops(), 2u);
  EXPECT_EQ(loop.reconnects(), 0u);
}

// The cv::VideoCapture source on a real file: every frame once, in order, then the end.
TEST(EndoscopeCapture, ReadsAVideoFileFrameByFrame) {
  std::string const path = testing::TempDir() + "endoscope_capture_test.avi";
  {
    cv::VideoWriter w(path, cv::VideoWriter::fourcc('M', 'J', 'P', 'G'), 30.0, cv::Size(64, 48));
    ASSERT_TRUE(w.isOpened());
    for (int k = 0; k < 12; ++k) {
      cv::Mat m(48, 64, CV_8UC3, cv::Scalar(0, 0, 0));
      cv::rectangle(m, cv::Rect(4 * k, 0, 4, 48), cv::Scalar(255, 255, 255), cv::FILLED);  // a bar at 4k px
      w.write(m);
    }
  }
  io::EndoscopeCapture cap(params(path));
  std::vector<int> bars;
  cv::Mat f;
  Status s;
  while ((s = cap.next(f)) == Status::kFrame) {
    cv::Mat grey;
    cv::cvtColor(f, grey, cv::COLOR_BGR2GRAY);
    cv::Point at;
    cv::minMaxLoc(grey.row(24), nullptr, nullptr, nullptr, &at);
    bars.push_back(at.x / 4);
  }
  EXPECT_EQ(s, Status::kEnded);
  std::vector<int> expected(12);
  for (int k = 0; k < 12; ++k) expected[k] = k;
  EXPECT_EQ(bars, expected);
  EXPECT_NEAR(cap.playbackFps(), 30.0, 1e-6);
  std::remove(path.c_str());
}

TEST(EndoscopeCapture, AMissingFileIsRetriedWithItsReason) {
  io::EndoscopeCapture cap(params("/nonexistent/endoscope.avi", 0.01, 0.02));
  cv::Mat f;
  EXPECT_EQ(cap.next(f), Status::kDisconnected);
  EXPECT_EQ(cap.lastError(), "no such file '/nonexistent/endoscope.avi'");
  EXPECT_GT(cap.retryIn(), 0.0);
}
