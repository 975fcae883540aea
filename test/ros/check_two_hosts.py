#!/usr/bin/python3
# Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
"""What crosses between the two hosts of test/ros/check_two_hosts.sh, checked from a third
process: the camera host's trocar tf and instruments reach the robot side, the robot host's servo
commands flow once a target is set, the camera's JPEG stream is decoded on the robot host; and the
latency each hop adds. Prints one JSON line of figures; exits 1 with the reason on a failure."""
import json
import sys
import threading
import time

import numpy as np
import rospy
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import CompressedImage, Image
from tf2_msgs.msg import TFMessage
from endo_guidance.msg import InsertionPointArray, InstrumentAxisArray, InstrumentVelocity, ServoState, ServoTarget

lock = threading.Lock()
trocars, inst_lat, cmd, state, jpeg_bytes, robot_images, manager_lat = set(), [], [], [], [], [], []


def fail(msg):
    print("two hosts: FAILED: " + msg)
    sys.exit(1)


def on_tf(m):
    with lock:
        for t in m.transforms:
            if t.header.frame_id == "endoscope_optical_frame" and t.child_frame_id.startswith("trocar_"):
                trocars.add(t.child_frame_id)


def on_inst(m):
    with lock:
        inst_lat.append((rospy.Time.now() - m.header.stamp).to_sec())


def on_cmd(m):
    with lock:
        cmd.append(abs(m.pan_rate) + abs(m.tilt_rate) + abs(m.insertion_rate))


def on_state(m):
    with lock:
        if m.active:
            state.append(m.latency)


def on_jpeg(m):
    with lock:
        jpeg_bytes.append(len(m.data))


def on_robot_image(m):
    with lock:
        robot_images.append((rospy.Time.now() - m.header.stamp).to_sec())


def on_diag(m):
    # the camera host's own image -> insertion points latency (inside one manager)
    for s in m.status:
        if s.name.endswith("insertion_points: insertion points") or "insertion_points" in s.name:
            for kv in s.values:
                if kv.key == "latency (ms)":
                    try:
                        with lock:
                            manager_lat.append(float(kv.value) / 1e3)
                    except ValueError:
                        pass


def wait(pred, timeout, what):
    end = time.time() + timeout
    while time.time() < end and not rospy.is_shutdown():
        with lock:
            if pred():
                return
        time.sleep(0.1)
    fail(what)


def main():
    rospy.init_node("two_hosts_check")
    subs = [rospy.Subscriber("/tf", TFMessage, on_tf, queue_size=100),
            rospy.Subscriber("/endoscope/instruments", InstrumentAxisArray, on_inst, queue_size=50),
            rospy.Subscriber("/arm_0/command", InstrumentVelocity, on_cmd, queue_size=100),
            rospy.Subscriber("/visual_servo/state", ServoState, on_state, queue_size=100),
            rospy.Subscriber("/endoscope/image_raw/compressed", CompressedImage, on_jpeg, queue_size=10),
            rospy.Subscriber("/endoscope/image_robot", Image, on_robot_image, queue_size=10),
            rospy.Subscriber("/diagnostics", DiagnosticArray, on_diag, queue_size=50)]
    wait(lambda: len(inst_lat) > 20, 60, "no instruments from the camera host")
    wait(lambda: len(trocars) >= 3, 90, "the camera host's trocar tf did not reach the robot side (%s)" % sorted(trocars))
    wait(lambda: len(robot_images) > 10, 30, "the robot host decoded no compressed image")
    explore = rospy.get_param("/motion_script/duration", 12.0)
    time.sleep(max(0.0, explore + 1.0 - (time.time() - start)))
    pub = rospy.Publisher("/visual_servo/target", ServoTarget, queue_size=1, latch=True)
    t = ServoTarget()
    # arm_0's trocar among the estimates: the nearest to the simulator's true one
    truth = rospy.wait_for_message("/endoscope/truth/insertion_points", InsertionPointArray, 10).points[0].position
    est = rospy.wait_for_message("/endoscope/insertion_points", InsertionPointArray, 10).points
    d = [np.linalg.norm([p.position.x - truth.x, p.position.y - truth.y, p.position.z - truth.z]) for p in est]
    if not d or min(d) > 0.01:
        fail("arm_0's trocar not estimated within 10 mm (%s)" % d)
    t.mode, t.insertion_point_id = ServoTarget.TIP_3D, est[int(np.argmin(d))].id
    t.header.frame_id = "endoscope_optical_frame"
    t.tip.x, t.tip.y, t.tip.z = 0.0, 0.01, 0.12
    with lock:
        n0 = len(cmd)
    pub.publish(t)
    wait(lambda: len(cmd) > n0 + 20 and max(cmd[n0:]) > 1e-4, 30, "the robot host's servo sent no motion command")
    wait(lambda: len(state) > 10, 10, "no active servo state")
    with lock:
        figures = {
            "trocars_on_tf": sorted(trocars),
            "instruments_latency_ms_p50": 1e3 * float(np.percentile(inst_lat, 50)),
            "instruments_latency_ms_p99": 1e3 * float(np.percentile(inst_lat, 99)),
            "in_manager_latency_ms_p50": 1e3 * float(np.percentile(manager_lat, 50)) if manager_lat else None,
            "servo_data_age_ms_p50": 1e3 * float(np.percentile(state, 50)),
            "robot_side_image_latency_ms_p50": 1e3 * float(np.percentile(robot_images, 50)),
            "jpeg_kB_per_frame": float(np.mean(jpeg_bytes)) / 1e3 if jpeg_bytes else None,
            "raw_kB_per_frame": 640 * 480 * 3 / 1e3,
            "commands": len(cmd) - n0,
        }
    print(json.dumps(figures))


start = time.time()
if __name__ == "__main__":
    main()
