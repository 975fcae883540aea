#!/usr/bin/env bash
# Replays the embedded simulated surgery (build/demo/surgery.bag, rendered once by
# endo_guidance_synthetic) through replay.launch on a private master, then prints the trocar
# estimates with their errors and saves the last overlay (build/demo/overlay.png).
# Usage: scripts/replay_demo.sh [--check TOL_MM] [roslaunch args...]
#   --check TOL_MM: exit 1 unless every true trocar is estimated (located: on tf) within TOL_MM.
set -euo pipefail
cd "$(dirname "$0")/.."
CHECK=()
if [ "${1:-}" = "--check" ]; then CHECK=(--check "$2"); shift 2; fi
BIN=build/devel/lib/endo_guidance
DEMO="$PWD/build/demo"
[ -f "$DEMO/surgery.bag" ] || "$BIN/endo_guidance_synthetic" --write-bag "$DEMO/surgery.bag" --frames 250
set +u; source build/devel/setup.bash; set -u
export ROS_MASTER_URI="http://localhost:$((11400 + RANDOM % 500))"
export ROS_HOME="${ROS_HOME:-$PWD/build/ros_home}"
mkdir -p "$ROS_HOME"
roslaunch -p "${ROS_MASTER_URI##*:}" endo_guidance replay.launch bag:="$DEMO/surgery.bag" quit_at_end:=true "$@" \
  >"$ROS_HOME/replay_demo.log" 2>&1 &
launch=$!
trap '{ kill -INT $launch; wait $launch; } 2>/dev/null || true' EXIT
sleep 2
/usr/bin/python3 scripts/report_trocars.py "$DEMO/surgery.truth.yaml" "$DEMO/overlay.png" /endoscope "${CHECK[@]}"
echo "pipeline log: $ROS_HOME/replay_demo.log"
