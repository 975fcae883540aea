// Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
// Console reporter that also prints every benchmark as a ratio to a reference benchmark measured
// in the same run, or its own "ratio" counter when it times the reference itself, paired within
// each iteration (speed is reported, never asserted: machines are noisy).
#pragma once

#include <benchmark/benchmark.h>

#include <cstdio>
#include <functional>
#include <opencv2/core/utility.hpp>
#include <string>
#include <utility>
#include <vector>

namespace endo_guidance::bench {

class RatioReporter : public benchmark::ConsoleReporter {
 public:
  /// reference_of(name) names the benchmark a result is divided by ("" = not reported).
  RatioReporter(std::string title, std::function<std::string(std::string const&)> reference_of)
      : title_(std::move(title)), reference_of_(std::move(reference_of)) {}
  void ReportRuns(std::vector<Run> const& runs) override {
    ConsoleReporter::ReportRuns(runs);
    for (auto const& r : runs) {
      times_.emplace_back(r.benchmark_name(), r.GetAdjustedRealTime());
      units_.push_back(benchmark::GetTimeUnitString(r.time_unit));
      auto const it = r.counters.find("ratio");
      paired_.push_back(it != r.counters.end() ? static_cast<double>(it->second) : -1.0);
      aggregate_.push_back(r.run_type == Run::RT_Aggregate);
    }
  }
  void Finalize() override {
    ConsoleReporter::Finalize();
    std::printf("\n%s\n", title_.c_str());
    for (std::size_t i = 0; i < times_.size(); ++i) {
      auto const& [n, t] = times_[i];
      if (paired_[i] >= 0.0) {  // measured against the reference within its own iterations
        std::printf("  %-45s %9.4f   (%s)\n", n.c_str(), paired_[i],
                    aggregate_[i] ? "over the repetitions' ratios" : "paired, each iteration");
        continue;
      }
      std::string const ref = reference_of_(n);
      for (auto const& [m, tr] : times_)
        if (m == ref && tr > 0.0) std::printf("  %-45s %9.4f   (%.1f %s)\n", n.c_str(), t / tr, t, units_[i]);
    }
  }

 private:
  std::string title_;
  std::function<std::string(std::string const&)> reference_of_;
  std::vector<std::pair<std::string, double>> times_;
  std::vector<char const*> units_;
  std::vector<double> paired_;  ///< a benchmark's own "ratio" counter, -1 if none
  std::vector<bool> aggregate_;  ///< the run is an aggregate of repetitions (median, mean, stddev, cv)
};

/// main() of the benchmark programs: single thread, the reporter above.
inline int runBenchmarks(int argc, char** argv, RatioReporter& reporter) {
  cv::setNumThreads(1);
  benchmark::Initialize(&argc, argv);
  if (benchmark::ReportUnrecognizedArguments(argc, argv)) return 1;
  benchmark::RunSpecifiedBenchmarks(&reporter);
  benchmark::Shutdown();
  return 0;
}

}  // namespace endo_guidance::bench
