#!/usr/bin/env bash
# Benchmarks (reported, never asserted): times and ratios to cv::cvtColor(BGR->HSV) of the same
# frame in the same run. Single thread.
# The figure to quote, the paired pipeline ratio, moves by 5-8 % between runs on a 2-core VM: it
# is run again five times and reported as the median, mean and spread of those runs.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
B=build/devel/lib/endo_guidance
"$B/endo_guidance_bench_pipeline" --benchmark_min_time=0.3 "$@"
echo
echo "The paired pipeline ratios (rendered and, with the shared data, real frames), five repetitions (aggregates: median, mean, stddev, cv):"
"$B/endo_guidance_bench_pipeline" --benchmark_filter='PipelinePairedWithHSV|PipelineTrackingPairedWithHSV|RealVideoPairedWithHSV|RealStillsSegmentationPairedWithHSV' \
  --benchmark_min_time=1 --benchmark_repetitions=5 --benchmark_report_aggregates_only=true "$@" | sed -n '/^Ratio/,$p'
"$B/endo_guidance_bench" --benchmark_min_time=0.2 "$@"
