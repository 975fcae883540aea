// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "endo_guidance/io/endoscope_capture.h"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <stdexcept>

namespace endo_guidance::io {

SourceKind sourceKind(std::string const& source) {
  if (!source.empty() && std::all_of(source.begin(), source.end(), [](unsigned char c) { return std::isdigit(c); }))
    return SourceKind::kDevice;
  if (source.rfind("/dev/", 0) == 0) return SourceKind::kDevice;
  if (source.find("://") != std::string::npos) return SourceKind::kStream;
  return SourceKind::kFile;
}

void validate(CaptureParams const& p) {
  if (p.source.empty()) throw std::invalid_argument("source is empty (a device index, /dev/videoN, a video file or a URL)");
  if (p.width < 0 || p.height < 0 || (p.width == 0) != (p.height == 0))
    throw std::invalid_argument("width and height must both be 0 (the device's default) or both positive");
  if (!(p.fps >= 0.0) || !std::isfinite(p.fps)) throw std::invalid_argument("fps must be >= 0 (0: the source's own rate)");
  if (!p.pixel_format.empty() && p.pixel_format.size() != 4)
    throw std::invalid_argument("pixel_format must be a four-character code (MJPG, YUYV, ...) or empty, not '" + p.pixel_format + "'");
  if (!(p.reconnect_min_s > 0.0) || !(p.reconnect_max_s >= p.reconnect_min_s) || !std::isfinite(p.reconnect_max_s))
    throw std::invalid_argument("reconnect delays must satisfy 0 < reconnect_min <= reconnect_max");
}

namespace {

class VideoCaptureSource : public FrameSource {
 public:
  bool open(CaptureParams const& p, std::string& error) override {
    close();
    SourceKind const kind = sourceKind(p.source);
    // A stream that stalls must not block for ever (FFmpeg honours these; others ignore them).
    std::vector<int> const timeouts{cv::CAP_PROP_OPEN_TIMEOUT_MSEC, 5000, cv::CAP_PROP_READ_TIMEOUT_MSEC, 5000};
    bool ok = false;
    if (kind == SourceKind::kDevice && std::isdigit(static_cast<unsigned char>(p.source[0])))
      ok = cap_.open(std::stoi(p.source), cv::CAP_V4L2);
    else if (kind == SourceKind::kDevice)
      ok = cap_.open(p.source, cv::CAP_V4L2);
    else if (kind == SourceKind::kFile && !std::filesystem::is_regular_file(p.source)) {
      error = "no such file '" + p.source + "'";
      return false;
    } else  // FFmpeg first (it decodes the recordings, and honours the timeouts), then any backend
      ok = cap_.open(p.source, cv::CAP_FFMPEG, timeouts) || cap_.open(p.source, cv::CAP_ANY, timeouts);
    if (!ok || !cap_.isOpened()) {
      error = "cannot open '" + p.source + "'";
      return false;
    }
    if (kind == SourceKind::kDevice) {
      // The format first: V4L2 drivers offer their sizes and rates per format.
      if (!p.pixel_format.empty())
        cap_.set(cv::CAP_PROP_FOURCC, cv::VideoWriter::fourcc(p.pixel_format[0], p.pixel_format[1], p.pixel_format[2], p.pixel_format[3]));
      if (p.width > 0) {
        cap_.set(cv::CAP_PROP_FRAME_WIDTH, p.width);
        cap_.set(cv::CAP_PROP_FRAME_HEIGHT, p.height);
      }
      if (p.fps > 0.0) cap_.set(cv::CAP_PROP_FPS, p.fps);
    }
    return true;
  }
  bool grab() override { return cap_.isOpened() && cap_.grab(); }
  bool retrieve(cv::Mat& frame) override { return cap_.retrieve(frame) && !frame.empty(); }
  double fps() const override {
    double const f = cap_.isOpened() ? cap_.get(cv::CAP_PROP_FPS) : 0.0;
    return std::isfinite(f) && f > 0.0 && f < 1000.0 ? f : 0.0;
  }
  void close() override {
    if (cap_.isOpened()) cap_.release();
  }
  std::string describe() const override {
    if (!cap_.isOpened()) return "not open";
    int const fcc = static_cast<int>(cap_.get(cv::CAP_PROP_FOURCC));
    char f[5] = {static_cast<char>(fcc & 255), static_cast<char>((fcc >> 8) & 255), static_cast<char>((fcc >> 16) & 255),
                 static_cast<char>((fcc >> 24) & 255), 0};
    for (char& c : f)
      if (c && !std::isprint(static_cast<unsigned char>(c))) c = '?';
    char b[160];
    std::snprintf(b, sizeof b, "%s, %dx%d, %.3g fps, format '%s'", cap_.getBackendName().c_str(),
                  static_cast<int>(cap_.get(cv::CAP_PROP_FRAME_WIDTH)), static_cast<int>(cap_.get(cv::CAP_PROP_FRAME_HEIGHT)),
                  cap_.get(cv::CAP_PROP_FPS), f);
    return b;
  }

 private:
  cv::VideoCapture cap_;
};

bool sameBytes(cv::Mat const& a, cv::Mat const& b) {
  if (a.empty() || b.empty() || a.size() != b.size() || a.type() != b.type()) return false;
  std::size_t const row = a.cols * a.elemSize();
  for (int r = 0; r < a.rows; ++r)
    if (std::memcmp(a.ptr(r), b.ptr(r), row) != 0) return false;
  return true;
}

}  // namespace

std::unique_ptr<FrameSource> makeVideoCaptureSource() { return std::make_unique<VideoCaptureSource>(); }

EndoscopeCapture::EndoscopeCapture(CaptureParams p, std::unique_ptr<FrameSource> source)
    : p_(std::move(p)), kind_(sourceKind(p_.source)), source_(std::move(source)), backoff_(p_.reconnect_min_s, p_.reconnect_max_s) {
  validate(p_);
  if (!source_) throw std::invalid_argument("EndoscopeCapture: no frame source");
}

bool EndoscopeCapture::tryOpen(bool reconnection) {
  std::string err;
  if (source_->open(p_, err)) {
    if (reconnection) ++reconnects_;
    open_ = ever_opened_ = true;
    source_fps_ = source_->fps();
    frames_since_open_ = 0;
    error_.clear();
    return true;
  }
  error_ = err;
  retry_at_ = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(backoff_.next()));
  return false;
}

double EndoscopeCapture::retryIn() const {
  if (open_ || ended_) return 0.0;
  return std::max(0.0, std::chrono::duration<double>(retry_at_ - Clock::now()).count());
}

double EndoscopeCapture::playbackFps() const {
  if (kind_ != SourceKind::kFile) return 0.0;
  if (p_.fps > 0.0) return p_.fps;
  return source_fps_ > 0.0 ? source_fps_ : 25.0;
}

EndoscopeCapture::Status EndoscopeCapture::next(cv::Mat& frame, std::function<void()> const& on_grab) {
  if (ended_) return Status::kEnded;
  if (!open_) {
    if (Clock::now() < retry_at_ || !tryOpen(ever_opened_)) return Status::kDisconnected;
  }
  if (!source_->grab()) {
    source_->close();
    open_ = false;
    if (kind_ == SourceKind::kFile && frames_since_open_ > 0) {
      if (!p_.loop) {
        ended_ = true;
        error_ = "end of file";
        return Status::kEnded;
      }
      ++loops_;
      last_.release();  // a looped file shows its frames again, by request
      return tryOpen(false) ? next(frame, on_grab) : Status::kDisconnected;
    }
    error_ = frames_since_open_ > 0 ? "source lost: no frame from '" + p_.source + "'" : "'" + p_.source + "' gives no frames";
    retry_at_ = Clock::now() + std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(backoff_.next()));
    return Status::kDisconnected;
  }
  if (on_grab) on_grab();
  cv::Mat img;
  if (!source_->retrieve(img)) {
    ++frames_since_open_;
    ++undecodable_;
    error_ = "a grabbed frame could not be decoded";
    return Status::kUndecodable;  // the next grab decides whether the source is lost
  }
  ++frames_since_open_;
  backoff_.reset();
  if (sameBytes(img, last_)) {
    ++duplicates_;
    return Status::kDuplicate;
  }
  img.copyTo(last_);  // a copy: a backend may reuse the buffer it decoded into
  frame = img;
  ++frames_;
  return Status::kFrame;
}

char const* toString(EndoscopeCapture::Status s) {
  switch (s) {
    case EndoscopeCapture::Status::kFrame: return "frame";
    case EndoscopeCapture::Status::kDuplicate: return "duplicate";
    case EndoscopeCapture::Status::kUndecodable: return "undecodable";
    case EndoscopeCapture::Status::kEnded: return "ended";
    case EndoscopeCapture::Status::kDisconnected: return "disconnected";
  }
  return "?";
}

}  // namespace endo_guidance::io
