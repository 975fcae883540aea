#!/usr/bin/python3
# Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
"""The run report of one recording: DIR/index.html with PNG plots, from what
`endo_guidance_offline --report DIR` wrote there (frames.jsonl, run.yaml, worst/).

  scripts/run_report.py DIR

Plots: detections per frame over time; each trocar's position converging with its 1-sigma band;
the imaged axes in (theta, rho), where the axes through one trocar lie on one sinusoid (the
trocar's image point); the overlays of the frames with the largest line residual; then the
parameters and versions. `summarize()` is also the batch command's per-recording summary.
"""
import html
import json
import math
import os
import sys

import numpy as np
import yaml

COLOURS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2", "#7f7f7f"]


def load_frames(path):
    """The JSON lines; a truncated last line (an interrupted run) is dropped."""
    rows = []
    with open(path) as f:
        for line in f:
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                break
    return rows


def _sigma_mm(cov):
    if cov is None or any(c is None for c in cov):
        return [float("nan")] * 3
    return [math.sqrt(max(cov[4 * i], 0.0)) * 1e3 for i in range(3)]


def summarize(rows):
    """Frames, shafts per frame, errors, and each trocar: first frame located (and time), final
    position, spread of the axes (deg), 1-sigma (mm), views."""
    t0 = next((r["stamp"] for r in rows if r.get("stamp") is not None), 0.0)
    good = [r for r in rows if "error" not in r]
    errors = {}
    for r in rows:
        if "error" in r:
            errors[r["error"]] = errors.get(r["error"], 0) + 1
    trocars = {}
    for r in good:
        for p in r["insertion_points"]:
            tr = trocars.setdefault(p["id"], {"id": p["id"], "located_frame": None, "located_s": None})
            if p["located"] and tr["located_frame"] is None:
                tr["located_frame"], tr["located_s"] = r["frame"], r["stamp"] - t0
            tr.update(position_mm=[x * 1e3 for x in p["position"]], views=p["views"], located=p["located"],
                      spread_deg=math.degrees(math.asin(min(1.0, p["conditioning"]))) if p["conditioning"] is not None else None,
                      sigma_mm=max(_sigma_mm(p["covariance"])), last_frame=r["frame"])
    last_ids = {p["id"] for p in good[-1]["insertion_points"]} if good else set()
    return {
        "frames": len(rows),
        "rejected": len(rows) - len(good),
        "shafts_per_frame": (sum(len(r["instruments"]) for r in good) / len(good)) if good else 0.0,
        "errors": errors,
        "duration_s": (rows[-1]["stamp"] - t0) if rows and rows[-1].get("stamp") is not None else 0.0,
        # trocars still tracked at the end (a discarded candidate is not a trocar of the recording)
        "trocars": [trocars[i] for i in sorted(trocars) if i in last_ids],
    }


def _plt():
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    return plt


def plot_detections(rows, out):
    plt = _plt()
    t0 = rows[0]["stamp"] if rows else 0.0
    good = [r for r in rows if "error" not in r]
    t = [r["stamp"] - t0 for r in good]
    fig, ax = plt.subplots(figsize=(10, 3.2), dpi=100)
    ax.step(t, [len(r["instruments"]) for r in good], where="post", color=COLOURS[0], lw=3.0, label="shafts detected")
    ax.step(t, [sum(1 for o in r["instruments"] if o["insertion_point"] >= 0) for r in good], where="post",
            color=COLOURS[1], label="attached to a trocar")
    bad = [r["stamp"] - t0 for r in rows if "error" in r and r.get("stamp") is not None]
    if bad:
        ax.plot(bad, [0] * len(bad), "x", color=COLOURS[3], label="frame rejected (%d)" % len(bad))
    ax.set_xlabel("time (s)")
    ax.set_ylabel("per frame")
    ax.set_title("Detections per frame")
    ax.grid(alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)


def plot_trocars(rows, summary, out):
    plt = _plt()
    t0 = rows[0]["stamp"] if rows else 0.0
    keep = {tr["id"] for tr in summary["trocars"]}
    series = {}
    for r in rows:
        if "error" in r:
            continue
        for p in r["insertion_points"]:
            if p["id"] in keep:
                s = series.setdefault(p["id"], ([], [], []))
                s[0].append(r["stamp"] - t0)
                s[1].append([x * 1e3 for x in p["position"]])
                s[2].append(_sigma_mm(p["covariance"]))
    fig, axes = plt.subplots(3, 1, figsize=(10, 6.5), dpi=100, sharex=True)
    for k, (tid, (t, x, s)) in enumerate(sorted(series.items())):
        x, s, c = np.array(x), np.array(s), COLOURS[k % len(COLOURS)]
        for i, ax in enumerate(axes):
            ax.plot(t, x[:, i], color=c, lw=1.2, label="trocar %d" % tid if i == 0 else None)
            ax.fill_between(t, x[:, i] - s[:, i], x[:, i] + s[:, i], color=c, alpha=0.25, lw=0)
        tr = next(tr for tr in summary["trocars"] if tr["id"] == tid)
        if tr["located_s"] is not None:
            for ax in axes:
                ax.axvline(tr["located_s"], color=c, ls="--", lw=0.8)
    for ax, name in zip(axes, "xyz"):
        ax.set_ylabel(name + " (mm)")
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("time (s); dashed: located")
    axes[0].set_title("Insertion points (optical frame) with their 1-sigma band")
    if series:
        axes[0].legend(loc="upper right", fontsize=8)
    else:
        axes[0].text(0.5, 0.5, "no insertion point estimated", transform=axes[0].transAxes, ha="center")
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)


def image_line(K, moment):
    """The image of a Pluecker axis: l ~ K^-T m (the moment is the normal of the plane through
    the centre), as (theta, rho) with x cos(theta) + y sin(theta) = rho, theta in [0, pi)."""
    a, b, c = np.linalg.solve(K.T, np.asarray(moment, float))
    n = math.hypot(a, b)
    if n < 1e-12:
        return None
    a, b, c = a / n, b / n, c / n
    theta = math.atan2(b, a)
    if theta < 0:
        theta, c = theta + math.pi, -c
    if theta >= math.pi:
        theta -= math.pi
    return theta, -c


def plot_theta_rho(rows, run, summary, out):
    plt = _plt()
    K = np.array(run["camera_matrix"], float).reshape(3, 3)
    fig, ax = plt.subplots(figsize=(10, 4.5), dpi=100)
    ids = sorted({tr["id"] for tr in summary["trocars"]})
    pts = {}
    for r in rows:
        if "error" in r:
            continue
        for o in r["instruments"]:
            tr = image_line(K, o["moment"])
            if tr:
                pts.setdefault(o["insertion_point"], []).append(tr)
    for key, v in sorted(pts.items()):
        v = np.array(v)
        c = COLOURS[ids.index(key) % len(COLOURS)] if key in ids else "#999999"
        ax.plot(np.degrees(v[:, 0]), v[:, 1], ".", ms=2.5, color=c,
                label=("axes of trocar %d" % key) if key in ids else "axes not attached")
    th = np.linspace(0, math.pi, 361)
    last = next((r for r in reversed(rows) if "error" not in r), None)
    for p in (last["insertion_points"] if last else []):
        if p["id"] in ids and p["pixel"] is not None:
            u, v = p["pixel"]
            ax.plot(np.degrees(th), u * np.cos(th) + v * np.sin(th), "-", lw=1.0,
                    color=COLOURS[ids.index(p["id"]) % len(COLOURS)],
                    label="trocar %d's image point (%.0f, %.0f) px" % (p["id"], u, v))
    ax.set_xlim(0, 180)
    if pts:  # rho around the axes (the sinusoids span thousands of px when a trocar is far outside)
        rho = np.concatenate([np.array(v)[:, 1] for v in pts.values()])
        pad = max(50.0, 0.25 * (rho.max() - rho.min()))
        ax.set_ylim(rho.min() - pad, rho.max() + pad)
    ax.set_xlabel("theta (deg)")
    ax.set_ylabel("rho (px)")
    ax.set_title("Imaged axes in (theta, rho): the axes through one trocar lie on its sinusoid")
    ax.grid(alpha=0.3)
    if pts:
        ax.legend(loc="best", fontsize=7, markerscale=4)
    fig.tight_layout()
    fig.savefig(out)
    plt.close(fig)


def _table(header, rows):
    h = "".join("<th>%s</th>" % html.escape(str(x)) for x in header)
    b = "".join("<tr>%s</tr>" % "".join("<td>%s</td>" % html.escape(str(x)) for x in r) for r in rows)
    return "<table><tr>%s</tr>%s</table>" % (h, b)


def fmt(x, spec):
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else format(x, spec)


def write_report(d):
    rows = load_frames(os.path.join(d, "frames.jsonl"))
    with open(os.path.join(d, "run.yaml")) as f:
        run = yaml.safe_load(f)
    worst_path = os.path.join(d, "worst", "worst.yaml")
    worst = (yaml.safe_load(open(worst_path)) or []) if os.path.exists(worst_path) else []
    s = summarize(rows)
    plot_detections(rows, os.path.join(d, "detections.png"))
    plot_trocars(rows, s, os.path.join(d, "trocars.png"))
    plot_theta_rho(rows, run, s, os.path.join(d, "theta_rho.png"))

    trocar_rows = [[t["id"], fmt(t["located_s"], ".2f"), t["located_frame"] if t["located_frame"] is not None else "-",
                    "(%.1f, %.1f, %.1f)" % tuple(t["position_mm"]), fmt(t["sigma_mm"], ".2f"),
                    fmt(t["spread_deg"], ".1f"), t["views"]] for t in s["trocars"]]
    params_text = ""
    pf = run.get("parameters_file", "")
    if pf and os.path.isfile(pf):
        params_text = "<h3>%s</h3><pre>%s</pre>" % (html.escape(pf), html.escape(open(pf).read()))
    run_rows = [[k, v if not isinstance(v, list) else ", ".join(map(str, v))] for k, v in run.items()]
    worst_html = "".join(
        '<figure><img class="frame" src="worst/%s" alt="frame %d"><figcaption>frame %d (%s): largest line residual %.2f px'
        '</figcaption></figure>' % (html.escape(w["image"]), w["frame"], w["frame"], html.escape(str(w["source"])),
                                    w["residual_px"]) for w in worst) or "<p>no frame with a detection</p>"
    title = "endo_guidance run report: " + ", ".join(os.path.basename(i) for i in run.get("inputs", []))
    page = """<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>
body {{ font-family: sans-serif; margin: 24px; max-width: 1100px; color: #222; }}
table {{ border-collapse: collapse; margin: 8px 0 16px; font-size: 13px; }}
td, th {{ border: 1px solid #ccc; padding: 3px 8px; text-align: left; }}
img.plot {{ width: 1000px; display: block; margin: 8px 0 20px; }}
img.frame {{ width: 340px; }}
figure {{ display: inline-block; margin: 4px; font-size: 12px; width: 340px; vertical-align: top; }}
pre {{ background: #f6f6f6; padding: 8px; font-size: 11px; overflow-x: auto; }}
</style></head><body>
<h1>{title}</h1>
<p>{frames} frames ({rejected} rejected) over {duration:.1f} s; {spf:.2f} shafts per frame; {ntroc} trocars.</p>
{errors}
<h2>Trocars</h2>
{trocars}
<h2>Detections per frame</h2>
<img class="plot" id="detections" src="detections.png" alt="detections per frame">
<h2>Insertion points converging</h2>
<img class="plot" id="trocars" src="trocars.png" alt="trocar positions with 1-sigma">
<h2>Imaged axes in (theta, rho)</h2>
<img class="plot" id="theta_rho" src="theta_rho.png" alt="imaged axes in theta rho">
<h2>Worst frames (largest line residual)</h2>
{worst}
<h2>Parameters and versions</h2>
{run}
{params}
<script>
window.addEventListener("load", function () {{
  var imgs = document.images, n = 0;
  for (var i = 0; i < imgs.length; ++i) if (imgs[i].complete && imgs[i].naturalWidth > 0) ++n;
  document.body.setAttribute("data-images-loaded", n + "/" + imgs.length);
}});
</script>
</body></html>
""".format(title=html.escape(title), frames=s["frames"], rejected=s["rejected"], duration=s["duration_s"],
           spf=s["shafts_per_frame"], ntroc=len(s["trocars"]),
           errors=_table(["error", "frames"], sorted(s["errors"].items())) if s["errors"] else "",
           trocars=_table(["id", "located at (s)", "frame", "position (mm)", "1-sigma (mm)", "spread (deg)", "views"],
                          trocar_rows) if trocar_rows else "<p>no trocar estimated</p>",
           worst=worst_html, run=_table(["", ""], run_rows), params=params_text)
    tmp = os.path.join(d, "index.html.tmp")
    with open(tmp, "w") as f:
        f.write(page)
    os.replace(tmp, os.path.join(d, "index.html"))
    return s


def main(argv):
    if len(argv) != 2 or argv[1].startswith("-"):
        print(__doc__.strip().split("\n\n")[1], file=sys.stderr)
        return 2
    d = argv[1]
    for need in ("frames.jsonl", "run.yaml"):
        if not os.path.isfile(os.path.join(d, need)):
            print("run_report.py: %s has no %s (written by endo_guidance_offline --report)" % (d, need), file=sys.stderr)
            return 1
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        print("run_report.py: matplotlib is missing (apt-get install python3-matplotlib; scripts/setup.sh does)", file=sys.stderr)
        return 1
    write_report(d)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
