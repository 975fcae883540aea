// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// Frames from a real endoscope, ROS-free: any source cv::VideoCapture opens (a V4L2/UVC device or
// frame grabber by index or path, a video file, a stream URL), with the requested size, rate and
// pixel format. Reconnects with exponential backoff when the device disappears, never returns
// the same frame twice, loops or stops at the end of a file. The EndoscopeCamera nodelet is a
// thin adapter over it (stamps, camera_info, image_transport, diagnostics).
#pragma once

#include <opencv2/core.hpp>
#include <opencv2/videoio.hpp>

#include <chrono>
#include <functional>
#include <memory>
#include <string>

namespace endo_guidance::io {

struct CaptureParams {
  /// "0" (device index), "/dev/video0", a video file, or a URL ("rtsp://...", "http://...").
  std::string source = "0";
  int width = 0, height = 0;  ///< requested frame size (0: the device's default)
  double fps = 0.0;           ///< requested device rate; a file's playback rate (0: the file's own)
  std::string pixel_format;   ///< FOURCC asked of a device ("MJPG", "YUYV"; "": its default)
  bool loop = false;          ///< a file: start again at its end (else stop)
  double reconnect_min_s = 0.5, reconnect_max_s = 8.0;  ///< backoff between attempts to (re)open
};

/// What kind of source a `source` string names.
enum class SourceKind { kDevice, kFile, kStream };
SourceKind sourceKind(std::string const& source);
/// Throws std::invalid_argument with the reason (empty source, bad FOURCC, negative size...).
void validate(CaptureParams const& p);

/// The delays between attempts to reopen a lost source: min, 2 min, 4 min, ... up to max;
/// back to min after a success.
class Backoff {
 public:
  Backoff(double min_s, double max_s) : min_(min_s), max_(max_s), next_(min_s) {}
  double next() {
    double const d = next_;
    next_ = std::min(max_, next_ * 2.0);
    return d;
  }
  void reset() { next_ = min_; }

 private:
  double min_, max_, next_;
};

/// The one thing read from a source; a seam so that tests can make a device disappear.
class FrameSource {
 public:
  virtual ~FrameSource() = default;
  virtual bool open(CaptureParams const& p, std::string& error) = 0;
  /// Blocks until the next frame has been grabbed (false: none: end of file or lost device);
  /// `retrieve` then decodes it. Split so that the caller stamps the frame at grab time.
  virtual bool grab() = 0;
  virtual bool retrieve(cv::Mat& frame) = 0;
  virtual double fps() const = 0;  ///< the source's own rate (0: unknown)
  virtual void close() = 0;
  virtual std::string describe() const = 0;  ///< what was opened (backend, size, format)
};
/// The cv::VideoCapture implementation.
std::unique_ptr<FrameSource> makeVideoCaptureSource();

class EndoscopeCapture {
 public:
  enum class Status {
    kFrame,         ///< a new frame
    kDuplicate,     ///< the source gave the previous frame's bytes again: dropped
    kUndecodable,   ///< a frame was grabbed but could not be decoded: dropped
    kEnded,         ///< a file ended and `loop` is off: no more frames
    kDisconnected,  ///< the source is not open; `next()` retries after the backoff delay
  };
  using Clock = std::chrono::steady_clock;

  explicit EndoscopeCapture(CaptureParams p, std::unique_ptr<FrameSource> source = makeVideoCaptureSource());

  /// One step: opens the source when it is due, grabs and decodes a frame. `on_grab` is called
  /// right after the grab, before decoding (the capture stamp). Never blocks longer than a
  /// device read; a frame is returned at most once.
  Status next(cv::Mat& frame, std::function<void()> const& on_grab = {});

  CaptureParams const& params() const { return p_; }
  SourceKind kind() const { return kind_; }
  bool connected() const { return open_; }
  /// Seconds until the next attempt to reopen (0 when connected).
  double retryIn() const;
  std::string const& lastError() const { return error_; }
  std::string describe() const { return source_->describe(); }
  /// The rate a file is played at (`fps`, else its own once opened, else 25); 0 for devices and
  /// streams (their reads pace).
  double playbackFps() const;
  std::size_t frames() const { return frames_; }
  std::size_t duplicates() const { return duplicates_; }
  std::size_t reconnects() const { return reconnects_; }
  std::size_t loops() const { return loops_; }
  std::size_t undecodable() const { return undecodable_; }

 private:
  bool tryOpen(bool reconnection);
  CaptureParams p_;
  SourceKind kind_;
  std::unique_ptr<FrameSource> source_;
  Backoff backoff_;
  bool open_ = false, ever_opened_ = false, ended_ = false;
  Clock::time_point retry_at_{};
  std::string error_;
  cv::Mat last_;
  double source_fps_ = 0.0;
  std::size_t frames_ = 0, duplicates_ = 0, undecodable_ = 0, reconnects_ = 0, loops_ = 0, frames_since_open_ = 0;
};

char const* toString(EndoscopeCapture::Status s);

}  // namespace endo_guidance::io
