#!/usr/bin/env bash
# Two hosts on one machine: the robot host's master and robot_host.launch (driver, scripted
# surgeon, servo, JPEG decoder) and camera_host.launch (simulated endoscope + pipeline) as two
# separate roslaunch processes with their own managers; check_two_hosts.py checks what crosses
# between them and measures the latencies. Every wait is bounded; a launch that dies fails the
# test with its log.
# Usage: check_two_hosts.sh [FIGURES.json]
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT="${1:-}"
set +u; source build/devel/setup.bash; set -u
PORT=$((12000 + RANDOM % 2000))
export ROS_MASTER_URI="http://127.0.0.1:$PORT" ROS_IP=127.0.0.1
export ROS_HOME="$(mktemp -d)"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill -INT "$p" 2>/dev/null || true; done
  for p in "${pids[@]}"; do timeout 15 tail --pid="$p" -f /dev/null 2>/dev/null || kill -9 "$p" 2>/dev/null || true; done
  rm -rf "$ROS_HOME"
}
trap cleanup EXIT
roscore -p "$PORT" >"$ROS_HOME/master.log" 2>&1 &
pids+=($!)
for _ in $(seq 100); do rostopic list >/dev/null 2>&1 && break; sleep 0.1; done
rostopic list >/dev/null 2>&1 || { echo "the master did not start:"; tail "$ROS_HOME/master.log"; exit 1; }
roslaunch endo_guidance robot_host.launch scripted_motion:=true view_images:=true >"$ROS_HOME/robot.log" 2>&1 &
pids+=($!)
roslaunch endo_guidance camera_host.launch simulated_camera:=true >"$ROS_HOME/camera.log" 2>&1 &
pids+=($!)
set +e
timeout 180 /usr/bin/python3 test/ros/check_two_hosts.py >"$ROS_HOME/check.out" 2>&1 &
check=$!
while kill -0 $check 2>/dev/null; do
  for h in robot camera; do
    i=$([ $h = robot ] && echo 1 || echo 2)
    if ! kill -0 "${pids[$i]}" 2>/dev/null; then
      echo "the $h host's launch died:"; tail -20 "$ROS_HOME/$h.log"; kill $check; exit 1
    fi
  done
  sleep 0.5
done
wait $check
rc=$?
set -e
cat "$ROS_HOME/check.out"
if [ $rc -ne 0 ]; then
  echo "--- robot host:"; tail -15 "$ROS_HOME/robot.log"; echo "--- camera host:"; tail -15 "$ROS_HOME/camera.log"
  exit 1
fi
[ -n "$OUT" ] && tail -1 "$ROS_HOME/check.out" > "$OUT"
echo "two hosts ok"
