#!/usr/bin/python3
"""The soak's verdict (scripts/soak_monitor.py --judge) on recorded runs made up here: a steady run
passes; a leak, a latency drift of the graph and dropped frames each fail it; a machine that slows
down (the simulator's CPU per frame and the latency together) does not."""
import json
import os
import subprocess
import sys
import tempfile

MONITOR = os.path.join(os.path.dirname(__file__), "..", "..", "scripts", "soak_monitor.py")


def run(name, leak_mb=0.0, drift=0.0, slowdown=0.0, dropped=0):
    """A 30-minute soak.jsonl: vision manager memory growing by leak_mb over the run, its p99
    growing by `drift`, the whole machine slowing by `slowdown`; returns the judge's exit code."""
    d = tempfile.mkdtemp(prefix="soak_judge_")
    with open(os.path.join(d, "soak.jsonl"), "w") as f:
        for m in range(1, 31):
            x = (m - 1) / 29.0
            speed = 1.0 + slowdown * x
            wobble = 1.0 + 0.03 * ((m * 7) % 5 - 2) / 2.0  # +-3 %, as a real run's minute to minute
            s = {"minute": m, "frames": 3600, "dropped": dropped,
                 "graph_p99_ms": 3.3 * speed * (1.0 + drift * x) * wobble, "p99_ms": 9.0 * speed,
                 "graph_p50_ms": 1.7 * speed, "p50_ms": 6.0 * speed,
                 "rss_kb": {"/endoscope/endo_guidance_manager": 105252 + leak_mb * 1024 * x, "/sim_manager": 112500},
                 "cpu_s": {"/sim_manager": 21.0 * speed * wobble, "/endoscope/endo_guidance_manager": 7.0 * speed}}
            f.write(json.dumps(s) + "\n")
    rc = subprocess.run([sys.executable, MONITOR, "--judge", os.path.join(d, "soak.jsonl"), "--out", d],
                        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    print("%-28s exit %d: %s" % (name, rc.returncode, rc.stdout.strip().splitlines()[-1][:160]))
    return rc.returncode


cases = [("steady", {}, 0), ("machine 25 % slower", {"slowdown": 0.25}, 0), ("leak of 2 MB", {"leak_mb": 2.0}, 1),
         ("p99 drifting +20 %", {"drift": 0.2}, 1), ("1 % dropped", {"dropped": 36}, 1)]
failed = [n for n, kw, want in cases if run(n, **kw) != want]
if failed:
    sys.exit("FAILED: the soak's verdict was wrong for: %s" % ", ".join(failed))
