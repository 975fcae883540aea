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
/usr/bin/python3 scripts/report_trocars.py "$DEMO/surgery.truth.yaml" "$DEMO/overlay.png" /endoscope "${CHECK[@]}" &
report=$!
# The launch ends when the bag does (quit_at_end); if it ends before the report, it failed.
while kill -0 $report 2>/dev/null; do
  if ! kill -0 $launch 2>/dev/null && kill -0 $report 2>/dev/null; then
    sleep 1  # the report may be finishing on the last messages
    if kill -0 $report 2>/dev/null && ! grep -q "process\[player-" "$ROS_HOME/replay_demo.log"; then
      kill $report 2>/dev/null || true
      echo "roslaunch failed to start (log: $ROS_HOME/replay_demo.log):" >&2
      tail -5 "$ROS_HOME/replay_demo.log" >&2
      exit 1
    fi
  fi
  sleep 0.2
done
wait $report
echo "pipeline log: $ROS_HOME/replay_demo.log"
