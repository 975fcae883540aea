#!/usr/bin/env bash
# The run report in a real browser: endo_guidance_offline --report on a rendered sequence, then
# headless Chromium loads index.html: every image must load (the page counts them after its load
# event) and the screenshot must show the plots (matplotlib's first two line colours, over a
# good share of the page).
# Usage: check_report.sh BIN_DIR [SCREENSHOT.png]
set -euo pipefail
BIN="$1"
SHOT="${2:-}"
command -v chromium >/dev/null || { echo "chromium is not installed (scripts/setup.sh installs it)"; exit 1; }
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
"$BIN/endo_guidance_synthetic" --write-sequence "$T/seq" --frames 150 >/dev/null
"$BIN/endo_guidance_offline" --camera "$T/seq/camera.yaml" --radius 0.004 --report "$T/report" --quiet "$T/seq/frames"
for f in index.html detections.png trocars.png theta_rho.png run.yaml frames.jsonl; do
  [ -s "$T/report/$f" ] || { echo "report: $f missing"; exit 1; }
done
# (not under a preloaded sanitizer runtime: chromium has its own allocator; scripts/sanitize.sh)
CHROME=(env -u LD_PRELOAD timeout 90 chromium --headless=new --no-sandbox --disable-gpu --hide-scrollbars --user-data-dir="$T/profile")
"${CHROME[@]}" --dump-dom "file://$T/report/index.html" 2>/dev/null > "$T/dom.html"
loaded=$(grep -o 'data-images-loaded="[0-9]*/[0-9]*"' "$T/dom.html" | grep -o '[0-9]*/[0-9]*' || true)
[ -n "$loaded" ] || { echo "the page's load script did not run"; exit 1; }
[ "${loaded%/*}" = "${loaded#*/}" ] && [ "${loaded#*/}" -ge 5 ] || { echo "images loaded: $loaded"; exit 1; }
"${CHROME[@]}" --screenshot="$T/shot.png" --window-size=1150,3000 "file://$T/report/index.html" >/dev/null 2>&1
/usr/bin/python3 - "$T/shot.png" <<'PY'
import sys, cv2, numpy as np
img = cv2.imread(sys.argv[1])
assert img is not None and img.shape[0] >= 2000, "no screenshot"
def share(bgr, tol=40):
    return float((np.abs(img.astype(int) - bgr).sum(axis=2) < tol).mean())
blue, orange = share((180, 119, 31)), share((14, 127, 255))  # matplotlib C0 #1f77b4, C1 #ff7f0e
nonwhite = float((img.min(axis=2) < 230).mean())
print("report screenshot: %.2f %% C0 blue, %.2f %% C1 orange, %.1f %% not white" % (100 * blue, 100 * orange, 100 * nonwhite))
assert blue > 0.0005 and orange > 0.0005, "the plots' lines are not in the screenshot"
assert nonwhite > 0.15, "the page is mostly blank"
PY
grep -q "<h2>Trocars</h2>" "$T/report/index.html"
grep -q "opencv_version" "$T/report/index.html"
if [ -n "$SHOT" ]; then cp "$T/shot.png" "$SHOT"; fi
echo "report ok: $loaded images loaded"
