#!/usr/bin/env bash
# Screenshot of rviz (shipped config) under Xvfb while the pipeline replays the embedded
# simulated surgery; then checks the pixels: the image panel must show the segmentation overlay
# (tissue colours and the green/red contour lines) and the 3D view the markers (trocars).
# Usage: scripts/rviz_screenshot.sh [OUT.png]   (default build/rviz_screenshot.png)
# Exit 0 when both are seen, 1 otherwise.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT="$(realpath -m "${1:-build/rviz_screenshot.png}")"
BIN=build/devel/lib/endo_guidance
BAG="$PWD/build/demo/surgery.bag"
[ -f "$BAG" ] || "$BIN/endo_guidance_synthetic" --write-bag "$BAG" --frames 250 >/dev/null
# shellcheck disable=SC1091
set +u; source build/devel/setup.bash; set -u
export ROS_MASTER_URI="http://localhost:$((12000 + RANDOM % 5000))"
export ROS_HOME="${ROS_HOME:-$PWD/build/ros_home}"
mkdir -p "$ROS_HOME"
shoot() {
  xvfb-run -a -s "-screen 0 1280x800x24" bash -c "
    roslaunch -p \${ROS_MASTER_URI##*:} endo_guidance replay.launch bag:='$BAG' rviz:=true start_delay:=4 loop:=true >'$ROS_HOME/rviz_screenshot.log' 2>&1 &
    pid=\$!
    sleep 22
    import -window root '$OUT'
    kill -INT \$pid; wait \$pid || true
  "
}
shoot
# rviz (Mesa llvmpipe) has been seen to abort at start-up on a loaded machine: one more try.
if grep -q "rviz-[0-9]*\] process has died" "$ROS_HOME/rviz_screenshot.log"; then
  echo "rviz died at start-up (see $ROS_HOME/rviz_screenshot.log); trying once more"
  shoot
fi
/usr/bin/python3 - "$OUT" <<'PY'
import sys, cv2, numpy as np
img = cv2.imread(sys.argv[1])
if img is None:
    sys.exit("no screenshot")
hsv = cv2.cvtColor(img, cv2.COLOR_BGR2HSV)
h, s, v = hsv[..., 0].astype(int), hsv[..., 1].astype(int), hsv[..., 2].astype(int)
# The overlay image: rendered tissue (saturated red/orange, OpenCV hue < 20 or > 165) in a block.
tissue = ((h < 20) | (h > 165)) & (s > 90) & (v > 60)
# Trocar markers: yellow-orange (hue 20-35), saturated; contour generators: bright green.
yellow = (h >= 18) & (h <= 35) & (s > 120) & (v > 120)
green = (h >= 45) & (h <= 80) & (s > 120) & (v > 120)
H, W = tissue.shape
print(f"screenshot {W}x{H}: tissue px {tissue.sum()}, marker yellow px {yellow.sum()}, green px {green.sum()}")
# The image panel: the largest blob of tissue colour (closed over the drawn lines).
closed = cv2.morphologyEx(tissue.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((15, 15), np.uint8))
n, _, stats, _ = cv2.connectedComponentsWithStats(closed)
best = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA])) if n > 1 else 0
ok_image = n > 1 and stats[best, cv2.CC_STAT_AREA] > 20000
# Markers outside the image panel (the 3D view).
if ok_image:
    x0, y0 = stats[best, cv2.CC_STAT_LEFT], stats[best, cv2.CC_STAT_TOP]
    x1, y1 = x0 + stats[best, cv2.CC_STAT_WIDTH] - 1, y0 + stats[best, cv2.CC_STAT_HEIGHT] - 1
    outside = np.ones_like(tissue)
    outside[y0:y1 + 1, x0:x1 + 1] = False
    mk = int(((yellow | green) & outside).sum())
    print(f"image panel at x {x0}-{x1}, y {y0}-{y1}; marker px outside it {mk}")
else:
    mk = 0
ok_markers = mk > 30
print("image panel:", "ok" if ok_image else "MISSING", "| markers:", "ok" if ok_markers else "MISSING")
sys.exit(0 if ok_image and ok_markers else 1)
PY
