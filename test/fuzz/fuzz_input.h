// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// Reading a libFuzzer input as typed values; past the end, zeros.
#pragma once

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <cstdlib>
#include <cstdio>
#include <limits>

namespace endo_guidance::fuzz {

class Input {
 public:
  Input(std::uint8_t const* data, std::size_t size) : p_(data), n_(size) {}
  std::uint8_t byte() { return i_ < n_ ? p_[i_++] : 0; }
  std::uint32_t u32() {
    std::uint32_t v = 0;
    for (int k = 0; k < 4; ++k) v = v << 8 | byte();
    return v;
  }
  /// A value in [lo, hi] (integers).
  long range(long lo, long hi) { return lo + static_cast<long>(u32() % static_cast<std::uint32_t>(hi - lo + 1)); }
  /// A double: mostly in [lo, hi], sometimes the raw bits (NaN, inf, huge, tiny, negative zero).
  double real(double lo, double hi) {
    std::uint8_t const how = byte();
    if (how < 16) {
      double v;
      std::uint64_t bits = static_cast<std::uint64_t>(u32()) << 32 | u32();
      std::memcpy(&v, &bits, sizeof v);
      return v;
    }
    if (how < 24) {
      static double const special[] = {std::numeric_limits<double>::quiet_NaN(), std::numeric_limits<double>::infinity(),
                                       -std::numeric_limits<double>::infinity(), 0.0, -0.0, 1e300, -1e300, 1e-300};
      return special[how - 16];
    }
    return lo + (hi - lo) * (u32() / 4294967295.0);
  }
  std::uint8_t const* rest(std::size_t* size) {
    *size = n_ - i_;
    return p_ + i_;
  }
  bool empty() const { return i_ >= n_; }

 private:
  std::uint8_t const* p_;
  std::size_t n_, i_ = 0;
};

/// A broken invariant: report and abort, so that libFuzzer saves the input.
[[noreturn]] inline void fail(char const* what) {
  std::fprintf(stderr, "invariant broken: %s\n", what);
  std::abort();
}

}  // namespace endo_guidance::fuzz
