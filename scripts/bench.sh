#!/usr/bin/env bash
# Benchmarks (reported, never asserted): times and ratios to cv::cvtColor(BGR->HSV) in the same run.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
exec build/devel/lib/endo_guidance/endo_guidance_bench --benchmark_min_time=0.2 "$@"
