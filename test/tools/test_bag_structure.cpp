// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The bag check (bag_structure.h) on bags written by rosbag_storage, uncompressed, bz2 and lz4,
// then damaged where rosbag_storage would read past its buffers: each is refused with why, and
// the sound ones are read to their last frame by the offline program's reader.
#include <gtest/gtest.h>
#include <rosbag/bag.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "bag_structure.h"
#include "frame_sources.h"

using endo_guidance::tools::bagStructureError;

namespace {

using Bytes = std::vector<unsigned char>;
constexpr int kFrames = 5;

std::string temporary(std::string const& name) { return "/tmp/endo_guidance_bag_" + std::to_string(getpid()) + "_" + name + ".bag"; }

// kFrames 8×6 images and their camera_info, in chunks of one message each (more index records).
std::string writeBag(std::string const& name, rosbag::compression::CompressionType compression) {
  std::string const path = temporary(name);
  rosbag::Bag bag(path, rosbag::bagmode::Write);
  bag.setCompression(compression);
  bag.setChunkThreshold(1);
  for (int k = 0; k < kFrames; ++k) {
    sensor_msgs::Image img;
    img.header.stamp = ros::Time(1.0 + 0.04 * k);
    img.header.frame_id = "endoscope_optical";
    img.width = 8;
    img.height = 6;
    img.encoding = "bgr8";
    img.step = 24;
    img.data.assign(24 * 6, static_cast<std::uint8_t>(40 * k));
    bag.write("/endoscope/image_raw", img.header.stamp, img);
    sensor_msgs::CameraInfo info;
    info.header = img.header;
    info.width = 8;
    info.height = 6;
    info.K = {100, 0, 4, 0, 100, 3, 0, 0, 1};
    info.P = {100, 0, 4, 0, 0, 100, 3, 0, 0, 0, 1, 0};
    bag.write("/endoscope/camera_info", img.header.stamp, info);
  }
  bag.close();
  return path;
}

Bytes read(std::string const& path) {
  std::ifstream in(path, std::ios::binary);
  return Bytes(std::istreambuf_iterator<char>(in), {});
}
std::string write(std::string const& name, Bytes const& b) {
  std::string const path = temporary(name);
  std::ofstream(path, std::ios::binary).write(reinterpret_cast<char const*>(b.data()), static_cast<std::streamsize>(b.size()));
  return path;
}
std::uint32_t u32(Bytes const& b, std::size_t i) { return b[i] | b[i + 1] << 8 | b[i + 2] << 16 | std::uint32_t(b[i + 3]) << 24; }
void put32(Bytes& b, std::size_t i, std::uint32_t v) {
  for (int k = 0; k < 4; ++k) b[i + k] = static_cast<unsigned char>(v >> (8 * k));
}

// A top-level record: its op, where its header's fields and its data start.
struct Record {
  int op = -1;
  std::size_t header = 0, data = 0;
  std::uint32_t data_len = 0;
};
std::vector<Record> records(Bytes const& b) {
  std::vector<Record> out;
  for (std::size_t pos = 13; pos + 4 <= b.size();) {
    Record r;
    std::uint32_t const hl = u32(b, pos);
    r.header = pos + 4;
    for (std::size_t i = r.header; i < r.header + hl; i += 4 + u32(b, i))
      if (u32(b, i) == 4 && std::string(b.begin() + i + 4, b.begin() + i + 7) == "op=") r.op = b[i + 7];
    r.data = pos + 8 + hl;
    r.data_len = u32(b, pos + 4 + hl);
    out.push_back(r);
    pos = r.data + r.data_len;
  }
  return out;
}
// Where the value of field `name` of a record's header starts.
std::size_t field(Bytes const& b, Record const& r, std::string const& name) {
  for (std::size_t i = r.header;; i += 4 + u32(b, i))
    if (std::string(b.begin() + i + 4, b.begin() + i + 4 + name.size() + 1) == name + "=") return i + 4 + name.size() + 1;
}
Record first(Bytes const& b, int op) {
  for (Record const& r : records(b))
    if (r.op == op) return r;
  ADD_FAILURE() << "no record with op " << op;
  return {};
}

class BagStructure : public ::testing::TestWithParam<rosbag::compression::CompressionType> {
 protected:
  void SetUp() override { sound = read(path = writeBag("sound", GetParam())); }
  void TearDown() override {
    std::remove(path.c_str());
    std::remove(temporary("damaged").c_str());
  }
  // The check's verdict on the sound bag changed by `damage`.
  std::string verdict(void (*damage)(Bytes&)) {
    Bytes b = sound;
    damage(b);
    return bagStructureError(write("damaged", b));
  }
  std::string path;
  Bytes sound;
};

}  // namespace

TEST_P(BagStructure, ASoundBagIsAcceptedAndReadToItsLastFrame) {
  EXPECT_EQ(bagStructureError(path), "");
  auto source = endo_guidance::tools::openBag(path, "/endoscope/image_raw");
  ASSERT_TRUE(source->camera().has_value());
  endo_guidance::tools::Frame frame;
  int frames = 0;
  while (source->next(frame)) {
    EXPECT_EQ(frame.error, "");
    ASSERT_EQ(frame.image.size(), cv::Size(8, 6));
    EXPECT_EQ(frame.image.at<cv::Vec3b>(2, 3)[0], 40 * frames);
    ++frames;
  }
  EXPECT_EQ(frames, kFrames);
}

TEST_P(BagStructure, AnIndexEntryOutsideItsChunkOrBetweenItsRecordsIsRefused) {
  // The offset of the first entry of the first index data record (time 8 bytes, then offset).
  EXPECT_EQ(verdict([](Bytes& b) { put32(b, first(b, 4).data + 8, 1u << 20); }), "an index entry points between a chunk's records");
  EXPECT_EQ(verdict([](Bytes& b) { put32(b, first(b, 4).data + 8, u32(b, first(b, 4).data + 8) + 2); }),
            "an index entry points between a chunk's records");
}

TEST_P(BagStructure, AChunkInfoOrIndexPositionThatIsNoRecordsIsRefused) {
  EXPECT_EQ(verdict([](Bytes& b) { b[field(b, first(b, 6), "chunk_pos")] += 3; }), "a chunk info record points to no chunk");
  EXPECT_EQ(verdict([](Bytes& b) { b[field(b, first(b, 3), "index_pos")] += 3; }), "the index position is not a record's");
}

TEST_P(BagStructure, AChunkWhoseDataIsNotItsStatedSizeIsRefused) {
  std::string const why = verdict([](Bytes& b) { ++b[field(b, first(b, 5), "size")]; });
  EXPECT_NE(why.find("size"), std::string::npos) << why;
}

TEST_P(BagStructure, ACorruptChunkOrATruncatedFileIsRefused) {
  // The first 4 bytes of the first chunk's data: its first record's header length when it is
  // not compressed, else the compressed stream's magic.
  std::string const why = verdict([](Bytes& b) { put32(b, first(b, 5).data, 0xfffffff0u); });
  EXPECT_EQ(why, GetParam() == rosbag::compression::Uncompressed ? "corrupt chunk" : GetParam() == rosbag::compression::BZ2
                                                                                      ? "a bz2 chunk does not uncompress to its size"
                                                                                      : "a lz4 chunk does not uncompress to its size");
  EXPECT_EQ(verdict([](Bytes& b) { b.resize(b.size() - 7); }), "a record's data runs past the end of the file");
}

INSTANTIATE_TEST_SUITE_P(Compressions, BagStructure,
                         ::testing::Values(rosbag::compression::Uncompressed, rosbag::compression::BZ2, rosbag::compression::LZ4));
