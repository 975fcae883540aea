// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The "compressed" image_transport (sensor_msgs/CompressedImage on <topic>/compressed, JPEG or
// PNG), wire-compatible with ROS' compressed_image_transport, which Debian does not package.
// Lets the Segmentation nodelet read compressed endoscope streams and bags (image_transport:=
// compressed) and the simulator publish them. Where compressed_image_transport is installed,
// build with -DENDO_GUIDANCE_COMPRESSED_TRANSPORT=OFF to use that one.
#include <cv_bridge/cv_bridge.h>
#include <image_transport/simple_publisher_plugin.h>
#include <image_transport/simple_subscriber_plugin.h>
#include <pluginlib/class_list_macros.hpp>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/image_encodings.h>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include <algorithm>

#include "endo_guidance/ros/transport_errors.h"

namespace endo_guidance {

class CompressedPublisher : public image_transport::SimplePublisherPlugin<sensor_msgs::CompressedImage> {
 public:
  std::string getTransportName() const override { return "compressed"; }

 protected:
  void advertiseImpl(ros::NodeHandle& nh, std::string const& base_topic, uint32_t queue_size,
                     image_transport::SubscriberStatusCallback const& connect_cb,
                     image_transport::SubscriberStatusCallback const& disconnect_cb, ros::VoidPtr const& tracked_object,
                     bool latch) override {
    ros::NodeHandle pnh(nh, getTopicToAdvertise(base_topic));
    pnh.param("format", format_, std::string("jpeg"));
    pnh.param("jpeg_quality", quality_, 95);
    SimplePublisherPlugin::advertiseImpl(nh, base_topic, queue_size, connect_cb, disconnect_cb, tracked_object, latch);
  }
  void publish(sensor_msgs::Image const& image, PublishFn const& publish_fn) const override {
    cv_bridge::CvImageConstPtr cv;
    try {
      namespace enc = sensor_msgs::image_encodings;
      cv = cv_bridge::toCvShare(image, nullptr, enc::isColor(image.encoding) ? enc::BGR8 : enc::MONO8);
    } catch (cv_bridge::Exception const& e) {
      ROS_ERROR_THROTTLE(2.0, "compressed transport: %s", e.what());
      return;
    }
    sensor_msgs::CompressedImage out;
    out.header = image.header;
    bool const png = format_ == "png";
    out.format = cv->encoding + "; " + (png ? "png" : "jpeg") + " compressed " + cv->encoding;
    std::vector<int> const params = png ? std::vector<int>{cv::IMWRITE_PNG_COMPRESSION, 3}
                                        : std::vector<int>{cv::IMWRITE_JPEG_QUALITY, quality_};
    if (!cv::imencode(png ? ".png" : ".jpg", cv->image, out.data, params)) {
      ROS_ERROR_THROTTLE(2.0, "compressed transport: encoding failed");
      return;
    }
    publish_fn(out);
  }

 private:
  std::string format_ = "jpeg";
  int quality_ = 95;
};

class CompressedSubscriber : public image_transport::SimpleSubscriberPlugin<sensor_msgs::CompressedImage> {
 public:
  std::string getTransportName() const override { return "compressed"; }

 protected:
  void internalCallback(sensor_msgs::CompressedImageConstPtr const& msg, Callback const& user_cb) override {
    if (std::string const why = undecodable(msg->data); !why.empty()) return lost(why);
    cv::Mat const img = cv::imdecode(cv::Mat(msg->data), cv::IMREAD_UNCHANGED);
    if (img.empty()) return lost("cannot decode a '" + msg->format + "' image");
    namespace enc = sensor_msgs::image_encodings;
    cv_bridge::CvImage out;
    out.header = msg->header;
    if (img.channels() == 1) {
      out.encoding = enc::MONO8;
      out.image = img;
    } else if (img.channels() == 3) {
      out.encoding = enc::BGR8;  // imdecode gives BGR whatever the format field says
      out.image = img;
      if (msg->format.rfind("rgb8", 0) == 0) cv::cvtColor(img, out.image, cv::COLOR_RGB2BGR);  // stored as RGB
    } else {
      out.encoding = enc::BGRA8;
      out.image = img;
    }
    user_cb(out.toImageMsg());
  }

 private:
  /// libjpeg decodes a truncated JPEG as a grey-filled image: refuse one without its end-of-image
  /// marker (FF D9, followed by at most a few bytes of padding).
  static std::string undecodable(std::vector<uint8_t> const& d) {
    if (d.size() < 4) return "empty or truncated image data";
    if (d[0] != 0xFF || d[1] != 0xD8) return {};  // not a JPEG: imdecode judges
    std::size_t const tail = std::min<std::size_t>(d.size() - 2, 16);
    for (std::size_t k = 0; k <= tail; ++k)
      if (d[d.size() - 2 - k] == 0xFF && d[d.size() - 1 - k] == 0xD9) return {};
    return "truncated JPEG (no end-of-image marker)";
  }
  void lost(std::string const& why) const {
    ROS_ERROR_THROTTLE(2.0, "compressed transport: %s on %s: frame skipped", why.c_str(), getTopic().c_str());
    ros_io::TransportErrors::instance().report(getTopic(), why);
  }
};

}  // namespace endo_guidance

PLUGINLIB_EXPORT_CLASS(endo_guidance::CompressedPublisher, image_transport::PublisherPlugin)
PLUGINLIB_EXPORT_CLASS(endo_guidance::CompressedSubscriber, image_transport::SubscriberPlugin)
