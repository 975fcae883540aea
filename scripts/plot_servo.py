#!/usr/bin/python3
"""Plot of a visual-servo run: tip and axis errors (as measured by the camera, from
/visual_servo/state) and the commanded rates against time.

  scripts/plot_servo.py OUT.png --bag RUN.bag          (a bag holding /visual_servo/state)
  scripts/plot_servo.py OUT.png --live SECONDS          (records the running servo)
  scripts/plot_servo.py OUT.png --demo                  (starts servo_sim.launch on a private
                                                         master, sends two targets, records)
"""
import argparse
import os
import random
import subprocess
import sys
import time

import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def from_bag(path, topic):
    import rosbag
    with rosbag.Bag(path) as bag:
        return [m for _, m, _ in bag.read_messages(topics=[topic])]


def live(seconds, topic, on_start=None):
    import rospy
    from endo_guidance.msg import ServoState
    rospy.init_node("plot_servo", anonymous=True)
    states = []
    rospy.Subscriber(topic, ServoState, states.append, queue_size=100)
    if on_start:
        on_start()
    t0 = time.time()
    while time.time() - t0 < seconds and not rospy.is_shutdown():
        time.sleep(0.05)
    return list(states)


def demo():
    """servo_sim.launch with breathing; two targets for arm_0 once the trocars are known."""
    here = os.path.dirname(os.path.abspath(__file__))
    port = 12500 + random.randint(0, 400)
    os.environ["ROS_MASTER_URI"] = f"http://localhost:{port}"
    log = open(os.path.join(here, "..", "build", "plot_servo_launch.log"), "w")
    launch = subprocess.Popen(["roslaunch", "-p", str(port), "endo_guidance", "servo_sim.launch", "breathing:=0.002",
                               "camera_base_rpy_prior:=[-2.2648, -0.1153, 1.4979]"], stdout=log, stderr=subprocess.STDOUT)
    try:
        time.sleep(3)
        import numpy as np
        import rospy
        import tf2_ros
        from endo_guidance.msg import InsertionPointArray, ServoTarget
        rospy.init_node("plot_servo", anonymous=True)
        buf = tf2_ros.Buffer()
        tf2_ros.TransformListener(buf)
        # The pipeline finds the trocars during the scripted motion (12 s), then the servo takes arm_0.
        time.sleep(13)
        t = buf.lookup_transform("endoscope_optical_frame", "sim/trocar_0", rospy.Time(0), rospy.Duration(3))
        q, p = t.transform.rotation, t.transform.translation
        x, y, z, w = q.x, q.y, q.z, q.w
        R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                      [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                      [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
        T = np.array([p.x, p.y, p.z])
        est = rospy.wait_for_message("/endoscope/insertion_points", InsertionPointArray, timeout=5)
        iid = min((np.linalg.norm(np.array([e.position.x, e.position.y, e.position.z]) - T), e.id) for e in est.points)[1]
        jaw = rospy.get_param("/endoscope_simulator/jaw_length", 0.012)
        pub = rospy.Publisher("/visual_servo/target", ServoTarget, queue_size=1, latch=True)

        def target(pan, tilt, depth):
            d = np.array([np.cos(tilt) * np.sin(pan), -np.sin(tilt), np.cos(tilt) * np.cos(pan)])
            P = R @ ((depth + jaw) * d) + T
            m = ServoTarget(mode=ServoTarget.TIP_3D, insertion_point_id=iid)
            m.header.frame_id = "endoscope_optical_frame"
            m.tip.x, m.tip.y, m.tip.z = P
            pub.publish(m)

        from endo_guidance.msg import ServoState
        states = []
        rospy.Subscriber("/visual_servo/state", ServoState, states.append, queue_size=100)
        target(0.12, -0.10, 0.13)
        time.sleep(6)
        target(-0.15, 0.08, 0.16)
        time.sleep(6)
        return list(states)
    finally:
        launch.terminate()
        launch.wait()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out")
    ap.add_argument("--bag")
    ap.add_argument("--live", type=float)
    ap.add_argument("--demo", action="store_true")
    ap.add_argument("--topic", default="/visual_servo/state")
    a = ap.parse_args()
    if a.bag:
        states = from_bag(a.bag, a.topic)
    elif a.live:
        states = live(a.live, a.topic)
    elif a.demo:
        states = demo()
    else:
        sys.exit("give --bag, --live or --demo")
    states = [s for s in states if s.enabled]
    if not states:
        sys.exit("no servo state recorded")
    reasons = {}
    for s in states:
        if s.reason:
            key = s.reason.split(":")[0][:60]
            reasons[key] = reasons.get(key, 0) + 1
    for r, n in sorted(reasons.items(), key=lambda x: -x[1]):
        print(f"  stopped {n} x: {r}")
    nan = float("nan")
    t0 = states[0].header.stamp.to_sec()
    t = [s.header.stamp.to_sec() - t0 for s in states]
    fig, ax = plt.subplots(3, 1, figsize=(8, 8), sharex=True)
    # A stopped step carries no error (gap in the curves; grey lines in the command plot).
    ax[0].plot(t, [nan if s.reason else s.tip_error * 1e3 for s in states])
    ax[0].axhline(1.0, color="r", ls="--", lw=0.8)
    ax[0].set_ylabel("tip error (mm)")
    ax[0].set_yscale("log")
    ax[1].plot(t, [nan if s.reason else s.axis_error * 180 / 3.141592653589793 for s in states])
    ax[1].axhline(0.5, color="r", ls="--", lw=0.8)
    ax[1].set_ylabel("axis error (deg)")
    ax[1].set_yscale("log")
    ax[2].plot(t, [s.command[0] for s in states], label="pan (rad/s)")
    ax[2].plot(t, [s.command[1] for s in states], label="tilt (rad/s)")
    ax[2].plot(t, [s.command[2] * 10 for s in states], label="insertion (10 x m/s)")
    ax[2].legend(loc="upper right")
    ax[2].set_xlabel("time (s)")
    ax[2].set_ylabel("command")
    stopped = [ti for ti, s in zip(t, states) if s.reason]
    for ti in stopped:
        ax[2].axvline(ti, color="0.8", lw=0.5)
    fig.suptitle("endo_guidance visual servo (errors as measured by the camera)")
    fig.tight_layout()
    fig.savefig(a.out, dpi=100)
    print(f"{len(states)} servo steps; final tip error {states[-1].tip_error * 1e3:.2f} mm, axis "
          f"{states[-1].axis_error * 180 / 3.141592653589793:.2f} deg; plot: {a.out}")


if __name__ == "__main__":
    main()
