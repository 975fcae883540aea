#!/usr/bin/env python3
# Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
"""Trains the learned shaft mask (background / shaft / jaws per pixel, and the shaft's silhouette
sides: the shaft's outline against the background, not against its jaws or the view's black edge)
on the CPU and exports it to ONNX for OpenCV's DNN module (perception/learned_shaft_detector.h).

Data (read from ../shared/data, never copied): the EndoVis'15 rigid in-vivo stills (OP1-OP3,
class masks 0 / 70 jaws / 160 shaft), the robotic sequences' mask videos (DS1, DS2; every 5th
frame, pixels snapped to {0, 70, 160}) and the project's rendered frames with exact labels
(--sim; SIM, never held out). Each site weighs the same. Heavy augmentation: scale, rotation,
flips, colour cast, brightness, blur, noise, JPEG, specular spots, haze, circular or side-bar views.

  train_shaft_net.py --out DIR [--hold-out OP1|OP2|OP3|DS1|DS2] [--epochs N] [--seed S]

writes DIR/shaft_net.onnx and DIR/shaft_net.yaml (input size, normalisation, classes, the
training's held-out pixel IoU). --reference FRAME.png also writes the network's output on that
frame beside the model (shaft_net_reference.yml.gz), for the C++ test of the OpenCV runtime.
"""
import argparse
import os
import sys
import time

import cv2
import numpy as np

try:
    import torch
    import torch.nn as nn
    import torch.nn.functional as F
except ImportError:
    sys.exit("train_shaft_net.py: PyTorch is missing (Debian: apt-get install python3-torch python3-onnx)")

NET_W, NET_H = 160, 128          # network input (any frame is resized to it; --size)
STORE_W, STORE_H = 320, 256      # training images are kept at twice the input, augmented, then reduced
CLASSES = ("background", "shaft", "jaws")
SIDE = len(CLASSES)  # one more output channel: the shaft's silhouette sides (a logit, sigmoid)
MEAN, SCALE = 127.5, 1.0 / 127.5  # input = (BGR - MEAN) * SCALE


def snap(mask):
    """Mask grey levels to class indices: nearest of 0 (background), 160 (shaft), 70 (jaws)."""
    m = mask.astype(np.int16)
    d = np.stack([np.abs(m - 0), np.abs(m - 160), np.abs(m - 70)])
    return np.argmin(d, axis=0).astype(np.uint8)


def load_sites(data, sim):
    """{site: [(bgr, labels)]} at STORE size."""
    sites = {}
    if sim and os.path.isdir(sim):
        items = []
        for f in sorted(os.listdir(sim)):
            if not f.endswith(".png") or f.endswith("_labels.png"):
                continue
            im = cv2.imread(os.path.join(sim, f), cv2.IMREAD_COLOR)
            lab = cv2.imread(os.path.join(sim, f[:-4] + "_labels.png"), cv2.IMREAD_GRAYSCALE)
            if im is not None and lab is not None:
                items.append((cv2.resize(im, (STORE_W, STORE_H), interpolation=cv2.INTER_AREA),
                              cv2.resize(lab, (STORE_W, STORE_H), interpolation=cv2.INTER_NEAREST)))
        sites["SIM"] = items
    root = os.path.join(data, "endovis15_rigid_invivo")
    for op in ("OP1", "OP2", "OP3"):
        raw = os.path.join(root, op, "Raw")
        if not os.path.isdir(raw):
            continue
        items = []
        for f in sorted(os.listdir(raw)):
            im = cv2.imread(os.path.join(raw, f), cv2.IMREAD_COLOR)
            cls = cv2.imread(os.path.join(root, op, "Masks", f.replace("_raw", "_class")), cv2.IMREAD_GRAYSCALE)
            if im is None or cls is None:
                continue
            items.append((cv2.resize(im, (STORE_W, STORE_H), interpolation=cv2.INTER_AREA),
                          cv2.resize(snap(cls), (STORE_W, STORE_H), interpolation=cv2.INTER_NEAREST)))
        sites[op] = items
    rob = os.path.join(data, "endovis15_robotic")
    for ds in (1, 2):
        d = os.path.join(rob, "Dataset%d" % ds)
        masks = [os.path.join(d, f) for f in sorted(os.listdir(d)) if f.endswith("Segmentation.avi")] if os.path.isdir(d) else []
        if not masks:
            continue
        video = cv2.VideoCapture(os.path.join(d, "Video.avi"))
        caps = [cv2.VideoCapture(m) for m in masks]
        items, k = [], 0
        while True:
            ok, im = video.read()
            ms = [c.read() for c in caps]
            if not ok or not all(m[0] for m in ms):
                break
            if k % 5 == 0:
                lab = np.zeros(im.shape[:2], np.uint8)
                for _, m in ms:
                    s = snap(cv2.cvtColor(m, cv2.COLOR_BGR2GRAY))
                    lab = np.where(s > 0, s, lab)
                items.append((cv2.resize(im, (STORE_W, STORE_H), interpolation=cv2.INTER_AREA),
                              cv2.resize(lab, (STORE_W, STORE_H), interpolation=cv2.INTER_NEAREST)))
            k += 1
        sites["DS%d" % ds] = items
    return sites


def augment(im, lab, rng):
    """One randomly augmented copy at the network's input size."""
    h, w = lab.shape
    # Geometry: scale (zoom in up to 1.6x), rotation, shift, flips, aspect jitter.
    s = rng.uniform(1.0, 1.6)
    a = rng.uniform(-25, 25)
    M = cv2.getRotationMatrix2D((w / 2 + rng.uniform(-0.15, 0.15) * w, h / 2 + rng.uniform(-0.15, 0.15) * h), a, s)
    M[0, :] *= rng.uniform(0.85, 1.15)
    im = cv2.warpAffine(im, M, (w, h), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    lab = cv2.warpAffine(lab, M, (w, h), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_REFLECT)
    if rng.random() < 0.5:
        im, lab = im[:, ::-1], lab[:, ::-1]
    if rng.random() < 0.3:
        im, lab = im[::-1], lab[::-1]
    # The view's own black edge (OP1's top rows, the videos' borders) ends the labels, not the shaft.
    dark = cv2.dilate((im.max(axis=2) < 15).astype(np.uint8), np.ones((5, 5), np.uint8))
    im = im.astype(np.float32)
    # Colour: per-channel cast, brightness, contrast, desaturation or over-saturation.
    im *= rng.uniform(0.75, 1.25, size=3).astype(np.float32)
    im = (im - 128.0) * rng.uniform(0.6, 1.4) + 128.0 + rng.uniform(-40, 40)
    grey = im.mean(axis=2, keepdims=True)
    im = grey + (im - grey) * rng.uniform(0.4, 1.5)
    # Vignetting / circular or side-bar view (black outside).
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    r = np.hypot((xx - w / 2) / (w / 2), (yy - h / 2) / (h / 2))
    if rng.random() < 0.5:
        im *= np.clip(1.0 - rng.uniform(0.0, 0.6) * r[..., None] ** 2, 0, 1)
    u = rng.random()
    # (blacked out: the labels go on there, the sides are not seen)
    if u < 0.2:
        rad = rng.uniform(0.9, 1.3)
        out = np.hypot((xx - w / 2) / (h / 2), (yy - h / 2) / (h / 2)) > rad
        im[out] = rng.uniform(0, 12)
        dark[out] = 1
    elif u < 0.35:
        bar = int(rng.uniform(0.0, 0.12) * w)
        if bar > 0:
            im[:, :bar] = 0
            im[:, w - bar:] = 0
            dark[:, :bar] = 1
            dark[:, w - bar:] = 1
    # Specular spots and smoke/haze.
    for _ in range(rng.integers(0, 5)):
        c = (int(rng.uniform(0, w)), int(rng.uniform(0, h)))
        ax = (int(rng.uniform(2, 14)), int(rng.uniform(2, 8)))
        cv2.ellipse(im, c, ax, rng.uniform(0, 180), 0, 360, (255, 255, 255), -1)
    if rng.random() < 0.25:
        haze = rng.uniform(0.1, 0.45)
        im = im * (1 - haze) + haze * rng.uniform(150, 230)
    im = np.clip(im, 0, 255).astype(np.uint8)
    if rng.random() < 0.4:
        k = int(rng.choice([3, 5, 7]))
        im = cv2.GaussianBlur(im, (k, k), 0)
    # Reduce to the input size, then noise and JPEG at that size.
    im = cv2.resize(im, (NET_W, NET_H), interpolation=cv2.INTER_AREA)
    lab = cv2.resize(np.ascontiguousarray(lab), (NET_W, NET_H), interpolation=cv2.INTER_NEAREST)
    side = side_band(lab) * (cv2.resize(dark, (NET_W, NET_H), interpolation=cv2.INTER_NEAREST) == 0)
    if rng.random() < 0.5:
        im = np.clip(im + rng.normal(0, rng.uniform(1, 8), im.shape), 0, 255).astype(np.uint8)
    if rng.random() < 0.5:
        ok, buf = cv2.imencode(".jpg", im, [cv2.IMWRITE_JPEG_QUALITY, int(rng.uniform(30, 95))])
        im = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    return np.ascontiguousarray(im), np.ascontiguousarray(lab), side


def side_band(lab):
    """The shaft's sides at the labels' size: the pixels on either side of a shaft / background
    boundary (a band 2 px wide). The shaft against its jaws or another tool is no side (the
    caller also clears the view's black edge)."""
    shaft = (lab == 1).astype(np.uint8)
    background = (lab == 0).astype(np.uint8)
    k = np.ones((3, 3), np.uint8)
    return ((cv2.dilate(shaft, k) & background) | (cv2.dilate(background, k) & shaft)).astype(np.float32)


def to_input(bgr_list):
    x = np.stack(bgr_list).astype(np.float32)
    return torch.from_numpy(((x - MEAN) * SCALE).transpose(0, 3, 1, 2).copy())


class DSConv(nn.Sequential):
    """Depthwise-separable 3x3 convolution, batch norm, ReLU."""

    def __init__(self, cin, cout, stride=1, dilation=1):
        super().__init__(
            nn.Conv2d(cin, cin, 3, stride, padding=dilation, dilation=dilation, groups=cin, bias=False),
            nn.BatchNorm2d(cin), nn.ReLU(inplace=True),
            nn.Conv2d(cin, cout, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class ShaftNet(nn.Module):
    """Strided stem, depthwise-separable encoder to 1/16, a dilated context block, a decoder with
    skips back to 1/2, bilinear to the input size. About 70 k parameters."""

    def __init__(self):
        super().__init__()
        self.stem = nn.Sequential(nn.Conv2d(3, 16, 3, 2, 1, bias=False), nn.BatchNorm2d(16), nn.ReLU(inplace=True))
        self.e2 = nn.Sequential(DSConv(16, 32, 2), DSConv(32, 32))
        self.e3 = nn.Sequential(DSConv(32, 64, 2), DSConv(64, 64))
        self.e4 = nn.Sequential(DSConv(64, 128, 2), DSConv(128, 128, dilation=2), DSConv(128, 128, dilation=4))
        self.d3 = DSConv(128 + 64, 64)
        self.d2 = DSConv(64 + 32, 40)
        self.d1 = DSConv(40 + 16, 24)
        self.head = nn.Conv2d(24, len(CLASSES) + 1, 1)  # the classes' logits, then the side's

    @staticmethod
    def up(x):
        return F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)

    def forward(self, x):
        s1 = self.stem(x)
        s2 = self.e2(s1)
        s3 = self.e3(s2)
        s4 = self.e4(s3)
        y = self.d3(torch.cat([self.up(s4), s3], 1))
        y = self.d2(torch.cat([self.up(y), s2], 1))
        y = self.d1(torch.cat([self.up(y), s1], 1))
        return self.up(self.head(y))


class MobileUNet(nn.Module):
    """MobileNetV2's first blocks (torchvision's layout; ImageNet weights from pretrained_backbone.py,
    or random) as the encoder, cut after block_<cut> (1/8 up to block 5, 1/16 from block 6); a light
    decoder with skips at 1/8, 1/4 and 1/2 (depthwise-separable convolutions), bilinear to the input size."""

    def __init__(self, cut):
        super().__init__()
        import torchvision
        import pretrained_backbone as pb
        # Keras' padding and batch-norm eps, which the pretrained weights assume (the check's exact match).
        self.features = pb.keras_padding(torchvision.models.mobilenet_v2(weights=None).features[:cut + 2])
        for m in self.features.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.eps = 1e-3
        c4 = self.features[-1].conv[-1].num_features
        self.deep = cut >= 6  # blocks 6 onwards run at 1/16; up to block_5 the encoder ends at 1/8
        self.d3 = DSConv(c4 + 32, 64) if self.deep else nn.Identity()
        self.d2 = DSConv((64 if self.deep else 32) + 24, 40)
        self.d1 = DSConv(40 + 16, 24)
        self.head = nn.Conv2d(24, len(CLASSES) + 1, 1)  # the classes' logits, then the side's

    def load_pretrained(self, directory):
        import pretrained_backbone as pb
        keras = dict(np.load(pb.fetch(directory)))
        # Variances that dequantisation left at 0 are raised to the smallest nonzero one of theirs.
        state = pb.torch_state(keras, bgr=True, last_block=len(self.features) - 2)
        for k, v in state.items():
            if k.endswith("running_var") and (v > 0).any():
                state[k] = np.maximum(v, v[v > 0].min())
        missing, unexpected = self.features.load_state_dict({k: torch.from_numpy(np.array(v)) for k, v in state.items()},
                                                            strict=False)
        if [m for m in missing if not m.endswith("num_batches_tracked")] or unexpected:
            sys.exit("train_shaft_net.py: the pretrained encoder does not fit (%s, %s)" % (missing[:3], unexpected[:3]))

    def forward(self, x):
        taps = []
        for i, layer in enumerate(self.features):
            x = layer(x)
            if i in (1, 3, 6):  # ends of the 1/2, 1/4 and 1/8 stages
                taps.append(x)
        s1, s2, s3 = taps
        up = ShaftNet.up
        y = self.d3(torch.cat([up(x), s3], 1)) if self.deep else s3
        y = self.d2(torch.cat([up(y), s2], 1))
        y = self.d1(torch.cat([up(y), s1], 1))
        return up(self.head(y))


def iou(model, items):
    """Shaft-class pixel IoU over the items (each at the input size, no augmentation)."""
    if not items:
        return float("nan")
    model.eval()
    inter = union = 0
    with torch.no_grad():
        for i in range(0, len(items), 16):
            batch = items[i:i + 16]
            x = to_input([cv2.resize(im, (NET_W, NET_H), interpolation=cv2.INTER_AREA) for im, _ in batch])
            pred = model(x)[:, :SIDE].argmax(1).numpy()
            for p, (_, lab) in zip(pred, batch):
                t = cv2.resize(lab, (NET_W, NET_H), interpolation=cv2.INTER_NEAREST)
                inter += int(np.sum((p == 1) & (t == 1)))
                union += int(np.sum((p == 1) | (t == 1)))
    model.train()
    return inter / max(1, union)


def load_onnx(model, path):
    """The weights of an exported model (export(): batch norm folded into each convolution) into
    `model`: each convolution takes its folded weight, its batch norm passes the folded bias on."""
    import onnx
    from onnx import numpy_helper
    m = onnx.load(path)
    init = {i.name: numpy_helper.to_array(i) for i in m.graph.initializer}
    convs = [n for n in m.graph.node if n.op_type == "Conv"]
    mods = [(name, mod) for name, mod in model.named_modules() if isinstance(mod, nn.Conv2d)]
    if len(convs) != len(mods):
        sys.exit("train_shaft_net.py: %s has %d convolutions, the network %d" % (path, len(convs), len(mods)))
    bns = {name: mod for name, mod in model.named_modules() if isinstance(mod, nn.BatchNorm2d)}
    with torch.no_grad():
        for node, (name, conv) in zip(convs, mods):
            w = torch.from_numpy(init[node.input[1]].copy())
            b = torch.from_numpy(init[node.input[2]].copy()) if len(node.input) > 2 else torch.zeros(w.shape[0])
            if w.shape != conv.weight.shape:
                sys.exit("train_shaft_net.py: %s does not match the network at %s" % (path, name))
            conv.weight.copy_(w)
            if conv.bias is not None:
                conv.bias.copy_(b)
                continue
            parent, idx = name.rsplit(".", 1)  # the batch norm right after it in its Sequential
            bn = bns[parent + "." + str(int(idx) + 1)]
            bn.running_mean.zero_()
            bn.running_var.fill_(1.0)
            bn.weight.fill_(float(np.sqrt(1.0 + bn.eps)))
            bn.bias.copy_(b)


def export(model, path):
    import onnx
    from onnx import numpy_helper
    model.eval()
    dummy = torch.zeros(1, 3, NET_H, NET_W)
    torch.onnx.export(model, dummy, path, opset_version=11, input_names=["image"], output_names=["logits"],
                      do_constant_folding=True)
    m = onnx.load(path)
    # OpenCV 4.6's importer refuses Identity nodes on initialisers: rename their outputs away.
    ids = [n for n in m.graph.node if n.op_type == "Identity"]
    for n in ids:
        src, dst = n.input[0], n.output[0]
        for other in m.graph.node:
            for k, name in enumerate(other.input):
                if name == dst:
                    other.input[k] = src
        m.graph.node.remove(n)
    onnx.checker.check_model(m)
    # OpenCV 4.6 reads Pad without an omitted ("") constant value input, and Clip (ReLU6) only in
    # its opset-6 form, bounds as attributes: write them so.
    for n in m.graph.node:
        while n.input and n.input[-1] == "":
            del n.input[-1]
    consts = {i.name: numpy_helper.to_array(i) for i in m.graph.initializer}
    for n in m.graph.node:
        if n.op_type == "Constant":
            consts[n.output[0]] = numpy_helper.to_array(n.attribute[0].t)
    for n in m.graph.node:
        if n.op_type == "Clip" and len(n.input) == 3:
            lo, hi = float(consts[n.input[1]]), float(consts[n.input[2]])
            del n.input[1:]
            n.attribute.extend([onnx.helper.make_attribute("min", lo), onnx.helper.make_attribute("max", hi)])
    used = {i for n in m.graph.node for i in n.input}
    for n in [n for n in m.graph.node if n.op_type == "Constant" and n.output[0] not in used]:
        m.graph.node.remove(n)
    onnx.save(m, path)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", default=os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data"))
    ap.add_argument("--out", required=True)
    ap.add_argument("--sim", default="", help="rendered training frames (endo_guidance_synthetic --write-training DIR)")
    ap.add_argument("--hold-out", default="", help="site left out of training and scored (OP1, OP2, OP3, DS1, DS2)")
    ap.add_argument("--epochs", type=int, default=240)
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--arch", default="shaftnet", help="shaftnet (from scratch, 70 k parameters) or mnv2-CUT: "
                    "MobileNetV2 cut after block_CUT (5 to 10) with the decoder (MobileUNet)")
    ap.add_argument("--pretrained", default="", help="with mnv2-*: where pretrained_backbone.py fetches the ImageNet "
                    "weights (e.g. build/pretrained); none: random initialisation")
    ap.add_argument("--size", default="160x128", help="network input WxH (multiples of 32)")
    ap.add_argument("--threads", type=int, default=0, help="PyTorch threads (default: every core)")
    ap.add_argument("--reference", default="", help="a BGR frame: write the network's output on it beside the model")
    ap.add_argument("--weights", default="", help="skip training: export these weights (DIR/shaft_net.pt of a run)")
    ap.add_argument("--onnx", default="", help="skip training: the weights of this exported model (with --reference: "
                    "its reference output again, after a change of the rendered frame)")
    args = ap.parse_args()

    global NET_W, NET_H, STORE_W, STORE_H
    try:
        NET_W, NET_H = (int(v) for v in args.size.lower().split("x"))
    except ValueError:
        sys.exit("train_shaft_net.py: --size must be WxH, not %s" % args.size)
    if NET_W % 32 or NET_H % 32 or not 64 <= NET_W <= 1024 or not 64 <= NET_H <= 1024:
        sys.exit("train_shaft_net.py: --size %s: each side a multiple of 32 in [64, 1024]" % args.size)
    STORE_W, STORE_H = 2 * NET_W, 2 * NET_H
    torch.manual_seed(args.seed)
    rng = np.random.default_rng(args.seed)
    torch.set_num_threads(args.threads or max(1, os.cpu_count() or 1))
    t0 = time.time()
    sites = load_sites(args.data, args.sim)
    if not sites:
        sys.exit("train_shaft_net.py: no training data under %s" % args.data)
    if args.hold_out and args.hold_out not in sites:
        sys.exit("train_shaft_net.py: unknown site %s (have %s)" % (args.hold_out, ", ".join(sites)))
    train = [it for s, items in sites.items() if s != args.hold_out for it in items]
    held = sites.get(args.hold_out, [])
    # Each site weighs about the same per epoch: the stills are few, the sequences long.
    weights = np.concatenate([np.full(len(items), 1.0 / len(items)) for s, items in sites.items() if s != args.hold_out])
    weights /= weights.sum()
    print("sites: %s; training on %d images, holding out %s (%d)" %
          (", ".join("%s %d" % (s, len(v)) for s, v in sites.items()), len(train), args.hold_out or "none", len(held)), flush=True)

    if args.arch == "shaftnet":
        model = ShaftNet()
    elif args.arch.startswith("mnv2-") and args.arch[5:].isdigit() and 5 <= int(args.arch[5:]) <= 10:
        model = MobileUNet(int(args.arch[5:]))
        if args.pretrained:
            model.load_pretrained(args.pretrained)
    else:
        sys.exit("train_shaft_net.py: unknown --arch %s (shaftnet, mnv2-5 .. mnv2-10)" % args.arch)
    print("network %s%s, %d parameters, input %dx%d" % (args.arch, " (ImageNet encoder)" if args.pretrained else "",
          sum(p.numel() for p in model.parameters()), NET_W, NET_H), flush=True)
    if args.weights:
        model.load_state_dict(torch.load(args.weights))
        args.epochs = 0
    elif args.onnx:
        load_onnx(model, args.onnx)
        args.epochs = 0
    # A pretrained encoder learns at a third of the decoder's rate (it starts from useful features).
    encoder = list(model.features.parameters()) if isinstance(model, MobileUNet) else []
    rest = [p for p in model.parameters() if all(p is not q for q in encoder)]
    groups = [{"params": rest, "lr": 3e-3}] + ([{"params": encoder, "lr": 1e-3 if args.pretrained else 3e-3}] if encoder else [])
    opt = torch.optim.AdamW(groups, weight_decay=1e-4)
    per_epoch, batch = 256, 16
    steps = max(1, args.epochs * (per_epoch // batch))
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=[g["lr"] for g in groups], total_steps=steps, pct_start=0.15)
    class_w = torch.tensor([1.0, 3.0, 2.0])
    step = 0
    for epoch in range(args.epochs):
        idx = rng.choice(len(train), size=per_epoch, p=weights)
        total = 0.0
        for b in range(0, per_epoch, batch):
            pairs = [augment(*train[i], rng) for i in idx[b:b + batch]]
            x = to_input([p[0] for p in pairs])
            y = torch.from_numpy(np.stack([p[1] for p in pairs]).astype(np.int64))
            out = model(x)
            logits = out[:, :SIDE]
            loss = F.cross_entropy(logits, y, weight=class_w)
            # The sides: a thin band, weighed as the shaft class is.
            side = torch.from_numpy(np.stack([p[2] for p in pairs]))
            loss = loss + F.binary_cross_entropy_with_logits(out[:, SIDE], side, pos_weight=torch.tensor(3.0))
            # Soft Dice on the shaft class: the thin shafts count as much as the wide ones.
            p = logits.softmax(1)[:, 1]
            t = (y == 1).float()
            loss = loss + 1.0 - (2 * (p * t).sum() + 1) / (p.sum() + t.sum() + 1)
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()
            step += 1
            total += float(loss)
        if epoch % 10 == 9 or epoch == args.epochs - 1:
            held_report = "  held-out shaft IoU %.3f" % iou(model, held) if held else ""
            print("epoch %3d  loss %.4f%s  (%.0f s)" %
                  (epoch + 1, total / (per_epoch // batch), held_report, time.time() - t0), flush=True)
    held_iou = iou(model, held)
    os.makedirs(args.out, exist_ok=True)
    onnx_path = os.path.join(args.out, "shaft_net.onnx")
    torch.save(model.state_dict(), os.path.join(args.out, "shaft_net.pt"))
    export(model, onnx_path)
    with open(os.path.join(args.out, "shaft_net.yaml"), "w") as f:
        f.write("%YAML:1.0\n---\n")  # (the header OpenCV's FileStorage needs)
        f.write("# The learned shaft mask (scripts/train_shaft_net.sh reproduces it). Input: the BGR frame resized\n"
                "# to width x height, (pixel - mean) * scale; output: logits per class, then the sides' logit,\n"
                "# at the input size.\n")
        f.write("model: shaft_net.onnx\nwidth: %d\nheight: %d\nmean: %.1f\nscale: %.10f\n" % (NET_W, NET_H, MEAN, SCALE))
        f.write("classes: [%s]\n" % ", ".join(CLASSES))
        f.write("side: %d  # the output channel of the shaft's sides (a logit)\n" % SIDE)
        f.write("trained_on: [%s]\n" % ", ".join(s for s in sites if s != args.hold_out))
        f.write("held_out: [%s]\n" % args.hold_out)
        if held:
            f.write("held_out_shaft_iou: %.3f\n" % held_iou)
        f.write("epochs: %d\nseed: %d\narch: %s\npretrained: %s\n" %
                (args.epochs, args.seed, args.arch, "imagenet (nsfwjs@4.3.0)" if args.pretrained else "none"))
    if args.reference:
        im = cv2.imread(args.reference, cv2.IMREAD_COLOR)
        if im is None:
            sys.exit("train_shaft_net.py: cannot read %s" % args.reference)
        model.eval()
        with torch.no_grad():
            out = model(to_input([cv2.resize(im, (NET_W, NET_H), interpolation=cv2.INTER_AREA)]))[0].numpy()
        fs = cv2.FileStorage(os.path.join(args.out, "shaft_net_reference.yml.gz"), cv2.FILE_STORAGE_WRITE)
        fs.write("frame", os.path.basename(args.reference))
        fs.write("frame_sum", float(im.astype(np.float64).sum()))  # the C++ test renders the same frame
        for c, name in enumerate(CLASSES + ("side",)):
            fs.write(name, out[c].astype(np.float32))
        fs.release()
    held_report = "held-out (%s) shaft IoU %.3f" % (args.hold_out, held_iou) if held else "no site held out"
    print("trained in %.0f s on %d threads; %s; model %s (%d bytes)" %
          (time.time() - t0, torch.get_num_threads(), held_report, onnx_path, os.path.getsize(onnx_path)), flush=True)


if __name__ == "__main__":
    main()
