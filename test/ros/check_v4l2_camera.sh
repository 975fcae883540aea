#!/usr/bin/env bash
# The EndoscopeCamera on a real V4L2 device (/dev/video0, or $ENDO_V4L2_DEVICE): camera.launch
# must publish frames with increasing stamps within 15 s. Exit 77 (skipped) where no device exists.
set -euo pipefail
cd "$(dirname "$0")/../.."
DEV="${ENDO_V4L2_DEVICE:-/dev/video0}"
[ -c "$DEV" ] || { echo "no V4L2 device at $DEV: skipped"; exit 77; }
set +u; source build/devel/setup.bash; set -u
PORT=$((14000 + RANDOM % 1000))
export ROS_MASTER_URI="http://127.0.0.1:$PORT" ROS_IP=127.0.0.1 ROS_HOME="$(mktemp -d)"
roslaunch -p "$PORT" endo_guidance camera.launch source:="$DEV" >"$ROS_HOME/camera.log" 2>&1 &
launch=$!
trap 'kill -INT $launch 2>/dev/null; wait $launch 2>/dev/null; rm -rf "$ROS_HOME"' EXIT
timeout 30 /usr/bin/python3 - <<'PY' || { tail -20 "$ROS_HOME/camera.log"; exit 1; }
import time, rospy
from sensor_msgs.msg import Image
for _ in range(100):
    try:
        rospy.init_node("v4l2_check"); break
    except Exception:
        time.sleep(0.1)
stamps = [rospy.wait_for_message("/endoscope/image_raw", Image, 15).header.stamp.to_sec() for _ in range(5)]
assert all(b > a for a, b in zip(stamps, stamps[1:])), stamps
print("V4L2 camera ok: 5 frames, %.1f Hz" % (4 / (stamps[-1] - stamps[0])))
PY
