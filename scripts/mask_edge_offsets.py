#!/usr/bin/python3
# Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
"""How far the in-vivo masks' sides lie from the contour lines and from the image's edges (analysis only).

Runs `endo_guidance_offline --independent` on the 80 in-vivo stills of
../shared/data/endovis15_rigid_invivo (an assumed camera: the segmentation does not use it) and,
for every contour line it reports, samples profiles across the line every 3 px along it, 8 px
either side. A profile counts where the shaft mask (class 160) is clear of it on the outside
and covers it on the inside, and crosses 0.5 within 6 px of the line. On each such profile:
  - the mask's boundary: where the bilinearly sampled mask crosses 0.5;
  - the steepest step, within 6 px of the line, of the chroma (max - min, descending toward the
    shaft), of the luma (mean of B, G, R), of the RGB gradient's magnitude and of B, each the
    centroid of its slope about the peak down to half the peak, after a [1 2 1] / 4 smoothing.
Per line (at least 8 profiles): the median of the mask's offset from each of these (the line
itself at 0). Printed: the median and 75th percentile of those offsets' magnitudes over the
lines, how many are within 2 px, and the mask's median signed offset (negative: outside the
line, on the tissue's side). Needs numpy; skips, saying so, when the data is absent.

  /usr/bin/python3 scripts/mask_edge_offsets.py
"""
import argparse
import glob
import json
import os
import subprocess
import sys
import tempfile

import cv2
import numpy as np

CAMERA = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "config", "cameras", "assumed_640x480.yaml")
OFFS = np.arange(-8.0, 8.01, 0.5)  # px along the line's normal, toward the shaft
WINDOW = np.abs(OFFS) <= 6.0


def sample(img, pts):
    return cv2.remap(img, pts[:, 0].astype(np.float32)[None, :], pts[:, 1].astype(np.float32)[None, :], cv2.INTER_LINEAR)[0]


def smooth(a):
    return np.convolve(a, [0.25, 0.5, 0.25], "same")


def step_at(slope):
    """Centroid of a slope profile about its peak (within the window), down to half the peak."""
    s = np.where(WINDOW, slope, 0.0)
    i = int(np.argmax(s))
    if s[i] <= 0:
        return np.nan
    lo = hi = i
    while lo > 0 and s[lo - 1] > 0.5 * s[i]:
        lo -= 1
    while hi < len(s) - 1 and s[hi + 1] > 0.5 * s[i]:
        hi += 1
    w = s[lo:hi + 1]
    return float((w * OFFS[lo:hi + 1]).sum() / w.sum())


def line_offsets(img, mask, line, tip):
    """Per channel, the median offset of the mask's boundary from the line and from each channel's step."""
    f = img.astype(np.float32)
    chroma, luma = f.max(axis=2) - f.min(axis=2), f.mean(axis=2)
    n = line[:2] / np.linalg.norm(line[:2])  # toward the shaft
    foot = tip - (line[:2] @ tip + line[2]) / np.linalg.norm(line[:2]) * n
    along = np.array([-n[1], n[0]])
    rows = []
    for t in range(-400, 401, 3):
        pts = foot + t * along + OFFS[:, None] * n[None, :]
        if pts.min() < 2 or pts[:, 0].max() > img.shape[1] - 3 or pts[:, 1].max() > img.shape[0] - 3:
            continue
        mk = sample(mask, pts)
        if not (mk[:4].max() < 0.1 and mk[-4:].min() > 0.9):
            continue
        k = int(np.argmax(mk >= 0.5))
        boundary = OFFS[k - 1] + (0.5 - mk[k - 1]) / (mk[k] - mk[k - 1]) * 0.5
        if abs(boundary) > 6:
            continue
        cols = [smooth(sample(np.ascontiguousarray(f[:, :, c]), pts)) for c in range(3)]
        steps = {
            "chroma": step_at(np.gradient(-smooth(sample(chroma, pts)), 0.5)),
            "luma": step_at(np.abs(np.gradient(smooth(sample(luma, pts)), 0.5))),
            "RGB gradient": step_at(np.sqrt(sum(np.gradient(c, 0.5) ** 2 for c in cols))),
            "B": step_at(np.abs(np.gradient(cols[0], 0.5))),
        }
        rows.append((boundary, steps))
    if len(rows) < 8:
        return None
    b = np.array([r[0] for r in rows])
    out = {"the contour line": float(np.median(b))}
    for name in rows[0][1]:
        out[name] = float(np.nanmedian(b - np.array([r[1][name] for r in rows])))
    return out


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=os.path.join(here, "..", "..", "shared", "data"))
    ap.add_argument("--offline", default=os.path.join(here, "..", "build", "devel", "lib", "endo_guidance", "endo_guidance_offline"))
    a = ap.parse_args()
    inv = os.path.join(a.data, "endovis15_rigid_invivo")
    if not os.path.isdir(inv):
        print("skipped: %s is absent" % inv)
        return 0
    stills = sorted(glob.glob(os.path.join(inv, "OP*", "Raw", "*_raw.png")))
    with tempfile.TemporaryDirectory() as tmp:
        cam = CAMERA
        out = os.path.join(tmp, "stills.jsonl")
        subprocess.run([a.offline, "--camera", cam, "--radius", "0.0025", "--independent", "--quiet", "--output", out] + stills,
                       check=True)
        frames = [json.loads(line) for line in open(out)]
    per_line = []
    for fr in frames:
        src = fr["source"]
        img = cv2.imread(src)
        cls = cv2.imread(src.replace(os.sep + "Raw" + os.sep, os.sep + "Masks" + os.sep).replace("_raw.png", "_class.png"), 0)
        if img is None or cls is None:
            continue
        mask = (cls == 160).astype(np.float32)
        for ins in fr["instruments"]:
            for line in ins["contours"]:
                r = line_offsets(img, mask, np.array(line, float), np.array(ins["tip_px"], float))
                if r:
                    per_line.append(r)
    print("%d contour lines with at least 8 profiles across the mask's boundary (%d stills)" % (len(per_line), len(frames)))
    print("the mask's boundary, offset from (median per line; over the lines: median / p75 of its magnitude, lines within 2 px):")
    for name in per_line[0]:
        v = np.abs([r[name] for r in per_line])
        print("  %-17s %.2f / %.2f px, %d of %d" % (name, np.median(v), np.percentile(v, 75), int((v <= 2).sum()), len(v)))
    print("the mask's signed offset from the line (median over the lines; negative: on the tissue's side): %.2f px"
          % np.median([r["the contour line"] for r in per_line]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
