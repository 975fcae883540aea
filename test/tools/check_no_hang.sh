#!/usr/bin/env bash
# Nothing hangs: a launch that cannot start, and a script with no master, each say why and exit
# non-zero in bounded time (a hang is killed by the timeout and fails the test).
set -uo pipefail
cd "$(dirname "$0")/../.."
fail() { echo "FAILED: $*"; exit 1; }
# 1. replay_demo.sh (scripts/run.sh's job) with a launch that fails at once (a missing parameters file).
start=$(date +%s)
out=$(timeout 90 bash scripts/replay_demo.sh params:=/nonexistent/pipeline.yaml 2>&1); rc=$?
el=$(( $(date +%s) - start ))
[ $rc -ne 124 ] || fail "replay_demo.sh hung on a failed launch"
[ $rc -ne 0 ] || fail "replay_demo.sh exited 0 on a failed launch"
grep -q "roslaunch failed to start" <<<"$out" || fail "replay_demo.sh did not say why: $out"
echo "replay_demo.sh with a failed launch: exit $rc after ${el} s"
# 2. report_trocars.py with no master at all.
set +u; source build/devel/setup.bash; set -u
start=$(date +%s)
out=$(ROS_MASTER_URI=http://127.0.0.1:1 timeout 60 /usr/bin/python3 scripts/report_trocars.py <(echo "trocars: [[0, 0, 0.1]]") /tmp/x.png 2>&1); rc=$?
el=$(( $(date +%s) - start ))
[ $rc -ne 124 ] || fail "report_trocars.py hung without a master"
[ $rc -ne 0 ] || fail "report_trocars.py exited 0 without a master"
grep -q "no ROS master" <<<"$out" || fail "report_trocars.py did not say why: $out"
echo "report_trocars.py without a master: exit $rc after ${el} s"
