// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// A bag's structure checked before rosbag_storage reads it: rosbag_storage trusts the lengths
// and offsets it finds in the file and reads past its buffers when one is corrupt (found by
// test/fuzz/fuzz_readers.cpp), so a damaged recording must be refused here, with why.
#pragma once

#include <string>

namespace endo_guidance::tools {

/// "" when every record, chunk (uncompressed, bz2 or lz4), index entry and index position of
/// the version 2.0 bag at `path` lies where rosbag_storage will look for it; else why not.
std::string bagStructureError(std::string const& path);

}  // namespace endo_guidance::tools
