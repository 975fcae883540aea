#!/usr/bin/python3
# Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
"""Per-shaft separability of candidate region features on the in-vivo stills (analysis only).

For every shaft instance of ../shared/data/endovis15_rigid_invivo (class-160 pixels of one
instrument id, at least 200 px), the AUC of a feature between the shaft's pixels and the tissue
in a band around the instrument (up to 20 px away, 4 px clear of any instrument), low = shaft:
  - S.H, the pipeline's feature (colour_feature.cpp, hue origin 120 deg, gain 1);
  - a colour table (Bayes ratio of shaft / tissue counts in 5-bit BGR bins);
  - a logistic regression on brightness and texture as well as colour (box-filter means and
    standard deviations of the feature and of max(B, G, R), chroma ratio; quadratic terms).
Both learned features are cross-validated by operation: trained on OP2's stills (and the robotic
frames, weighted 0.2) for OP1's shafts and the other way round. Shafts are split into those the
pipeline finds and those it misses (`endo_guidance_eval_real --invivo-only --verbose` output,
given with --misses FILE). Needs numpy and scipy; skips, saying so, when the data is absent.

  build/devel/lib/endo_guidance/endo_guidance_eval_real --invivo-only --verbose > /tmp/real.txt
  /usr/bin/python3 scripts/feature_auc.py --misses /tmp/real.txt
"""
import argparse
import glob
import os
import sys

import cv2
import numpy as np
from scipy.stats import rankdata


def sh_feature(img):
    """S.H as colour_feature.cpp: C * ((h - 120) mod 360) / 180, C = max - min."""
    b, g, r = [img[:, :, i].astype(np.float32) for i in range(3)]
    mx = np.maximum(np.maximum(b, g), r)
    c = mx - np.minimum(np.minimum(b, g), r)
    cc = np.where(c > 0, c, 1)
    h = np.where(mx == r, 60 * np.mod((g - b) / cc + 6, 6), np.where(mx == g, 60 * ((b - r) / cc + 2), 60 * ((r - g) / cc + 4)))
    return np.where(c > 0, c * np.mod(h - 120 + 720, 360) / 180, 0)


def auc_low(pos, neg):
    """P(a shaft pixel is lower than a tissue pixel), ties halved."""
    rk = rankdata(np.concatenate([pos, neg]))
    u = rk[: len(pos)].sum() - len(pos) * (len(pos) + 1) / 2
    return 1 - u / (len(pos) * len(neg))


def in_view(img):
    m = (img.max(axis=2) > 25).astype(np.uint8)
    return cv2.erode(m, np.ones((7, 7), np.uint8)) > 0


BITS = 5


def bins(img):
    s = 8 - BITS
    return ((img[:, :, 0] >> s).astype(np.int32) << (2 * BITS)) | ((img[:, :, 1] >> s).astype(np.int32) << BITS) | (img[:, :, 2] >> s)


def texture_features(img):
    f = img.astype(np.float32)
    mx = f.max(axis=2)
    c = mx - f.min(axis=2)
    F = sh_feature(img)

    def mean(x, k):
        return cv2.blur(x, (k, k))

    def std(x, k):
        m = mean(x, k)
        return np.sqrt(np.maximum(mean(x * x, k) - m * m, 0))

    X = np.stack([F / 100, c / 100, mx / 255, (f[:, :, 2] - f[:, :, 1]) / 100, (f[:, :, 0] - f[:, :, 1]) / 100,
                  std(mx, 7) / 30, std(F, 7) / 30, mean(F, 15) / 100, mean(mx, 15) / 255, std(mx, 15) / 30,
                  c / (mx + 10), mean(c, 31) / 100 - c / 100], -1)
    quad = [X[:, :, i] * X[:, :, j] for i in range(6) for j in range(i, 6)]
    return np.concatenate([X, np.stack(quad, -1)], -1)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data"))
    ap.add_argument("--misses", help="endo_guidance_eval_real --verbose output (its 'miss' lines)")
    a = ap.parse_args()
    inv = os.path.join(a.data, "endovis15_rigid_invivo")
    rob = os.path.join(a.data, "endovis15_robotic")
    if not os.path.isdir(inv):
        print("skipped: %s is absent" % inv)
        return 0
    missed = set()
    if a.misses:
        for line in open(a.misses):
            w = line.split()
            if len(w) >= 4 and w[0] == "miss" and w[1].startswith("OP"):
                missed.add((w[1], int(w[3].rstrip(":"))))
    stills = []
    for op in ("OP1", "OP2"):
        for f in sorted(glob.glob(os.path.join(inv, op, "Raw", "*_raw.png"))):
            k = os.path.basename(f).replace("_raw.png", "")
            m = os.path.join(inv, op, "Masks", k)
            stills.append((op, k, cv2.imread(f), cv2.imread(m + "_class.png", 0), cv2.imread(m + "_instrument.png", 0)))
    robotic = []
    for f in sorted(glob.glob(os.path.join(rob, "Dataset*", "frames_png", "*.png"))):
        n = os.path.basename(f).replace("img_", "").replace(".png", "")
        img = cv2.imread(f)
        mask = np.zeros(img.shape[:2], np.uint8)
        for mf in glob.glob(os.path.join(os.path.dirname(os.path.dirname(f)), "masks_png", "*_%s.png" % n)):
            mask = np.maximum(mask, cv2.imread(mf, 0))
        robotic.append((img, np.abs(mask.astype(int) - 160) < 40, mask < 35))
    rs = np.random.RandomState(1)

    def training(op):  # (shaft, tissue) masks of the other operation's stills and the robotic frames
        for o, _, img, cls, ins in stills:
            if o != op:
                v = in_view(img)
                yield img, (cls == 160) & v, (ins == 0) & (cls == 0) & v, 1.0
        for img, shaft, tissue in robotic:
            v = in_view(img)
            yield img, shaft & v, tissue & v, 0.2

    def colour_table(op):
        n = 1 << (3 * BITS)
        s, t = np.zeros(n), np.zeros(n)
        for img, shaft, tissue, w in training(op):
            q = bins(img)
            s += w * np.bincount(q[shaft], minlength=n)
            t += w * np.bincount(q[tissue], minlength=n)
        return -np.log((s + 1) / (s.sum() + n) / ((t + 1) / (t.sum() + n)))

    def logistic(op):
        xs, ys = [], []
        for img, shaft, tissue, _ in training(op):
            X = texture_features(img).reshape(-1, 33)
            for m, y in ((shaft, 1.0), (tissue, 0.0)):
                idx = np.flatnonzero(m.ravel())
                if len(idx):
                    idx = rs.choice(idx, min(4000, len(idx)), replace=False)
                    xs.append(X[idx])
                    ys.append(np.full(len(idx), y))
        X, y = np.concatenate(xs), np.concatenate(ys)
        mu, sd = X.mean(0), X.std(0) + 1e-6
        Z = np.hstack([(X - mu) / sd, np.ones((len(X), 1))])
        w = np.zeros(Z.shape[1])
        for _ in range(25):  # Newton (IRLS), a little ridge
            p = 1 / (1 + np.exp(-Z @ w))
            H = Z.T @ (Z * (p * (1 - p) + 1e-6)[:, None]) + 1e-3 * np.eye(len(w))
            w -= np.linalg.solve(H, Z.T @ (p - y) + 1e-3 * w)
        return mu, sd, w

    tables = {op: colour_table(op) for op in ("OP1", "OP2")}
    models = {op: logistic(op) for op in ("OP1", "OP2")}
    rows = []
    for op, k, img, cls, ins in stills:
        v = in_view(img)
        mu, sd, w = models[op]
        feats = [sh_feature(img), tables[op][bins(img)], -(((texture_features(img) - mu) / sd) @ w[:-1] + w[-1])]
        anyins = cv2.dilate((ins > 0).astype(np.uint8), np.ones((9, 9), np.uint8)) > 0
        for iid in np.unique(ins[ins > 0]):
            shaft = (cls == 160) & (ins == iid) & v
            band = (cv2.dilate((ins == iid).astype(np.uint8), np.ones((41, 41), np.uint8)) > 0) & ~anyins & v
            if shaft.sum() < 200 or band.sum() < 100:
                continue
            r = np.random.RandomState(0)
            P = r.choice(np.flatnonzero(shaft.ravel()), min(3000, int(shaft.sum())), replace=False)
            N = r.choice(np.flatnonzero(band.ravel()), min(3000, int(band.sum())), replace=False)
            rows.append([("%s/%s" % (op, k), int(iid)) in missed] + [auc_low(f.ravel()[P], f.ravel()[N]) for f in feats])
    rows = np.array(rows, float)
    print("per-shaft AUC, shaft against the tissue around it (mean / median); learned features cross-validated by operation")
    for m, name in ((0, "found by the pipeline"), (1, "missed by the pipeline")):
        sel = rows[:, 0] == m
        if sel.any():
            print("  %-24s %3d shafts: S.H %.3f / %.3f, colour table %.3f / %.3f, colour+brightness+texture %.3f / %.3f"
                  % (name, sel.sum(), *[x for j in (1, 2, 3) for x in (rows[sel, j].mean(), np.median(rows[sel, j]))]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
