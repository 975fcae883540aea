#!/usr/bin/env bash
# The main job: set up (apt packages, configure, build; quick when nothing changed), render the
# embedded default input once (a simulated surgery bag: three instruments pivoting about
# out-of-view trocars, build/demo/surgery.bag), replay it through the ROS pipeline
# (replay.launch: the three nodelets in one manager, simulated time), then print the estimated
# trocars with their errors against the truth and save the last overlay (build/demo/overlay.png).
# Extra arguments go to roslaunch (e.g. rviz:=true, params:=/path/to.yaml, standalone:=true).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
BIN=build/devel/lib/endo_guidance
DEMO="$PWD/build/demo"
mkdir -p "$DEMO"
[ -f "$DEMO/surgery.bag" ] || "$BIN/endo_guidance_synthetic" --write-bag "$DEMO/surgery.bag" --frames 250
set +u; source build/devel/setup.bash; set -u
export ROS_MASTER_URI="http://localhost:$((11400 + RANDOM % 500))"
export ROS_HOME="${ROS_HOME:-$PWD/build/ros_home}"
mkdir -p "$ROS_HOME"
roslaunch -p "${ROS_MASTER_URI##*:}" endo_guidance replay.launch bag:="$DEMO/surgery.bag" quit_at_end:=true "$@" \
  >"$ROS_HOME/run.log" 2>&1 &
launch=$!
trap 'kill -INT $launch 2>/dev/null; wait $launch 2>/dev/null || true' EXIT
sleep 2
/usr/bin/python3 scripts/report_trocars.py "$DEMO/surgery.truth.yaml" "$DEMO/overlay.png" /endoscope
echo "pipeline log: $ROS_HOME/run.log"
