#!/usr/bin/python3
# Copyright (C) endo_guidance developers. SPDX-License-Identifier: GPL-2.0-or-later
"""Turns a rendered surgery bag (endo_guidance_synthetic --write-bag) into what a recorder of a
compressed endoscope stream leaves: <camera>/image_raw/compressed (JPEG) + camera_info, with one
frame truncated mid-file (a corrupted write). Used by test/ros/bag_faults.test.
Usage: make_fault_bag.py IN.bag OUT.bag [--truncate K]"""
import argparse
import sys

import cv2
import numpy as np
import rosbag
from sensor_msgs.msg import CompressedImage


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("inp")
    ap.add_argument("out")
    ap.add_argument("--truncate", type=int, default=100, help="index of the frame to truncate (default 100)")
    a = ap.parse_args()
    images = 0
    try:
        with rosbag.Bag(a.inp) as src, rosbag.Bag(a.out, "w", compression="lz4") as dst:
            for topic, msg, t in src.read_messages():
                if not topic.endswith("/image_raw"):
                    dst.write(topic, msg, t)
                    continue
                img = np.frombuffer(msg.data, np.uint8).reshape(msg.height, msg.width, -1)
                if msg.encoding == "rgb8":
                    img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
                ok, data = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
                if not ok:
                    sys.exit("make_fault_bag: JPEG encoding failed")
                data = data.tobytes()
                if images == a.truncate:
                    data = data[: len(data) // 2]
                c = CompressedImage(header=msg.header, format="bgr8; jpeg compressed bgr8", data=data)
                dst.write(topic + "/compressed", c, t)
                images += 1
    except (OSError, rosbag.ROSBagException) as e:
        sys.exit(f"make_fault_bag: {e}")
    if images <= a.truncate:
        sys.exit(f"make_fault_bag: only {images} images in {a.inp}, none truncated")
    print(f"make_fault_bag: {images} JPEG frames, frame {a.truncate} truncated -> {a.out}")


if __name__ == "__main__":
    main()
