#!/usr/bin/python3
# Writes the fuzzers' seed corpus (test/fuzz/corpus/<harness>/), deterministically: inputs laid
# out as the harnesses read them (fuzz_input.h: big-endian u32, a byte before each real).
# Run once when a harness's input layout changes: /usr/bin/python3 test/fuzz/make_corpus.py
# Video seeds are not kept in the repository: `make_corpus.py --videos DIR` writes them where
# scripts/fuzz.sh asks (build/fuzz/seeds/readers).
import os
import random
import struct
import sys
import tempfile

import cv2
import numpy as np

ROOT = os.path.dirname(os.path.abspath(__file__))
OUT = os.path.join(ROOT, "corpus")


def u32(v):
    return struct.pack(">I", v & 0xFFFFFFFF)


def rng_range(lo, hi, v):  # the u32 giving v from Input::range(lo, hi)
    return u32(v - lo)


def real(lo, hi, v):  # the byte + u32 giving v from Input::real(lo, hi)
    return bytes([255]) + u32(round((v - lo) / (hi - lo) * 4294967295.0))


def write(harness, name, data):
    d = os.path.join(OUT, harness)
    os.makedirs(d, exist_ok=True)
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)


def picture(w, h, shafts, seed):
    """A small laparoscopic-looking picture: reddish tissue, dark or grey shafts from the border."""
    r = np.random.default_rng(seed)
    img = np.zeros((h, w, 3), np.uint8)
    img[:] = (60, 70, 170)
    img = np.clip(img + r.normal(0, 12, img.shape), 0, 255).astype(np.uint8)
    for (x0, y0, x1, y1, width, grey) in shafts:
        cv2.line(img, (x0, y0), (x1, y1), (grey, grey, grey), width)
    cv2.circle(img, (w // 2, h // 2), int(0.62 * w), (0, 0, 0), int(0.3 * w))  # dark rim of the view
    return img


def pipeline_seeds():
    cases = [
        (640, 480, [(0, 30, 30, 18, 6, 40)], 1, 3),
        (720, 576, [(47, 5, 20, 20, 5, 120), (0, 33, 25, 22, 4, 30)], 2, 2),
        (1920, 1080, [(10, 0, 28, 24, 5, 200)], 3, 1),
        (1, 1, [], 4, 1),
        (33, 7, [(0, 3, 30, 3, 2, 50)], 5, 2),
    ]
    for i, (w, h, shafts, seed, frames) in enumerate(cases):
        pw, ph = 48, 36
        b = rng_range(1, 1920, w) + rng_range(1, 1080, h) + rng_range(0, 5, 0) + rng_range(1, 4, 3)
        b += bytes([200]) + rng_range(1, 3, frames) + rng_range(0, 4, 0)
        b += rng_range(1, 48, pw) + rng_range(1, 36, ph)
        b += picture(pw, ph, shafts, seed).tobytes() + bytes([i & 1]) + real(0.3, 3.0, 0.9)
        write("pipeline", "frame_%d" % i, b)
        if i < 2:  # the same with the learned detector (its byte comes last)
            write("pipeline", "frame_%d_learned" % i, b + bytes([255]))
    # a refused type (16-bit, one channel)
    write("pipeline", "mono16", rng_range(1, 1920, 64) + rng_range(1, 1080, 48) + rng_range(0, 5, 2) + rng_range(1, 4, 1) + bytes([3]))


def geometry_seeds():
    r = random.Random(7)
    for i in range(6):
        write("geometry", "random_%d" % i, bytes(r.randrange(24, 256) if k % 5 == 0 else r.randrange(256) for k in range(1200)))
    # a shaft 12 px wide seen at 640x480, then 20 axes through one trocar
    b = real(50, 3000, 600) + real(-1, 1, 0) + real(0, 2000, 320) + real(50, 3000, 600) + real(0, 2000, 240) + real(0, 0.02, 0.004)
    for (a, bb, c) in [(0.99, -0.14, -280.0), (-0.99, 0.14, 300.0)]:
        b += real(-1, 1, a) + real(-1, 1, bb) + real(-2000, 2000, c) + bytes([1]) + real(0, 1e-4, 1e-6) + real(0, 1e-4, 1e-6) + real(0, 10, 1)
    b += real(-100, 2000, 330) + real(-100, 2000, 240)
    b += real(-0.3, 0.3, 0.01) * 3 + real(0, 1e-4, 1e-6) * 3 + real(0, 0.01, 0.001)
    b += rng_range(0, 40, 20)
    for k in range(20):
        b += bytes([200]) + real(-0.2, 0.2, 0.1) + real(-0.2, 0.2, 0.02) + real(-0.1, 0.1, 0.0)
        b += real(-0.2, 0.2, -0.1 + 0.01 * k) + real(-0.2, 0.2, -0.02) + real(-0.2, 0.2, 0.15) + bytes([k & 1])
    write("geometry", "trocar", b)


def config_seeds():
    repo = os.path.dirname(os.path.dirname(ROOT))
    with open(os.path.join(repo, "config", "pipeline.yaml"), "rb") as f:
        write("config", "pipeline.yaml", f.read())
    cams = os.path.join(repo, "config", "cameras")
    for name in sorted(os.listdir(cams))[:3]:
        with open(os.path.join(cams, name), "rb") as f:
            write("config", name, f.read())
    write("config", "nested", b"segmentation: {sigma_radius: 2, grow_thresholds: [10, 20, 30]}\ninsertion_points:\n  max_points: 3\n")


def video_seeds(out):
    """Three frames of the seed picture as AVI (MJPG), MP4 (mp4v) and MKV, each after its kind byte."""
    img = picture(32, 24, [(0, 5, 30, 15, 3, 40)], 9)
    os.makedirs(out, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for kind, ext, fourcc in [(2, ".avi", "MJPG"), (3, ".mp4", "mp4v"), (4, ".mkv", "MJPG")]:
            p = os.path.join(tmp, "v" + ext)
            vw = cv2.VideoWriter(p, cv2.VideoWriter_fourcc(*fourcc), 25, (32, 24))
            for k in range(3):
                vw.write(np.roll(img, k, axis=1))
            vw.release()
            with open(p, "rb") as f, open(os.path.join(out, "video" + ext), "wb") as g:
                g.write(bytes([kind]) + f.read())


def readers_seeds():
    img = picture(32, 24, [(0, 5, 30, 15, 3, 40)], 9)
    write("readers", "image.png", bytes([0]) + cv2.imencode(".png", img)[1].tobytes())
    write("readers", "image.jpg", bytes([1]) + cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 70])[1].tobytes())
    with tempfile.TemporaryDirectory() as tmp:
        import rosbag
        import rospy
        from sensor_msgs.msg import CameraInfo, CompressedImage, Image
        for name, compression in [("recording.bag", "none"), ("recording_lz4.bag", "lz4")]:
            p = os.path.join(tmp, name)
            with rosbag.Bag(p, "w", compression=compression, chunk_threshold=1) as bag:
                ci = CameraInfo(width=32, height=24, K=[30, 0, 16, 0, 30, 12, 0, 0, 1], P=[30, 0, 16, 0, 0, 30, 12, 0, 0, 0, 1, 0])
                bag.write("/endoscope/camera_info", ci, rospy.Time(1))
                for k in range(2):
                    m = Image(height=24, width=32, encoding="bgr8", step=96, data=img.tobytes())
                    m.header.stamp = rospy.Time(1 + k)
                    bag.write("/endoscope/image_raw", m, rospy.Time(1 + k))
                c = CompressedImage(format="jpeg", data=cv2.imencode(".jpg", img)[1].tobytes())
                c.header.stamp = rospy.Time(3)
                bag.write("/endoscope/image_raw", c, rospy.Time(3))
                bad = Image(height=24, width=32, encoding="16UC3", step=5, data=b"\x01\x02")
                bag.write("/endoscope/image_raw", bad, rospy.Time(4))
            with open(p, "rb") as f:
                write("readers", name, bytes([5]) + f.read())


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--videos":
        video_seeds(sys.argv[2])
        sys.exit(0)
    pipeline_seeds()
    geometry_seeds()
    config_seeds()
    readers_seeds()
    for h in sorted(os.listdir(OUT)):
        files = os.listdir(os.path.join(OUT, h))
        print("%s: %d seeds, %d bytes" % (h, len(files), sum(os.path.getsize(os.path.join(OUT, h, f)) for f in files)))
    sys.exit(0)
