#!/usr/bin/python3
"""scripts/tsan_reports.py on reports cut from real TSan runs of the rostests: it counts a race
between two of our accesses and a lock-order cycle through our mutex, and leaves out a message
freed by roscpp after a read of ours and a cycle inside roscpp reached from our code."""
import os
import subprocess
import sys
import tempfile

REPO = "/work/main"  # the repository root as the reports below name it
SCRIPT = os.path.join(os.path.dirname(__file__), "..", "..", "scripts", "tsan_reports.py")
SEP = "==================\n"
OURS_RACE = """WARNING: ThreadSanitizer: data race (pid=1)
  Write of size 4 at 0x7b by thread T1:
    #0 endo_guidance::SegmentationNodelet::pointsCb() /work/main/src/nodelets/segmentation_nodelet.cpp:160 (libendo_guidance_nodelets.so+0x1)
    #1 boost::function /usr/include/boost/function.hpp:2 (libendo_guidance_nodelets.so+0x2)

  Previous read of size 4 at 0x7b by thread T2:
    #0 std::vector<int>::size() const /usr/include/c++/12/bits/stl_vector.h:919 (libendo_guidance_nodelets.so+0x3)
    #1 endo_guidance::SegmentationNodelet::imageCb() /work/main/src/nodelets/segmentation_nodelet.cpp:200 (libendo_guidance_nodelets.so+0x4)

SUMMARY: ThreadSanitizer: data race /work/main/src/nodelets/segmentation_nodelet.cpp:160
"""
OURS_CYCLE = """WARNING: ThreadSanitizer: lock-order-inversion (potential deadlock) (pid=2)
  Mutex M371 acquired here while holding mutex M340 in thread T2:
    #0 pthread_mutex_lock ../../../../src/libsanitizer/sanitizer_common/sanitizer_common_interceptors.inc:4324 (libtsan.so+0x558e1)
    #1 boost::unique_lock<boost::mutex>::lock() <null> (libnodeletlib.so.1d+0x681f7)
    #2 operator() /work/main/src/nodelets/segmentation_nodelet.cpp:120 (libendo_guidance_nodelets.so+0x8be80)

  Mutex M340 previously acquired by the same thread here:
    #0 pthread_mutex_lock ../../../../src/libsanitizer/sanitizer_common/sanitizer_common_interceptors.inc:4324 (libtsan.so+0x558e1)
    #1 std::mutex::lock() /usr/include/c++/12/bits/std_mutex.h:100 (libendo_guidance_nodelets.so+0x8b866)
    #2 endo_guidance::SegmentationNodelet::connectCb() /work/main/src/nodelets/segmentation_nodelet.cpp:144 (libendo_guidance_nodelets.so+0x8b866)

  Mutex M340 acquired here while holding mutex M371 in thread T2:
    #0 pthread_mutex_lock ../../../../src/libsanitizer/sanitizer_common/sanitizer_common_interceptors.inc:4324 (libtsan.so+0x558e1)
    #1 std::mutex::lock() /usr/include/c++/12/bits/std_mutex.h:100 (libendo_guidance_nodelets.so+0x89254)
    #2 endo_guidance::SegmentationNodelet::imageCb() /work/main/src/nodelets/segmentation_nodelet.cpp:175 (libendo_guidance_nodelets.so+0x89254)

SUMMARY: ThreadSanitizer: lock-order-inversion (potential deadlock) (libnodeletlib.so.1d+0x681f7)
"""
FREED_BY_ROS = """WARNING: ThreadSanitizer: data race (pid=3)
  Write of size 8 at 0x7b5c by thread T4 (mutexes: write M335):
    #0 operator delete(void*, unsigned long) ../../../../src/libsanitizer/tsan/tsan_new_delete.cpp:150 (libtsan.so+0x86c3d)
    #1 boost::detail::sp_counted_impl_pd<endo_guidance::ApparentContourArray_<std::allocator<void> >*>::dispose() <null> (libendo_guidance_nodelets.so+0x5)
    #2 boost::detail::sp_counted_base::release() <null> (libroscpp.so.4d+0x6)

  Previous read of size 4 at 0x7b5c by thread T2 (mutexes: write M334):
    #0 endo_guidance::ros_io::fromMsg(endo_guidance::ApparentContour_<std::allocator<void> > const&) /work/main/src/ros/conversions.cpp:123 (libendo_guidance_ros.so+0x7)
    #1 endo_guidance::CylinderPoseNodelet::contoursCb() /work/main/src/nodelets/cylinder_pose_nodelet.cpp:91 (libendo_guidance_nodelets.so+0x8)

SUMMARY: ThreadSanitizer: data race (libtsan.so+0x86c3d) in operator delete(void*, unsigned long)
"""
ROS_CYCLE = """WARNING: ThreadSanitizer: lock-order-inversion (potential deadlock) (pid=4)
  Mutex M706 acquired here while holding mutex M288 in main thread:
    #0 pthread_mutex_lock ../../../../src/libsanitizer/sanitizer_common/sanitizer_common_interceptors.inc:4324 (libtsan.so+0x558e1)
    #1 ros::Connection::addDropListener() <null> (libroscpp.so.4d+0xab34f)
    #2 bool ros::ServiceClient::call() /usr/include/ros/service_client.h:75 (test_pipeline_graph+0x52f35)
    #3 endo_guidance::test::callService() /work/main/test/ros/ros_test_main.h:29 (test_pipeline_graph+0x5308b)

  Mutex M288 previously acquired by the same thread here:
    #0 pthread_mutex_lock ../../../../src/libsanitizer/sanitizer_common/sanitizer_common_interceptors.inc:4324 (libtsan.so+0x558e1)
    #1 ros::ServiceManager::createServiceServerLink() <null> (libroscpp.so.4d+0x1)
    #2 endo_guidance::test::callService() /work/main/test/ros/ros_test_main.h:29 (test_pipeline_graph+0x5308b)

SUMMARY: ThreadSanitizer: lock-order-inversion (potential deadlock) (libroscpp.so.4d+0xab34f)
"""


def count(*reports):
    d = tempfile.mkdtemp(prefix="tsan_reports_")
    with open(os.path.join(d, "tsan.1"), "w") as f:
        f.write(SEP + SEP.join(reports) + SEP)
    out = subprocess.run([sys.executable, SCRIPT, d, REPO, os.path.join(d, "outside.txt")],
                         stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, check=True)
    return int(out.stdout.strip())


cases = [("a race between two of our accesses", [OURS_RACE], 1),
         ("a lock-order cycle through our mutex", [OURS_CYCLE], 1),
         ("a message freed by roscpp after our read", [FREED_BY_ROS], 0),
         ("a cycle inside roscpp reached from our code", [ROS_CYCLE], 0),
         ("all four", [OURS_RACE, FREED_BY_ROS, OURS_CYCLE, ROS_CYCLE], 2)]
failed = []
for name, reports, want in cases:
    got = count(*reports)
    print("%-45s ours: %d (expected %d)" % (name, got, want))
    if got != want:
        failed.append(name)
if failed:
    sys.exit("FAILED: " + ", ".join(failed))
