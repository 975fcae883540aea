#!/usr/bin/python3
# Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
"""rostest of the EndoscopeCamera (endoscope_camera.test).

The videos appear only after the cameras have started (the nodes report the missing source, then
reconnect). numbered.avi: frame k shows k in binary as wide bars (robust to MJPG), so that a frame
published twice, lost or out of order is seen. chessboard.avi: views of a chessboard rendered with
known intrinsics, calibrated with Debian's camera_calibration (the library behind
cameracalibrator.py), committed with set_camera_info, and its YAML loaded by a new camera node.
"""
import os
import shutil
import subprocess
import threading
import time
import unittest

import cv2
import numpy as np
import roslib.packages
import rospy
import rostest
import yaml
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from sensor_msgs.msg import CameraInfo, Image
from sensor_msgs.srv import SetCameraInfo

W, H, N = 320, 240, 40
BITS = 8
K_TRUE = np.array([[600.0, 0, 322.0], [0, 604.0, 238.0], [0, 0, 1]])
BOARD = (8, 6)  # inner corners
SQUARE = 0.03


def numbered(k):
    img = np.zeros((H, W, 3), np.uint8)
    for b in range(BITS):
        if (k >> b) & 1:
            img[:, b * (W // BITS):(b + 1) * (W // BITS)] = 255
    return img


def index_of(img):
    row = img[H // 2].mean(axis=1)
    return sum(1 << b for b in range(BITS) if row[b * (W // BITS) + W // (2 * BITS)] > 127)


def chessboard_views():
    """Chessboard views through K_TRUE (640x480), the board tilted and moved about."""
    px = 40  # board texture: px per square
    cols, rows = BOARD[0] + 1, BOARD[1] + 1
    tex = np.full(((rows + 2) * px, (cols + 2) * px), 255, np.uint8)
    for r in range(rows):
        for c in range(cols):
            if (r + c) % 2 == 0:
                tex[(r + 1) * px:(r + 2) * px, (c + 1) * px:(c + 2) * px] = 0
    # texture px -> board metres (origin at the first inner corner)
    S = np.array([[SQUARE / px, 0, -2 * SQUARE], [0, SQUARE / px, -2 * SQUARE], [0, 0, 1]])
    views = []
    rng = np.random.default_rng(3)
    for i in range(16):
        rvec = np.array([rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.3)])
        R, _ = cv2.Rodrigues(rvec)
        t = np.array([rng.uniform(-0.12, 0.0), rng.uniform(-0.09, 0.0), rng.uniform(0.45, 0.7)])
        Hm = K_TRUE @ np.column_stack([R[:, 0], R[:, 1], t]) @ S
        img = cv2.warpPerspective(tex, Hm, (640, 480), flags=cv2.INTER_AREA, borderValue=128)
        views.append(cv2.cvtColor(img, cv2.COLOR_GRAY2BGR))
    return views


def write_video(path, frames, fps):
    tmp = path + ".tmp.avi"
    w = cv2.VideoWriter(tmp, cv2.VideoWriter_fourcc(*"MJPG"), fps, (frames[0].shape[1], frames[0].shape[0]))
    assert w.isOpened(), "cannot write " + tmp
    for f in frames:
        w.write(f)
    w.release()
    os.rename(tmp, path)  # the camera sees the whole file or none


class Recorder:
    def __init__(self, ns):
        self.images, self.infos, self.lock = [], [], threading.Lock()
        self.subs = [rospy.Subscriber(ns + "/image_raw", Image, self.on_image, queue_size=100),
                     rospy.Subscriber(ns + "/camera_info", CameraInfo, self.on_info, queue_size=100)]

    def on_image(self, m):
        img = np.frombuffer(m.data, np.uint8).reshape(m.height, m.width, -1)
        with self.lock:
            self.images.append((m.header.stamp.to_sec(), m.header.frame_id, img.copy()))

    def on_info(self, m):
        with self.lock:
            self.infos.append(m)


class Diagnostics:
    def __init__(self):
        self.last, self.lock = {}, threading.Lock()
        self.sub = rospy.Subscriber("/diagnostics", DiagnosticArray, self.on_diag, queue_size=50)

    def on_diag(self, m):
        with self.lock:
            for s in m.status:
                self.last[s.name] = s

    def wait_for(self, node, pred, timeout):
        end = time.time() + timeout
        while time.time() < end and not rospy.is_shutdown():
            with self.lock:
                for name, s in self.last.items():
                    if name.startswith(node + ":") and pred(s):
                        return s
            time.sleep(0.05)
        return None


class EndoscopeCameraTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        rospy.init_node("test_endoscope_camera")
        cls.dir = rospy.get_param("~dir")
        os.makedirs(cls.dir, exist_ok=True)
        cls.diag = Diagnostics()
        cls.stop, cls.loop, cls.cal = Recorder("/cam_stop"), Recorder("/cam_loop"), Recorder("/cam_cal")

    @classmethod
    def tearDownClass(cls):
        shutil.rmtree(cls.dir, ignore_errors=True)

    def test_1_missing_source_then_every_frame_once_then_stop_or_loop(self):
        s = self.diag.wait_for("cam_stop/endoscope_camera", lambda s: s.level == DiagnosticStatus.ERROR, 15)
        self.assertIsNotNone(s, "no diagnostics saying the source is missing")
        self.assertIn("no such file", s.message)
        time.sleep(1.0)  # subscriptions connected
        self.assertEqual(len(self.stop.images), 0)
        write_video(os.path.join(self.dir, "numbered.avi"), [numbered(k) for k in range(N)], 25)
        ended = self.diag.wait_for("cam_stop/endoscope_camera", lambda s: "end of file" in s.message, 20)
        self.assertIsNotNone(ended, "cam_stop never reported the end of the file")
        time.sleep(1.0)
        with self.stop.lock:
            images = list(self.stop.images)
        idx = [index_of(i) for _, _, i in images]
        self.assertEqual(idx, list(range(N)), "cam_stop: frames lost, repeated or out of order")
        stamps = [t for t, _, _ in images]
        self.assertTrue(all(b > a for a, b in zip(stamps, stamps[1:])), "stamps must strictly increase")
        self.assertTrue(all(f == "endoscope_optical_frame" for _, f, _ in images))
        rate = (N - 1) / (stamps[-1] - stamps[0])
        self.assertAlmostEqual(rate, 50.0, delta=10.0, msg="playback at fps:=50 (the file says 25)")
        with self.stop.lock:
            info_stamps = {m.header.stamp.to_sec() for m in self.stop.infos}
        self.assertTrue(set(stamps) <= info_stamps, "each image has its camera_info with the same stamp")
        n = len(self.stop.images)
        time.sleep(0.5)
        self.assertEqual(len(self.stop.images), n, "frames after the end of the file (loop:=false)")

        with self.loop.lock:
            lidx = [index_of(i) for _, _, i in self.loop.images]
        self.assertGreater(len(lidx), N + 10, "cam_loop did not loop")
        steps_ok = all(b == a + 1 or (a == N - 1 and b == 0) for a, b in zip(lidx, lidx[1:]))
        self.assertTrue(steps_ok, "cam_loop: a frame lost or repeated: %s" % lidx[:3 * N])
        s = self.diag.wait_for("cam_loop/endoscope_camera", lambda s: s.level == DiagnosticStatus.WARN
                               and "not calibrated" in s.message, 5)
        self.assertIsNotNone(s, "an uncalibrated camera must say so")

    def test_2_calibration_workflow(self):
        from camera_calibration.calibrator import ChessboardInfo, MonoCalibrator
        views = chessboard_views()
        write_video(os.path.join(self.dir, "chessboard.avi"), views, 10)
        end = time.time() + 30
        while time.time() < end and len(self.cal.images) < len(views):
            time.sleep(0.1)
        with self.cal.lock:
            frames = [i for _, _, i in self.cal.images[:len(views)]]
            info0 = self.cal.infos[0]
        self.assertEqual(len(frames), len(views), "the chessboard frames did not arrive")
        self.assertEqual(list(info0.K), [0.0] * 9, "no calibration file yet: K is zero")
        self.assertEqual((info0.width, info0.height), (640, 480))

        cal = MonoCalibrator([ChessboardInfo("chessboard", BOARD[0], BOARD[1], SQUARE)], name="endoscope")
        cal.cal(frames)
        K = np.array(cal.intrinsics).reshape(3, 3)
        np.testing.assert_allclose(K[[0, 1, 0, 1], [0, 1, 2, 2]], K_TRUE[[0, 1, 0, 1], [0, 1, 2, 2]], rtol=0.01)
        ost = os.path.join(self.dir, "ost.yaml")
        with open(ost, "w") as f:
            f.write(cal.yaml())  # what cameracalibrator.py saves (calibrationdata.tar.gz: ost.yaml)

        # "commit": the calibrator's set_camera_info call; camera_info_manager writes the URL's file.
        rospy.wait_for_service("/cam_cal/set_camera_info", 10)
        r = rospy.ServiceProxy("/cam_cal/set_camera_info", SetCameraInfo)(cal.as_message())
        self.assertTrue(r.success, r.status_message)
        n = len(self.cal.infos)
        end = time.time() + 10
        while time.time() < end and len(self.cal.infos) <= n + 1:
            time.sleep(0.05)
        np.testing.assert_allclose(np.array(self.cal.infos[-1].K).reshape(3, 3), K, rtol=1e-9)
        saved = yaml.safe_load(open(os.path.join(self.dir, "cam_cal.yaml")))
        np.testing.assert_allclose(np.array(saved["camera_matrix"]["data"]).reshape(3, 3), K, rtol=1e-6)

        # A new camera node loads the calibrator's own YAML from camera_info_url.
        y = yaml.safe_load(open(ost))
        exe = roslib.packages.find_node("endo_guidance", "endoscope_camera_node")  # as roslaunch finds it
        self.assertTrue(exe, "endoscope_camera_node not built")
        node = subprocess.Popen([exe[0], "__ns:=/cal_check",
                                 "_source:=" + os.path.join(self.dir, "chessboard.avi"), "_loop:=true",
                                 "_camera_info_url:=file://" + ost])
        try:
            check = Recorder("/cal_check")
            end = time.time() + 20
            while time.time() < end and not check.infos:
                time.sleep(0.1)
            self.assertTrue(check.infos, "the node started with the calibrator's YAML published nothing")
            m = check.infos[-1]
            self.assertEqual((m.width, m.height), (y["image_width"], y["image_height"]))
            np.testing.assert_allclose(m.K, y["camera_matrix"]["data"], rtol=1e-9)
            np.testing.assert_allclose(m.D, y["distortion_coefficients"]["data"], rtol=1e-9)
            np.testing.assert_allclose(m.P, y["projection_matrix"]["data"], rtol=1e-9)
            self.assertEqual(m.distortion_model, y["distortion_model"])
            s = self.diag.wait_for("cal_check/endoscope_camera", lambda s: s.level == DiagnosticStatus.OK, 5)
            self.assertIsNotNone(s, "a calibrated camera streaming: diagnostics OK")
        finally:
            node.terminate()
            node.wait(10)


if __name__ == "__main__":
    rostest.rosrun("endo_guidance", "endoscope_camera", EndoscopeCameraTest)
