#!/usr/bin/python3
"""Listens to the running pipeline (<camera>/insertion_points, <camera>/overlay) until the input
stops, then prints every trocar estimate with its error against a truth YAML and saves the last
overlay image as PNG.  Usage: report_trocars.py TRUTH.yaml OUT.png [camera] [--check TOL_MM]
With --check, exits 1 unless every true trocar has a well-conditioned estimate within TOL_MM.
Every wait is bounded: no master within 20 s, or no insertion points within 60 s, exits 1."""
import sys
import time

import numpy as np
import rosgraph
import rospy
import yaml
from sensor_msgs.msg import Image

from endo_guidance.msg import InsertionPointArray


def main():
    args = sys.argv[1:]
    check = None
    if "--check" in args:
        i = args.index("--check")
        check = float(args[i + 1])
        del args[i:i + 2]
    truth_path, png = args[0], args[1]
    cam = args[2] if len(args) > 2 else "endoscope"
    truth = np.array(yaml.safe_load(open(truth_path))["trocars"], float)
    # rospy.init_node waits for a master for ever: wait here, bounded, and say why it failed.
    end = time.time() + 20.0
    while not rosgraph.is_master_online():
        if time.time() > end:
            sys.exit("no ROS master at %s after 20 s (did roslaunch fail to start? see its log)" % rosgraph.get_master_uri())
        time.sleep(0.2)
    rospy.init_node("report_trocars", anonymous=True)
    state = {"points": None, "overlay": None, "last": None, "frames": 0}

    def on_points(msg):
        state["points"], state["last"] = msg, time.time()
        state["frames"] += 1

    def on_overlay(msg):
        if msg.encoding == "bgr8":
            state["overlay"] = np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.step)[:, : msg.width * 3].reshape(
                msg.height, msg.width, 3)

    rospy.Subscriber(cam + "/insertion_points", InsertionPointArray, on_points, queue_size=10)
    rospy.Subscriber(cam + "/overlay", Image, on_overlay, queue_size=1)
    start = time.time()
    while not rospy.is_shutdown():
        time.sleep(0.2)
        if state["last"] is None and time.time() - start > 60:
            sys.exit("no insertion points received in 60 s")
        if state["last"] is not None and time.time() - state["last"] > 3.0:
            break
    p = state["points"]
    print(f"{state['frames']} frames processed; insertion points at the last frame (optical frame, mm):")
    worst = 0.0
    for q in p.points:
        x = np.array([q.position.x, q.position.y, q.position.z])
        err = np.linalg.norm(truth - x, axis=1)
        i = int(np.argmin(err))
        worst = max(worst, err[i]) if q.located else worst
        sigma = np.sqrt(max(np.linalg.eigvalsh(np.array(q.covariance).reshape(3, 3))[-1], 0.0))
        state_s = ("located" if q.located else "well conditioned, NOT LOCATED") if q.well_conditioned else "ILL-CONDITIONED"
        print(f"  trocar_{q.id}: ({x[0]*1e3:7.1f} {x[1]*1e3:7.1f} {x[2]*1e3:7.1f})  views {q.views:4d}  "
              f"spread {np.degrees(q.conditioning):5.1f} deg  sigma {sigma*1e3:4.1f} mm  {state_s}"
              f"  error vs true trocar {i}: {err[i]*1e3:.2f} mm")
    est = [np.array([q.position.x, q.position.y, q.position.z]) for q in p.points if q.located]
    per_truth = [min((np.linalg.norm(t - e) for e in est), default=np.inf) for t in truth]
    found = sum(1 for e in per_truth if e < 0.005)
    print(f"{found} of {len(truth)} true trocars estimated (within 5 mm); worst error {worst*1e3:.2f} mm")
    if state["overlay"] is not None:
        import cv2
        cv2.imwrite(png, state["overlay"])
        print(f"last overlay image: {png}")
    if check is not None and max(per_truth) * 1e3 > check:
        sys.exit(f"CHECK FAILED: a true trocar has no estimate within {check} mm ({max(per_truth)*1e3:.2f} mm)")


if __name__ == "__main__":
    main()
