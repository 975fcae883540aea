#!/usr/bin/python3
# Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
"""Batch replay: every recording (bags, videos) under the given folders through
endo_guidance_offline, a process per recording up to --jobs at a time, with a progress bar and a
summary table (OUT/summary.md, OUT/summary.csv). Resumable: a recording whose OUT/<name>/done.json
matches its file (size, mtime) is not redone; an interrupted one is.

  scripts/batch_replay.py FOLDER_OR_FILE... --out DIR [--jobs N] [--report] [--camera CAM.yaml]
      [--radius M] [--params P.yaml] [--detector colour|learned] [--exclude GLOB]... [--image-topic T]

A video's camera: <video stem>.yaml or camera.yaml beside it, else --camera (a bag's camera_info
is used when it has one). --report: each recording's run report (OUT/<name>/index.html) and
OUT/index.html with the summary linking them.
"""
import argparse
import csv
import fnmatch
import html
import json
import os
import signal
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import run_report  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
VIDEO = (".avi", ".mp4", ".mkv", ".mov", ".m4v", ".mpg", ".webm")


def find_offline():
    for d in (os.environ.get("ENDO_GUIDANCE_BIN", ""), os.path.join(HERE, "..", "build", "devel", "lib", "endo_guidance")):
        p = os.path.join(d, "endo_guidance_offline")
        if d and os.access(p, os.X_OK):
            return os.path.abspath(p)
    sys.exit("batch_replay.py: endo_guidance_offline not found (build with scripts/setup.sh, or set ENDO_GUIDANCE_BIN)")


def recordings(paths, exclude):
    found = []
    for p in paths:
        if os.path.isfile(p):
            found.append(os.path.abspath(p))
            continue
        if not os.path.isdir(p):
            sys.exit("batch_replay.py: '%s' does not exist" % p)
        for root, dirs, files in os.walk(p):
            dirs.sort()
            for f in sorted(files):
                if f.lower().endswith(VIDEO + (".bag",)):
                    found.append(os.path.abspath(os.path.join(root, f)))
    found = [f for f in found if not any(fnmatch.fnmatch(os.path.basename(f), g) or fnmatch.fnmatch(f, g) for g in exclude)]
    return sorted(dict.fromkeys(found))


def name_of(path, roots):
    """A unique, readable output name: the path below its folder argument, '/' -> '__'."""
    for r in roots:
        r = os.path.abspath(r)
        if os.path.isdir(r) and path.startswith(r + os.sep):
            rel = os.path.relpath(path, os.path.dirname(r))
            return rel.replace(os.sep, "__")
    return os.path.basename(path)


def frame_count(path, topic):
    try:
        if path.endswith(".bag"):
            import rosbag
            with rosbag.Bag(path) as b:
                return b.get_message_count(topic)
        import cv2
        c = cv2.VideoCapture(path)
        n = int(c.get(cv2.CAP_PROP_FRAME_COUNT)) if c.isOpened() else 0
        return max(n, 0)
    except Exception:
        return 0


def camera_for(path, fallback):
    if path.endswith(".bag"):
        return fallback
    d, stem = os.path.dirname(path), os.path.splitext(os.path.basename(path))[0]
    for c in (os.path.join(d, stem + ".yaml"), os.path.join(d, "camera.yaml")):
        if os.path.isfile(c):
            return c
    return fallback


def fingerprint(path):
    st = os.stat(path)
    return {"size": st.st_size, "mtime": int(st.st_mtime)}


def is_done(out, path):
    try:
        with open(os.path.join(out, "done.json")) as f:
            return json.load(f).get("input") == fingerprint(path)
    except (OSError, ValueError):
        return False


def count_lines(p):
    try:
        with open(p, "rb") as f:
            return sum(1 for _ in f)
    except OSError:
        return 0


def bar(done, total, width=30):
    k = int(width * min(1.0, done / total)) if total else 0
    return "[" + "#" * k + " " * (width - k) + "]"


def main(argv):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("inputs", nargs="+", help="folders (searched recursively) or recordings")
    ap.add_argument("--out", required=True, help="output folder (one sub-folder per recording)")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1, help="recordings at a time (default: the cores)")
    ap.add_argument("--report", action="store_true", help="run reports: OUT/<name>/index.html and OUT/index.html")
    ap.add_argument("--camera", help="camera_info YAML for videos without one beside them")
    ap.add_argument("--radius", type=float, default=0.004, help="shaft radius, m (default 0.004)")
    ap.add_argument("--params", help="pipeline parameters YAML")
    ap.add_argument("--detector", choices=["colour", "learned"])
    ap.add_argument("--image-topic", default="/camera/image_raw", help="a bag's image topic")
    ap.add_argument("--exclude", action="append", default=[], help="glob of files to leave out (repeatable)")
    a = ap.parse_args(argv[1:])
    if a.jobs < 1:
        ap.error("--jobs must be >= 1")
    offline = find_offline()
    recs = recordings(a.inputs, a.exclude)
    if not recs:
        sys.exit("batch_replay.py: no recordings (bags, videos) under %s" % " ".join(a.inputs))
    os.makedirs(a.out, exist_ok=True)
    names = {r: name_of(r, a.inputs) for r in recs}
    todo = [r for r in recs if not is_done(os.path.join(a.out, names[r]), r)]
    print("%d recordings, %d done before, %d to process, %d at a time" % (len(recs), len(recs) - len(todo), len(todo), a.jobs),
          file=sys.stderr)
    expected = {r: frame_count(r, a.image_topic) for r in todo}
    total = sum(expected.values())
    tty = sys.stderr.isatty()
    running, queue, failed = {}, list(todo), {}
    start = time.time()

    def stop(*_):
        for p, _r in running.values():
            p.terminate()
        for p, _r in running.values():
            p.wait()
        print("\ninterrupted: %d finished recordings kept; run again to resume" % (len(todo) - len(queue) - len(running)), file=sys.stderr)
        sys.exit(130)

    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGTERM, stop)
    finished = 0
    frames_done = 0
    while queue or running:
        while queue and len(running) < a.jobs:
            r = queue.pop(0)
            out = os.path.join(a.out, names[r])
            os.makedirs(out, exist_ok=True)
            for stale in ("done.json", "frames.jsonl"):
                if os.path.exists(os.path.join(out, stale)):
                    os.remove(os.path.join(out, stale))
            cmd = [offline, "--radius", str(a.radius), "--quiet", "--image-topic", a.image_topic]
            cam = camera_for(r, a.camera)
            if cam:
                cmd += ["--camera", cam]
            if a.params:
                cmd += ["--params", a.params]
            if a.detector:
                cmd += ["--detector", a.detector]
            cmd += ["--report", out] if a.report else ["--output", os.path.join(out, "frames.jsonl")]
            cmd.append(r)
            log = open(os.path.join(out, "offline.log"), "w")
            running[r] = (subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT), time.time())
        time.sleep(0.3)
        for r, (p, t0) in list(running.items()):
            if p.poll() is None:
                continue
            del running[r]
            finished += 1
            out = os.path.join(a.out, names[r])
            rows = run_report.load_frames(os.path.join(out, "frames.jsonl")) if os.path.exists(os.path.join(out, "frames.jsonl")) else []
            frames_done += expected[r]
            if p.returncode != 0:
                with open(os.path.join(out, "offline.log")) as f:
                    msg = [l.strip() for l in f if l.strip()]
                failed[r] = (msg[-1] if msg else "exit %d" % p.returncode)
                status = "FAILED: " + failed[r]
            else:
                s = run_report.summarize(rows)
                with open(os.path.join(out, "done.json.tmp"), "w") as f:
                    json.dump({"input": fingerprint(r), "recording": r, "seconds": time.time() - t0, "summary": s}, f)
                os.replace(os.path.join(out, "done.json.tmp"), os.path.join(out, "done.json"))
                status = "%d frames, %d trocars" % (s["frames"], len(s["trocars"]))
            print(("\r" if tty else "") + "%-60s %s" % (names[r][:60], status) + (" " * 10 if tty else ""), file=sys.stderr)
        if tty:
            live = frames_done + sum(count_lines(os.path.join(a.out, names[r], "frames.jsonl")) for r in running)
            el = time.time() - start
            sys.stderr.write("\r%s %d/%d recordings, %d/%d frames, %.0f fps, %.0f s" %
                             (bar(live, total), finished, len(todo), live, total, live / max(el, 1e-9), el))
            sys.stderr.flush()
    if tty:
        sys.stderr.write("\n")
    write_summary(a.out, recs, names, failed, a.report)
    print("summary: %s" % os.path.join(a.out, "summary.md"), file=sys.stderr)
    if a.report:
        print("report: %s" % os.path.join(a.out, "index.html"), file=sys.stderr)
    return 1 if failed else 0


def write_summary(out_dir, recs, names, failed, report):
    header = ["recording", "status", "frames", "rejected", "shafts/frame", "trocars located", "located at (s)",
              "spread (deg)", "1-sigma (mm)", "errors", "seconds"]
    table = []
    for r in recs:
        out = os.path.join(out_dir, names[r])
        try:
            with open(os.path.join(out, "done.json")) as f:
                d = json.load(f)
        except (OSError, ValueError):
            table.append([names[r], "failed: " + failed.get(r, "not finished"), "", "", "", "", "", "", "", "", ""])
            continue
        s = d["summary"]
        loc = [t for t in s["trocars"] if t["located_s"] is not None]
        table.append([names[r], "ok", s["frames"], s["rejected"], "%.2f" % s["shafts_per_frame"],
                      "%d of %d" % (len(loc), len(s["trocars"])),
                      " ".join("%.1f" % t["located_s"] for t in loc) or "-",
                      " ".join(run_report.fmt(t["spread_deg"], ".1f") for t in s["trocars"]) or "-",
                      " ".join(run_report.fmt(t["sigma_mm"], ".1f") for t in s["trocars"]) or "-",
                      "; ".join("%s (%d)" % kv for kv in s["errors"].items()) or "-", "%.1f" % d["seconds"]])
    with open(os.path.join(out_dir, "summary.csv"), "w", newline="") as f:
        csv.writer(f).writerows([header] + table)
    with open(os.path.join(out_dir, "summary.md"), "w") as f:
        f.write("| " + " | ".join(header) + " |\n|" + " --- |" * len(header) + "\n")
        for row in table:
            f.write("| " + " | ".join(str(c).replace("|", "/") for c in row) + " |\n")
    print(open(os.path.join(out_dir, "summary.md")).read(), end="")
    if report:
        rows = "".join("<tr>%s</tr>" % "".join(
            ("<td><a href=\"%s/index.html\">%s</a></td>" % (html.escape(names[r]), html.escape(c)) if i == 0 and row[1] == "ok"
             else "<td>%s</td>" % html.escape(str(c))) for i, c in enumerate(row)) for r, row in zip(recs, table))
        page = ("<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>endo_guidance batch</title>"
                "<style>body{font-family:sans-serif;margin:24px}table{border-collapse:collapse;font-size:13px}"
                "td,th{border:1px solid #ccc;padding:3px 8px}</style></head><body><h1>endo_guidance batch replay</h1>"
                "<table><tr>%s</tr>%s</table></body></html>\n" % ("".join("<th>%s</th>" % h for h in header), rows))
        with open(os.path.join(out_dir, "index.html"), "w") as f:
            f.write(page)


if __name__ == "__main__":
    sys.exit(main(sys.argv))
