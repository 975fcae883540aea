#!/usr/bin/env bash
# The main job: set up (apt packages, configure, build; quick when nothing changed), render the
# embedded default sequence (a simulated surgery: three instruments pivoting about out-of-view
# trocars; written once to build/demo), run the offline pipeline on it and print the estimated
# insertion points against the truth. Writes build/demo/out.jsonl and build/demo/overlay.avi.
# Extra arguments go to endo_guidance_offline (e.g. --params config/pipeline.yaml).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
BIN=build/devel/lib/endo_guidance
DEMO=build/demo
if [ ! -f "$DEMO/truth.yaml" ]; then
  "$BIN/endo_guidance_synthetic" --write-sequence "$DEMO" --frames 250 --scene clean
fi
"$BIN/endo_guidance_offline" --camera "$DEMO/camera.yaml" --radius 0.004 --params config/pipeline.yaml \
  --output "$DEMO/out.jsonl" --overlay "$DEMO/overlay.avi" --truth "$DEMO/truth.yaml" "$@" "$DEMO/frames"
echo "per-frame results: $DEMO/out.jsonl; overlay video: $DEMO/overlay.avi"
