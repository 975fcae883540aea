// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
#include "frame_sources.h"

#include "bag_structure.h"

#include <cv_bridge/cv_bridge.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>

#include <cmath>
#include <memory>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/videoio.hpp>
#include <stdexcept>

namespace endo_guidance::tools {

namespace {

class ImageFiles : public Source {
 public:
  ImageFiles(std::vector<std::string> files, double fps) : files_(std::move(files)), fps_(fps) {}
  bool next(Frame& f) override {
    if (i_ >= files_.size()) return false;
    f = Frame{};
    f.source = files_[i_];
    f.stamp = static_cast<double>(i_) / fps_;
    f.image = cv::imread(files_[i_], cv::IMREAD_COLOR);
    if (f.image.empty()) f.error = "unreadable image";
    ++i_;
    return true;
  }
  long size() const override { return static_cast<long>(files_.size()); }

 private:
  std::vector<std::string> files_;
  double fps_;
  std::size_t i_ = 0;
};

class Video : public Source {
 public:
  // Frame k is stamped k / fps, the container's frame rate (`fallback_fps` when it has none).
  // Not CAP_PROP_POS_MSEC: with the FFMPEG backend on H264 (the EndoVis robotic videos) it is
  // the time of a frame two ahead after a read (0.08 s for frame 0 at 25 fps) and 0 after the
  // last one, so the stamps went back to 0 at the end.
  Video(std::string const& path, double fallback_fps) : path_(path), cap_(path) {
    if (!cap_.isOpened()) throw std::runtime_error("cannot open video '" + path + "'");
    double const f = cap_.get(cv::CAP_PROP_FPS);
    fps_ = std::isfinite(f) && f > 0.0 ? f : fallback_fps;
  }
  bool next(Frame& f) override {
    f = Frame{};
    if (!cap_.read(f.image)) return false;
    f.source = path_ + "#" + std::to_string(k_);
    f.stamp = static_cast<double>(k_) / fps_;
    ++k_;
    return true;
  }
  long size() const override { return static_cast<long>(cap_.get(cv::CAP_PROP_FRAME_COUNT)); }

 private:
  std::string path_;
  cv::VideoCapture cap_;
  double fps_ = 25.0;
  long k_ = 0;
};

class Bag : public Source {
 public:
  Bag(std::string const& path, std::string const& topic) : path_(path) {
    if (std::string const why = bagStructureError(path); !why.empty()) throw std::runtime_error("bag '" + path + "' refused: " + why);
    bag_.open(path, rosbag::bagmode::Read);
    view_ = std::make_unique<rosbag::View>(bag_, rosbag::TopicQuery(std::vector<std::string>{topic}));
    if (view_->size() == 0) throw std::runtime_error("bag '" + path + "' has no messages on '" + topic + "'");
    it_ = view_->begin();
    // camera_info: <namespace of the image topic>/camera_info
    std::string const info = topic.substr(0, topic.find_last_of('/')) + "/camera_info";
    rosbag::View iv(bag_, rosbag::TopicQuery(std::vector<std::string>{info}));
    for (auto const& m : iv) {
      auto const ci = m.instantiate<sensor_msgs::CameraInfo>();
      if (!ci) continue;
      io::CameraModel c;
      c.width = static_cast<int>(ci->width);
      c.height = static_cast<int>(ci->height);
      for (int i = 0; i < 9; ++i) c.K(i / 3, i % 3) = ci->K[i];
      for (int i = 0; i < 12; ++i) c.P(i / 4, i % 4) = ci->P[i];
      c.D = ci->D;
      c.distortion_model = ci->distortion_model;
      if (c.K.allFinite() && c.P.allFinite() && c.K(0, 0) > 0.0 && c.K(1, 1) > 0.0 && c.width > 0 && c.height > 0) camera_ = c;
      break;
    }
  }
  bool next(Frame& f) override {
    if (ended_ || it_ == view_->end()) return false;
    f = Frame{};
    f.source = path_ + "#" + std::to_string(k_++);
    try {
      rosbag::MessageInstance const& m = *it_;
      f.stamp = m.getTime().toSec();
      if (auto const img = m.instantiate<sensor_msgs::Image>()) {
        f.stamp = img->header.stamp.toSec();
        f.image = cv_bridge::toCvCopy(img, "bgr8")->image;
      } else if (auto const cimg = m.instantiate<sensor_msgs::CompressedImage>()) {
        f.stamp = cimg->header.stamp.toSec();
        f.image = cv::imdecode(cimg->data, cv::IMREAD_COLOR);
        if (f.image.empty()) f.error = "undecodable compressed image";
      } else {
        f.error = "message is neither sensor_msgs/Image nor CompressedImage";
      }
    } catch (std::exception const& e) {
      f.error = std::string("unreadable message: ") + e.what();
    }
    try {
      ++it_;
    } catch (std::exception const& e) {  // a corrupt chunk: what follows cannot be read
      ended_ = true;
      if (f.error.empty()) f.error = std::string("bag truncated or corrupt after this message: ") + e.what();
    }
    return true;
  }
  std::optional<io::CameraModel> camera() const override { return camera_; }
  long size() const override { return static_cast<long>(view_->size()); }

 private:
  std::string path_;
  rosbag::Bag bag_;
  std::unique_ptr<rosbag::View> view_;
  rosbag::View::iterator it_;
  bool ended_ = false;
  std::optional<io::CameraModel> camera_;
  long k_ = 0;
};

}  // namespace

std::unique_ptr<Source> openImageFiles(std::vector<std::string> files, double fps) {
  return std::make_unique<ImageFiles>(std::move(files), fps);
}
std::unique_ptr<Source> openVideo(std::string const& path, double fallback_fps) {
  return std::make_unique<Video>(path, fallback_fps);
}
std::unique_ptr<Source> openBag(std::string const& path, std::string const& topic) {
  return std::make_unique<Bag>(path, topic);
}

}  // namespace endo_guidance::tools
