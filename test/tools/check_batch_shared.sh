#!/usr/bin/env bash
# The batch replay on the shared real recordings (the EndoVis'15 robotic videos, assumed
# intrinsics): both processed whole, with their reports. Exit 77 (skipped) without the data.
# Usage: check_batch_shared.sh BIN_DIR DATA_DIR
set -euo pipefail
BIN="$1"; DATA="$2/endovis15_robotic"
HERE="$(cd "$(dirname "$0")/../.." && pwd)"
[ -f "$DATA/Dataset1/Video.avi" ] || { echo "no shared data at $DATA: skipped"; exit 77; }
T=$(mktemp -d)
trap 'rm -rf "$T"' EXIT
ENDO_GUIDANCE_BIN="$BIN" /usr/bin/python3 "$HERE/scripts/batch_replay.py" "$DATA" --exclude '*Segmentation*' \
  --camera "$HERE/config/cameras/assumed_720x576.yaml" --report --out "$T/out"
/usr/bin/python3 - "$T/out" <<'PY'
import csv, os, sys
rows = {r["recording"]: r for r in csv.DictReader(open(sys.argv[1] + "/summary.csv"))}
want = {"endovis15_robotic__Dataset1__Video.avi": 370, "endovis15_robotic__Dataset2__Video.avi": 375}
assert sorted(rows) == sorted(want), sorted(rows)
for name, n in want.items():
    assert rows[name]["status"] == "ok" and int(rows[name]["frames"]) == n, rows[name]
    assert float(rows[name]["shafts/frame"]) > 0.5, rows[name]
    assert os.path.isfile(os.path.join(sys.argv[1], name, "index.html"))
print("batch on the shared robotic videos ok")
PY
