#!/usr/bin/python3
"""What the pipeline outputs, as one SHA-256 per input: proof that a refactor changed no behaviour.

Runs endo_guidance_offline on the rendered scenes (clean, hard, black_circular; the colour and
the learned detector) and, with --shared, on the shared real data (the in-vivo stills of each
operation as independent frames, the first frames of each robotic video; the colour method). Each JSON line is kept
whole except `latency_ms` (timing) and `source` (reduced to the file name); the digest is taken
over the canonical JSON (sorted keys).

  scripts/behaviour_digest.py [--bin DIR] [--shared DATA] [--write FILE | --check FILE] [--keep DIR]

--check compares with FILE (test/behaviour_digest.txt is the committed one: the rendered scenes
of this machine's build) and exits 1 on any difference, naming the inputs; inputs absent here
(no shared data) are reported as skipped. --write records the digests. Without either, prints them.

The programs run with OpenCV's AVX-512 dispatch off (OPENCV_CPU_DISABLE=AVX512-SKX): its DNN
kernels sum in another order than the AVX2 ones, which changes the learned detector's output in
the last bits (and so its digest) on a CPU that has AVX-512; the digest is of the code's behaviour,
the same on every x86-64 CPU with AVX2.
"""
import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENES = ("clean", "hard", "black_circular")
FRAMES = 60          # per rendered scene: long enough for the trocars to be located
ROBOTIC_FRAMES = 40  # per robotic video (first frames)


def run(cmd):
    env = dict(os.environ, OPENCV_CPU_DISABLE="AVX512-SKX")
    r = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    if r.returncode != 0:
        sys.exit("behaviour_digest: %s failed (%d):\n%s" % (os.path.basename(cmd[0]), r.returncode, r.stderr[-2000:]))
    return r.stdout


def digest(jsonl):
    h = hashlib.sha256()
    n = 0
    for line in jsonl.splitlines():
        if not line.strip():
            continue
        obj = json.loads(line)
        obj.pop("latency_ms", None)
        if "source" in obj:
            obj["source"] = os.path.basename(str(obj["source"]))
        h.update(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode())
        h.update(b"\n")
        n += 1
    if n == 0:
        sys.exit("behaviour_digest: no output lines")
    return "%s %d" % (h.hexdigest(), n)


def inputs(binary, tmp, shared):
    """(name, offline arguments) for every input this machine has."""
    out = []
    for scene in SCENES:
        seq = os.path.join(tmp, scene)
        run([os.path.join(binary, "endo_guidance_synthetic"), "--write-sequence", seq, "--frames", str(FRAMES),
             "--scene", scene])
        base = ["--camera", os.path.join(seq, "camera.yaml"), "--radius", "0.004", os.path.join(seq, "frames")]
        out.append(("rendered/%s/colour" % scene, base + ["--detector", "colour"]))
        out.append(("rendered/%s/learned" % scene, base + ["--detector", "learned"]))
    if shared:
        invivo = os.path.join(shared, "endovis15_rigid_invivo")
        invivo_cam = os.path.join(HERE, "config", "cameras", "assumed_640x480.yaml")
        for op in ("OP1", "OP2", "OP3"):
            raw = os.path.join(invivo, op, "Raw")
            if os.path.isdir(raw):
                out.append(("shared/invivo/%s" % op,
                            ["--detector", "colour", "--camera", invivo_cam, "--radius", "0.0025", "--independent", raw]))
        robotic = os.path.join(shared, "endovis15_robotic")
        cam = os.path.join(HERE, "config", "cameras", "assumed_720x576.yaml")
        for ds in ("Dataset1", "Dataset2"):
            frames = os.path.join(robotic, ds, "frames_png")
            if os.path.isdir(frames):
                first = sorted(f for f in os.listdir(frames) if f.endswith(".png"))[:ROBOTIC_FRAMES]
                out.append(("shared/robotic/%s" % ds,
                            ["--detector", "colour", "--camera", cam, "--radius", "0.004"] + [os.path.join(frames, f) for f in first]))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--bin", default=os.environ.get("ENDO_GUIDANCE_BIN", os.path.join(HERE, "build/devel/lib/endo_guidance")))
    ap.add_argument("--shared", help="the shared data directory (../shared/data)")
    g = ap.add_mutually_exclusive_group()
    g.add_argument("--write", metavar="FILE")
    g.add_argument("--check", metavar="FILE")
    ap.add_argument("--keep", metavar="DIR", help="keep the JSON lines here (to diff a difference)")
    a = ap.parse_args()
    offline = os.path.join(a.bin, "endo_guidance_offline")
    if not os.access(offline, os.X_OK):
        sys.exit("behaviour_digest: no %s (build first: scripts/setup.sh)" % offline)
    with tempfile.TemporaryDirectory() as tmp:
        got = {}
        for name, args in inputs(a.bin, tmp, a.shared):
            jsonl = run([offline, "--quiet"] + args)
            got[name] = digest(jsonl)
            if a.keep:
                path = os.path.join(a.keep, name.replace("/", "__") + ".jsonl")
                os.makedirs(a.keep, exist_ok=True)
                open(path, "w").write(jsonl)
            print("%-32s %s" % (name, got[name]), flush=True)
    if a.write:
        with open(a.write, "w") as f:
            f.write("# scripts/behaviour_digest.py: input, SHA-256 of its JSON lines (less latency_ms), lines\n")
            for name in sorted(got):
                f.write("%s %s\n" % (name, got[name]))
        return 0
    if a.check:
        want = {}
        for line in open(a.check):
            if line.strip() and not line.startswith("#"):
                name, value = line.split(None, 1)
                want[name] = value.strip()
        bad = [n for n in sorted(want) if n in got and got[n] != want[n]]
        for n in sorted(set(want) - set(got)):
            print("%-32s skipped (input absent here)" % n)
        for n in sorted(set(got) - set(want)):
            print("%-32s not in %s: not compared" % (n, a.check))
        if bad:
            print("behaviour changed: %s" % ", ".join(bad), file=sys.stderr)
            return 1
        print("behaviour unchanged: %d inputs" % len([n for n in want if n in got]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
