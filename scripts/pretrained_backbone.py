#!/usr/bin/env python3
# Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
"""ImageNet-pretrained MobileNetV2 weights for the shaft network, at training time only.

Source: the npm package nsfwjs@4.3.0 (MIT; pinned below by version and sha512) bundles Keras'
MobileNetV2 (width 1.0, 224 px; Keras Applications' ImageNet weights, Apache-2.0) as a TF.js
layers model: dist/models/mobilenet_v2/model.min.js (topology and weight manifest) and
group1-shard1of1.min.js (the weights, base64, uint8-quantised: value = q * scale + min). Its
layers Conv1 .. block_10 are Keras' ImageNet weights, frozen while that package trained its own
head (trainable: false in the topology); block_11 onwards were fine-tuned on its task and are
not used here.

  pretrained_backbone.py fetch DIR   npm pack (node and npm needed), checksum, decode ->
                                     DIR/mobilenet_v2_keras.npz (Keras names and layouts)
  pretrained_backbone.py check DIR   the converted encoder's output on a fixed image against
                                     TF.js's own (test/training/mobilenet_v2_tfjs_reference.json,
                                     made by scripts/pretrained_backbone_reference.js); exit 77
                                     when PyTorch or the fetched package is absent

Layer mapping onto torchvision's mobilenet_v2().features (made without any download):
Conv1 -> features.0, expanded_conv_* -> features.1, block_i_{expand,depthwise,project} ->
features[i+1].conv; conv kernels (kh, kw, in, out) -> (out, in, kh, kw), depthwise
(kh, kw, in, 1) -> (in, 1, kh, kw); batch norm eps 1e-3 (Keras'). Keras takes RGB scaled to
x / 127.5 - 1; the project feeds BGR with the same scale, so Conv1's input channels are reversed.
Keras pads its stride-2 convolutions on the bottom/right only (ZeroPadding2D ((0,1),(0,1)));
keras_padding() reproduces that, for the check and for the network trained on these weights.
"""
import argparse
import base64
import hashlib
import json
import os
import subprocess
import sys
import tarfile

import numpy as np

PACKAGE = "nsfwjs@4.3.0"
TARBALL = "nsfwjs-4.3.0.tgz"
SHA512 = "WTKDte0vp1X97N1h34P79G/hG+sVT3+TnDz9di1WseIJR93v11E4viNX7Vg9WsO6HYoR772Nzq2iM8jo3XBZ+g=="
MODEL_JS = "package/dist/models/mobilenet_v2/model.min.js"
SHARD_JS = "package/dist/models/mobilenet_v2/group1-shard1of1.min.js"
LAST_IMAGENET_BLOCK = 10  # block_11 onwards were fine-tuned on nsfwjs' own task
NPZ = "mobilenet_v2_keras.npz"
HERE = os.path.dirname(os.path.abspath(__file__))
REFERENCE = os.path.join(HERE, "..", "test", "training", "mobilenet_v2_tfjs_reference.json")


def fetch(directory):
    """The package's tarball (npm pack, checksum verified) decoded to DIR/NPZ; returns its path."""
    directory = os.path.abspath(directory)
    os.makedirs(directory, exist_ok=True)
    out = os.path.join(directory, NPZ)
    if os.path.exists(out):
        return out
    tgz = os.path.join(directory, TARBALL)
    if not os.path.exists(tgz):
        try:
            subprocess.run(["npm", "pack", PACKAGE, "--pack-destination", directory, "--silent"], check=True,
                           stdout=subprocess.DEVNULL, timeout=600)
        except (OSError, subprocess.SubprocessError) as e:
            sys.exit("pretrained_backbone: npm pack %s failed (%s); node and npm are needed at training time" % (PACKAGE, e))
    digest = base64.b64encode(hashlib.sha512(open(tgz, "rb").read()).digest()).decode()
    if digest != SHA512:
        os.remove(tgz)
        sys.exit("pretrained_backbone: %s has sha512 %s, not the pinned %s (removed)" % (TARBALL, digest, SHA512))
    unpacked = os.path.join(directory, "nsfwjs")
    with tarfile.open(tgz) as t:
        for name in (MODEL_JS, SHARD_JS):
            t.extract(t.getmember(name), unpacked)
    # The two files are UMD modules: node evaluates them (exports: the model JSON, the base64 string).
    js = ("const fs=require('fs');const m=require(process.argv[1]);const w=require(process.argv[2]);"
          "fs.writeFileSync(process.argv[3],JSON.stringify(m));fs.writeFileSync(process.argv[4],Buffer.from(w,'base64'));")
    model_json, weights_bin = os.path.join(directory, "model.json"), os.path.join(directory, "weights.bin")
    try:
        subprocess.run(["node", "-e", js, os.path.join(unpacked, MODEL_JS), os.path.join(unpacked, SHARD_JS),
                        model_json, weights_bin], check=True, timeout=300)
    except (OSError, subprocess.SubprocessError) as e:
        sys.exit("pretrained_backbone: node could not read the package's model (%s)" % e)
    weights = dequantise(json.load(open(model_json)), open(weights_bin, "rb").read())
    np.savez(out + ".part.npz", **weights)
    os.replace(out + ".part.npz", out)
    return out


def dequantise(model, raw):
    """{Keras weight name: float32 array} from the manifest (value = q * scale + min for uint8)."""
    out, offset = {}, 0
    for group in model["weightsManifest"]:
        for w in group["weights"]:
            n = int(np.prod(w["shape"])) if w["shape"] else 1
            q = w.get("quantization")
            if q:
                dt = {"uint8": np.uint8, "uint16": np.uint16, "float16": np.float16}[q["dtype"]]
                vals = np.frombuffer(raw, dt, n, offset)
                offset += n * np.dtype(dt).itemsize
                vals = vals.astype(np.float32) if dt == np.float16 else vals.astype(np.float32) * q["scale"] + q["min"]
            else:
                vals = np.frombuffer(raw, np.float32, n, offset)
                offset += 4 * n
            out[w["name"]] = vals.reshape(w["shape"]).astype(np.float32)
    if offset != len(raw):
        sys.exit("pretrained_backbone: the manifest covers %d of the shard's %d bytes" % (offset, len(raw)))
    return out


def keras_layers(last_block=LAST_IMAGENET_BLOCK):
    """(torchvision conv prefix, its batch norm's prefix, Keras conv, Keras batch norm, depthwise)."""
    layers = [("0.0", "0.1", "Conv1", "bn_Conv1", False),
              ("1.conv.0.0", "1.conv.0.1", "expanded_conv_depthwise", "expanded_conv_depthwise_BN", True),
              ("1.conv.1", "1.conv.2", "expanded_conv_project", "expanded_conv_project_BN", False)]
    for i in range(1, last_block + 1):
        p, k = "%d.conv." % (i + 1), "block_%d_" % i
        layers += [(p + "0.0", p + "0.1", k + "expand", k + "expand_BN", False),
                   (p + "1.0", p + "1.1", k + "depthwise", k + "depthwise_BN", True),
                   (p + "2", p + "3", k + "project", k + "project_BN", False)]
    return layers


def torch_state(keras, bgr=True, var_floor=None, last_block=LAST_IMAGENET_BLOCK):
    """torchvision mobilenet_v2().features state (numpy) for features.0 .. features[last_block + 1].
    bgr: Conv1 takes BGR (its input channels reversed). var_floor: running variances below it are
    raised to it (dequantisation leaves some exactly 0); None keeps them as TF.js has them."""
    state = {}
    for prefix, b, conv, bn, depthwise in keras_layers(last_block):
        k = keras[conv + "/depthwise_kernel" if depthwise else conv + "/kernel"]
        k = k.transpose(2, 3, 0, 1) if depthwise else k.transpose(3, 2, 0, 1)
        if conv == "Conv1" and bgr:
            k = k[:, ::-1]
        state[prefix + ".weight"] = np.ascontiguousarray(k)
        var = keras[bn + "/moving_variance"]
        if var_floor is not None:
            var = np.maximum(var, var_floor)
        state[b + ".weight"] = keras[bn + "/gamma"]
        state[b + ".bias"] = keras[bn + "/beta"]
        state[b + ".running_mean"] = keras[bn + "/moving_mean"]
        state[b + ".running_var"] = var
    return state


def encoder(state, last_block=LAST_IMAGENET_BLOCK):
    """torchvision's MobileNetV2 features up to block_<last_block>, loaded with state, BN eps 1e-3."""
    import torch
    import torchvision
    net = torchvision.models.mobilenet_v2(weights=None).features[:last_block + 2]
    for m in net.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            m.eps = 1e-3
    missing, unexpected = net.load_state_dict({k: torch.from_numpy(np.array(v)) for k, v in state.items()}, strict=False)
    missing = [m for m in missing if not m.endswith("num_batches_tracked")]
    if missing or unexpected:
        sys.exit("pretrained_backbone: the state does not fit torchvision's layout (missing %s, unexpected %s)" %
                 (missing[:4], unexpected[:4]))
    return net


def keras_padding(net):
    """Keras' padding of the stride-2 3x3 convolutions, bottom/right only, as a pre-hook of each
    (the state's names stay torchvision's; ONNX gets a Pad before each)."""
    import torch
    import torch.nn.functional as F
    for m in net.modules():
        if isinstance(m, torch.nn.Conv2d) and m.stride == (2, 2) and m.kernel_size == (3, 3):
            m.padding = (0, 0)
            m.register_forward_pre_hook(lambda mod, inp: (F.pad(inp[0], (0, 1, 0, 1)),))
    return net


def reference_image(h, w):
    """The fixed RGB test image (uint8), also drawn by pretrained_backbone_reference.js."""
    y, x = np.mgrid[0:h, 0:w].astype(np.int64)
    return np.stack([(3 * x + 5 * y + x * y) % 256, (x * x + 2 * y) % 256, (7 * x + y * y) % 256], -1).astype(np.uint8)


def check(directory):
    try:
        import torch
        import torchvision  # noqa: F401
    except ImportError:
        print("pretrained_backbone check: SKIPPED (PyTorch/torchvision absent: training only)")
        return 77
    npz = os.path.join(directory, NPZ)
    if not os.path.exists(npz):
        print("pretrained_backbone check: SKIPPED (no %s: pretrained_backbone.py fetch %s)" % (npz, directory))
        return 77
    ref = json.load(open(REFERENCE))
    keras = dict(np.load(npz))
    net = keras_padding(encoder(torch_state(keras, bgr=True, var_floor=None))).eval()
    rgb = reference_image(ref["height"], ref["width"])
    bgr = rgb[..., ::-1].astype(np.float32)
    x = torch.from_numpy(((bgr - 127.5) / 127.5).transpose(2, 0, 1)[None].copy())
    worst, ok = 0.0, True
    with torch.no_grad():
        outs, y = {}, x
        for i, layer in enumerate(net):
            y = layer(y)
            outs[i] = y
    for name, r in ref["outputs"].items():
        got = outs[r["features_index"]][0].numpy().transpose(1, 2, 0)  # HWC, as TF.js
        if list(got.shape) != r["shape"]:
            print("  %s: shape %s, TF.js %s" % (name, list(got.shape), r["shape"]))
            ok = False
            continue
        got = got.reshape(-1)[np.array(r["indices"])]
        want = np.array(r["values"], np.float32)
        err = float(np.abs(got - want).max() / max(1e-6, np.abs(want).max()))
        worst = max(worst, err)
        print("  %-26s %-14s max |torch - tfjs| / max |tfjs| = %.2e" % (name, "x".join(map(str, r["shape"])), err))
        ok &= err < 1e-4
    print("pretrained_backbone check: %s (worst relative error %.2e, bound 1e-4)" % ("OK" if ok else "FAILED", worst))
    return 0 if ok else 1


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("command", choices=("fetch", "check"))
    ap.add_argument("dir", help="where the package and the decoded weights go (e.g. build/pretrained)")
    a = ap.parse_args()
    if a.command == "fetch":
        print(fetch(a.dir))
        return 0
    return check(a.dir)


if __name__ == "__main__":
    sys.exit(main())
