#!/usr/bin/env bash
# Latency the nodelet chain adds over the core pipeline (image in -> insertion points / trocar tf
# out) at 25 and 60 Hz: starts a private master, runs endo_guidance_latency, stops the master.
set -euo pipefail
cd "$(dirname "$0")/.."
set +u; source build/devel/setup.bash; set -u
export ROS_MASTER_URI="http://localhost:$((17000 + RANDOM % 3000))"
roscore -p "${ROS_MASTER_URI##*:}" >/dev/null 2>&1 &
core=$!
trap '{ kill -INT $core; wait $core; } 2>/dev/null || true' EXIT
sleep 2
build/devel/lib/endo_guidance/endo_guidance_latency "$@"
