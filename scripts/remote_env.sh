#!/usr/bin/env bash
# roslaunch's env-loader for a remote machine (camera_host.launch / robot_host.launch with
# address:=...): sets up this checkout's ROS environment there, then runs the node's command.
# The checkout must be at the same path on every host (docs/deployment.md).
set -e
HERE="$(cd "$(dirname "$0")/.." && pwd)"
source "$HERE/build/devel/setup.bash"
exec "$@"
