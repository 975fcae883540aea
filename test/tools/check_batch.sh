#!/usr/bin/env bash
# The batch replay on a folder of recordings: two rendered videos (a camera.yaml beside them), a
# rendered bag (its own camera_info), a corrupt video. Two at a time; the summary has a row per
# recording, the corrupt one failed with its reason and the batch exits 1; with --report every
# recording has its index.html and OUT/index.html links them. Run again: nothing is redone; a
# recording whose output was lost half-way (no done.json) is redone alone.
# Usage: check_batch.sh BIN_DIR
set -euo pipefail
BIN="$1"
HERE="$(cd "$(dirname "$0")/../.." && pwd)"
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
mkdir -p "$T/in/videos"
"$BIN/endo_guidance_synthetic" --write-sequence "$T/seq" --frames 100 >/dev/null
cp "$T/seq/camera.yaml" "$T/in/videos/camera.yaml"
/usr/bin/python3 - "$T/seq/frames" "$T/in/videos" <<'PY'
import glob, sys, cv2
files = sorted(glob.glob(sys.argv[1] + "/*.png"))
for name, part in (("first.avi", files[:60]), ("second.avi", files[40:])):
    w = cv2.VideoWriter(sys.argv[2] + "/" + name, cv2.VideoWriter_fourcc(*"MJPG"), 25, (640, 480))
    for f in part:
        w.write(cv2.imread(f))
    w.release()
open(sys.argv[2] + "/corrupt.avi", "wb").write(b"RIFF\x00\x00\x00\x00AVI not really a video" * 10)
PY
"$BIN/endo_guidance_synthetic" --write-bag "$T/in/surgery.bag" --frames 160 >/dev/null
export ENDO_GUIDANCE_BIN="$BIN"
run() { /usr/bin/python3 "$HERE/scripts/batch_replay.py" "$T/in" --out "$T/out" --jobs 2 --report --image-topic /endoscope/image_raw "$@"; }
set +e
run >"$T/log1" 2>&1
rc=$?
set -e
cat "$T/log1"
[ $rc -eq 1 ] || { echo "a failed recording must make the batch exit 1 (got $rc)"; exit 1; }
grep -q "4 recordings, 0 done before, 4 to process, 2 at a time" "$T/log1"
/usr/bin/python3 - "$T/out" <<'PY'
import csv, os, sys
rows = {r["recording"]: r for r in csv.DictReader(open(sys.argv[1] + "/summary.csv"))}
assert sorted(rows) == ["in__surgery.bag", "in__videos__corrupt.avi", "in__videos__first.avi", "in__videos__second.avi"], sorted(rows)
assert rows["in__videos__corrupt.avi"]["status"].startswith("failed: "), rows["in__videos__corrupt.avi"]
assert "cannot open video" in rows["in__videos__corrupt.avi"]["status"], rows["in__videos__corrupt.avi"]
for name, frames in (("in__surgery.bag", 160), ("in__videos__first.avi", 60), ("in__videos__second.avi", 60)):
    r = rows[name]
    assert r["status"] == "ok" and int(r["frames"]) == frames, r
    assert float(r["shafts/frame"]) > 2.0, r
    assert os.path.isfile(os.path.join(sys.argv[1], name, "index.html")), name
located, of = rows["in__surgery.bag"]["trocars located"].split(" of ")
assert of == "3" and int(located) >= 1, rows["in__surgery.bag"]  # 160 frames: at least one located
page = open(sys.argv[1] + "/index.html").read()
assert page.count("/index.html\">") == 3, page
print("batch summary ok")
PY
# Resume: nothing to redo; then one recording's output lost half-way is redone alone.
set +e; run >"$T/log2" 2>&1; set -e
grep -q "4 recordings, 3 done before, 1 to process" "$T/log2" || { cat "$T/log2"; exit 1; }
rm "$T/out/in__videos__first.avi/done.json"
head -c 300 "$T/out/in__videos__first.avi/frames.jsonl" > "$T/half" && mv "$T/half" "$T/out/in__videos__first.avi/frames.jsonl"
set +e; run >"$T/log3" 2>&1; set -e
grep -q "4 recordings, 2 done before, 2 to process" "$T/log3" || { cat "$T/log3"; exit 1; }
grep -q "in__videos__first.avi .*60 frames" "$T/log3" || { cat "$T/log3"; exit 1; }
echo "batch ok"
