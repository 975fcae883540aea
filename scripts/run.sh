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
exec bash scripts/replay_demo.sh "$@"
