#!/usr/bin/env bash
# Benchmarks (reported, never asserted): times and ratios to cv::cvtColor(BGR->HSV) of the same
# frame in the same run. Single thread.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
B=build/devel/lib/endo_guidance
"$B/endo_guidance_bench_pipeline" --benchmark_min_time=0.3 "$@"
"$B/endo_guidance_bench" --benchmark_min_time=0.2 "$@"
