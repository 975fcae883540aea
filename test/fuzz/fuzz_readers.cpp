// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// The offline program's readers (src/tools/frame_sources) on truncated or corrupted files: an
// image (PNG, JPEG), a video (AVI, MP4, MKV) or a bag, chosen by the first byte. A file that
// cannot be opened is refused with std::runtime_error; every frame read is either an 8-bit BGR
// image or an error, never both, never neither; nothing else escapes.
#include <unistd.h>

#include <cstdio>
#include <stdexcept>
#include <string>

#include "fuzz_input.h"
#include "frame_sources.h"

using endo_guidance::fuzz::fail;
namespace tools = endo_guidance::tools;

extern "C" int LLVMFuzzerTestOneInput(std::uint8_t const* data, std::size_t size) {
  if (size < 1) return 0;
  static char const* const kinds[] = {".png", ".jpg", ".avi", ".mp4", ".mkv", ".bag"};
  int const kind = data[0] % 6;
  std::string const path = "/tmp/endo_guidance_fuzz_" + std::to_string(getpid()) + kinds[kind];
  if (std::FILE* f = std::fopen(path.c_str(), "wb")) {
    std::fwrite(data + 1, 1, size - 1, f);
    std::fclose(f);
  } else {
    fail("cannot write the temporary file");
  }
  try {
    auto source = kind < 2 ? tools::openImageFiles({path}, 25.0)
                  : kind < 5 ? tools::openVideo(path, 25.0)
                             : tools::openBag(path, "/endoscope/image_raw");
    tools::Frame frame;
    for (int k = 0; k < 64 && source->next(frame); ++k) {
      bool const image = !frame.image.empty();
      if (image == !frame.error.empty()) fail("a frame must carry an image or an error, not both or neither");
      if (image && frame.image.type() != CV_8UC3) fail("a frame that is not 8-bit BGR");
    }
    if (auto const c = source->camera(); c && (!c->K.allFinite() || !(c->K(0, 0) > 0.0) || c->width <= 0)) fail("invalid camera accepted");
  } catch (std::runtime_error const&) {
  }
  std::remove(path.c_str());
  return 0;
}
