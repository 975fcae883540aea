// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// Bag format 2.0 (wiki.ros.org/Bags/Format/2.0): records of <header_len><header><data_len><data>,
// a header being fields <field_len><name>=<value>. Chunks (op 5) hold message and connection
// records, compressed or not; each chunk is followed by index data records (op 4) giving each
// message's offset in the uncompressed chunk; the bag header (op 3) gives where the index section
// starts, whose chunk info records (op 6) give each chunk's position.
#include "bag_structure.h"

#include <bzlib.h>
#include <roslz4/lz4s.h>

#include <algorithm>
#include <cstdint>
#include <cstdio>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <vector>

namespace endo_guidance::tools {

namespace {

using Bytes = std::vector<unsigned char>;

// Larger uncompressed chunks are refused before they are allocated: rosbag closes a chunk past
// 768 kB, so one holds at most one message more than that.
constexpr std::uint32_t kMaxChunkSize = 1u << 30;

std::uint32_t u32(unsigned char const* p) {
  return std::uint32_t(p[0]) | std::uint32_t(p[1]) << 8 | std::uint32_t(p[2]) << 16 | std::uint32_t(p[3]) << 24;
}
std::uint64_t u64(unsigned char const* p) { return u32(p) | std::uint64_t(u32(p + 4)) << 32; }

// A record header's fields, each within it; nullopt when one runs past it or lacks its '='.
std::optional<std::map<std::string, std::string>> headerFields(unsigned char const* h, std::uint32_t n) {
  std::map<std::string, std::string> fields;
  for (std::uint32_t i = 0; i < n;) {
    if (n - i < 4) return std::nullopt;
    std::uint32_t const len = u32(h + i);
    i += 4;
    if (len > n - i) return std::nullopt;
    std::string const field(reinterpret_cast<char const*>(h + i), len);
    auto const eq = field.find('=');
    if (eq == std::string::npos) return std::nullopt;
    fields[field.substr(0, eq)] = field.substr(eq + 1);
    i += len;
  }
  return fields;
}

// The op of a header, -1 when it has none (rosbag refuses those itself).
int opOf(std::map<std::string, std::string> const& fields) {
  auto const it = fields.find("op");
  return it != fields.end() && it->second.size() == 1 ? static_cast<unsigned char>(it->second[0]) : -1;
}

// A fixed-size integer field: nullopt when absent or of another size.
std::optional<std::uint64_t> intField(std::map<std::string, std::string> const& fields, char const* name, std::size_t size) {
  auto const it = fields.find(name);
  if (it == fields.end() || it->second.size() != size) return std::nullopt;
  auto const* p = reinterpret_cast<unsigned char const*>(it->second.data());
  return size == 8 ? u64(p) : u32(p);
}

// The offsets of the records of a chunk's uncompressed data, each record within it; nullopt when
// one is not.
std::optional<std::vector<std::uint32_t>> chunkRecords(Bytes const& b) {
  std::vector<std::uint32_t> starts;
  for (std::size_t i = 0; i < b.size();) {
    starts.push_back(static_cast<std::uint32_t>(i));
    if (b.size() - i < 4) return std::nullopt;
    std::uint32_t const hl = u32(&b[i]);
    i += 4;
    if (hl > b.size() - i || !headerFields(&b[i], hl)) return std::nullopt;
    i += hl;
    if (b.size() - i < 4) return std::nullopt;
    std::uint32_t const dl = u32(&b[i]);
    i += 4;
    if (dl > b.size() - i) return std::nullopt;
    i += dl;
  }
  return starts;
}

// A chunk's data uncompressed to exactly `size` bytes into `out` (an uncompressed chunk's is
// swapped in, not copied); "" or why not.
std::string uncompress(std::string const& compression, Bytes& data, std::uint32_t size, Bytes* out) {
  if (compression == "none") {
    if (size != data.size()) return "an uncompressed chunk's size is not its data's";
    out->swap(data);
    return "";
  }
  if (compression != "bz2" && compression != "lz4") return "unknown chunk compression '" + compression + "'";
  if (size > kMaxChunkSize) return "a chunk larger than 1 GiB";
  out->resize(size);
  unsigned int n = size;
  auto* in = const_cast<char*>(reinterpret_cast<char const*>(data.data()));
  auto* o = reinterpret_cast<char*>(out->data());
  bool const ok = compression == "bz2"
                      ? BZ2_bzBuffToBuffDecompress(o, &n, in, static_cast<unsigned int>(data.size()), 0, 0) == BZ_OK
                      : roslz4_buffToBuffDecompress(in, static_cast<unsigned int>(data.size()), o, &n) == ROSLZ4_OK;
  if (!ok || n != size) return "a " + compression + " chunk does not uncompress to its size";
  return "";
}

}  // namespace

std::string bagStructureError(std::string const& path) {
  std::FILE* f = std::fopen(path.c_str(), "rb");
  if (!f) return "cannot open";
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> closer(f, std::fclose);
  char magic[13];
  if (std::fread(magic, 1, 13, f) != 13 || std::string(magic, 13) != "#ROSBAG V2.0\n") return "not a version 2.0 bag";
  std::fseek(f, 0, SEEK_END);
  long const size = std::ftell(f);

  std::set<std::uint64_t> records, chunks;  // the file's record positions; the chunks' among them
  std::optional<std::vector<std::uint32_t>> last_chunk;  // record offsets in the last chunk read
  std::vector<std::uint64_t> chunk_positions;            // given by the chunk info records
  std::optional<std::uint64_t> index_pos;
  Bytes header, data, chunk;
  for (long pos = 13; pos < size;) {
    records.insert(static_cast<std::uint64_t>(pos));
    unsigned char len[4];
    std::fseek(f, pos, SEEK_SET);
    if (size - pos < 4 || std::fread(len, 1, 4, f) != 4) return "truncated record";
    std::uint32_t const hl = u32(len);
    if (hl > static_cast<std::uint64_t>(size - pos - 4)) return "a record header runs past the end of the file";
    header.resize(hl);
    if (std::fread(header.data(), 1, hl, f) != hl) return "truncated record header";
    auto const fields = headerFields(header.data(), hl);
    if (!fields) return "corrupt record header";
    if (std::fread(len, 1, 4, f) != 4) return "truncated record";
    std::uint32_t const dl = u32(len);
    long const at = pos + 8 + static_cast<long>(hl);
    if (dl > static_cast<std::uint64_t>(size - at)) return "a record's data runs past the end of the file";
    int const op = opOf(*fields);
    if (op == 0x04 || op == 0x05 || op == 0x06) {  // (the bag header's data is padding)
      data.resize(dl);
      if (std::fread(data.data(), 1, dl, f) != dl) return "truncated record data";
    }
    if (op == 0x03) {  // the bag header
      index_pos = intField(*fields, "index_pos", 8);
      if (!index_pos) return "the bag header has no index position";
    } else if (op == 0x05) {  // a chunk
      auto const compression = fields->find("compression");
      auto const chunk_size = intField(*fields, "size", 4);
      if (compression == fields->end() || !chunk_size) return "a chunk header lacks its compression or size";
      if (std::string const why = uncompress(compression->second, data, static_cast<std::uint32_t>(*chunk_size), &chunk); !why.empty()) return why;
      last_chunk = chunkRecords(chunk);
      if (!last_chunk) return "corrupt chunk";
      chunks.insert(static_cast<std::uint64_t>(pos));
    } else if (op == 0x04) {  // the index of the chunk before it: (time 8 bytes, offset 4) each
      auto const count = intField(*fields, "count", 4);
      if (!count || intField(*fields, "ver", 4) != 1u || dl != *count * 12) return "corrupt index data record";
      if (!last_chunk) return "an index data record before any chunk";
      for (std::uint64_t k = 0; k < *count; ++k)
        if (!std::binary_search(last_chunk->begin(), last_chunk->end(), u32(&data[k * 12 + 8]))) return "an index entry points between a chunk's records";
    } else if (op == 0x06) {  // chunk info: (connection 4 bytes, count 4) each
      auto const chunk_pos = intField(*fields, "chunk_pos", 8);
      auto const count = intField(*fields, "count", 4);
      if (!chunk_pos || !count || dl != *count * 8) return "corrupt chunk info record";
      chunk_positions.push_back(*chunk_pos);
    }
    pos = at + static_cast<long>(dl);
  }
  if (index_pos && *index_pos != 0 && !records.count(*index_pos)) return "the index position is not a record's";
  for (std::uint64_t const p : chunk_positions)
    if (!chunks.count(p)) return "a chunk info record points to no chunk";
  return "";
}

}  // namespace endo_guidance::tools
