#!/usr/bin/env bash
# Soak: the rendered surgery at 60 Hz through the nodelet graph with the servo driving arm_0
# between two targets, for MINUTES (default 30); every minute each node's resident memory, the
# image -> trocar tf latency and the dropped frames (scripts/soak_monitor.py). Writes
# build/soak/{soak.jsonl,soak.png,summary.json}; exit 1 when a target is missed.
#   scripts/soak.sh [MINUTES] [--out DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
minutes="${1:-30}"
shift || true
[[ "$minutes" =~ ^[0-9]+([.][0-9]+)?$ ]] || { echo "soak.sh: MINUTES must be a number, not '$minutes'" >&2; exit 2; }
[ -f build/devel/setup.bash ] || { echo "soak.sh: build first (scripts/setup.sh)" >&2; exit 2; }
set +u; source build/devel/setup.bash; set -u
export ROS_MASTER_URI="http://127.0.0.1:$((20000 + RANDOM % 3000))" ROS_IP=127.0.0.1
log=$(mktemp)
roslaunch -p "${ROS_MASTER_URI##*:}" endo_guidance servo_sim.launch camera_rate:=60 explore_time:=25 >"$log" 2>&1 &
launch=$!
trap '{ kill -INT $launch; wait $launch; } 2>/dev/null || true; rm -f "$log"' EXIT
sleep 3
kill -0 $launch 2>/dev/null || { echo "soak.sh: roslaunch failed to start:" >&2; tail -20 "$log" >&2; exit 1; }
/usr/bin/python3 scripts/soak_monitor.py --minutes "$minutes" --warmup 40 "$@"
