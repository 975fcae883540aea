#!/usr/bin/env bash
# The test suite under ASan + UBSan (gcc): configures build/sanitize with CMAKE_BUILD_TYPE=Sanitize,
# builds everything and the tests, and runs ctest there. ROS' own programs (the nodelet manager,
# roslaunch, rostest's Python) are not instrumented: libasan is preloaded into every process so
# that the instrumented nodelets load into them. Leak checking is off (ROS and Python leak at exit).
# Reports go to build/sanitize/reports/; the verdict to build/sanitize/summary.txt.
# --thread: the nodelet graph tests (the rostests) under TSan in build/tsan (CMAKE_BUILD_TYPE=
# ThreadSanitize, libtsan preloaded); the reports wholly inside ROS' uninstrumented libraries are
# listed, not counted (scripts/tsan_reports.py).
# Exit 0 only when every test passed and no sanitizer reported anything.
#   scripts/sanitize.sh [--thread] [-j N] [ctest args...]      e.g. scripts/sanitize.sh -R test_servo
set -euo pipefail
cd "$(dirname "$0")/.."
jobs="$(nproc)"
thread=0
if [ "${1:-}" = "--thread" ]; then thread=1; shift; fi
if [ "${1:-}" = "-j" ]; then
  [[ "${2:-}" =~ ^[0-9]+$ ]] || { echo "sanitize.sh: -j needs a number" >&2; exit 2; }
  jobs="$2"; shift 2
fi
if [ "$thread" -eq 1 ]; then
  runtime="$(g++ -print-file-name=libtsan.so)" B=build/tsan type=ThreadSanitize
  targets="all test_pipeline_graph test_simulation test_servo test_faults test_bag_faults"
  [ $# -gt 0 ] || set -- -R rostest
else
  runtime="$(g++ -print-file-name=libasan.so)" B=build/sanitize type=Sanitize targets="all tests"
fi
[ -f "$runtime" ] || { echo "sanitize.sh: $(basename "$runtime") not found (g++ -print-file-name)" >&2; exit 2; }
mkdir -p "$B"
if [ ! -f "$B/CMakeCache.txt" ]; then
  cmake -S . -B "$B" -DCMAKE_BUILD_TYPE=$type -DPYTHON_EXECUTABLE=/usr/bin/python3 >"$B/configure.log" 2>&1 \
    || { cat "$B/configure.log"; exit 1; }
fi
echo "[sanitize] building $B (-j$jobs)"
built=0
cmake --build "$B" -j"$jobs" --target $targets -- --no-print-directory >"$B/build.log" 2>&1 || built=$?
[ "$built" -eq 0 ] || { grep -m20 -E "error|Error" "$B/build.log" >&2; echo "sanitize.sh: build failed ($B/build.log)" >&2; exit 1; }
reports="$PWD/$B/reports"
rm -rf "$reports"; mkdir -p "$reports"
# libstdc++ after the runtime: its __cxa_throw interceptor finds the real one at start-up, and a
# C program (python) that loads C++ later would otherwise abort on its first exception.
export LD_PRELOAD="$runtime $(g++ -print-file-name=libstdc++.so.6)"
export ASAN_OPTIONS="detect_leaks=0:halt_on_error=1:abort_on_error=0:log_path=$reports/asan"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1:log_path=$reports/ubsan"
export TSAN_OPTIONS="report_signal_unsafe=0:second_deadlock_stack=1:log_path=$reports/tsan"
start=$(date +%s)
status=0
# fuzz_replay is the clang build's (already ASan + UBSan); behaviour_digest digests the Release
# build's floating point (-O3), not this one's; the rest run here.
(cd "$B" && ctest --output-on-failure -j"$jobs" -E '^(fuzz_replay|behaviour_digest)$' "$@") >"$B/ctest.log" 2>&1 || status=$?
unset LD_PRELOAD
minutes=$(( ($(date +%s) - start + 59) / 60 ))
pattern='runtime error:|ERROR: AddressSanitizer|AddressSanitizer: CHECK failed|WARNING: ThreadSanitizer|ThreadSanitizer: CHECK failed'
# Reports go to log_path where the runtime honours it, else to the test's output (rostest nodes,
# UBSan beside ASan): both are counted.
in_log=$(grep -cE "$pattern" "$B/ctest.log" || true)
if [ "$thread" -eq 1 ]; then
  # TSan also reports inside ROS' own uninstrumented libraries: only the reports in our code count.
  in_files=$(/usr/bin/python3 scripts/tsan_reports.py "$reports" "$PWD" "$B/tsan_outside.txt")
else
  in_files=$(find "$reports" -type f | wc -l)
fi
n_reports=$(( in_files + in_log ))
tests_line="$(grep -E 'tests passed|tests failed' "$B/ctest.log" | tail -1)"
{
  echo "sanitize ($type): $(sed -n 's/.*REVISION "\(.*\)"/\1/p' "$B/generated/endo_guidance_git_revision.h" 2>/dev/null) $(date -u +%Y-%m-%dT%H:%MZ), ${minutes} min of tests"
  echo "tests: ${tests_line:-no ctest summary (see $B/ctest.log)}"
  echo "sanitizer reports: $n_reports"
  [ "$thread" -eq 0 ] || { echo "TSan reports wholly inside ROS' own libraries (not counted), by kind and first function:"; head -20 "$B/tsan_outside.txt"; }
  [ "$thread" -eq 1 ] || for f in "$reports"/*; do [ -f "$f" ] && { echo "--- $f"; grep -m3 -E 'ERROR|runtime error|WARNING' "$f" || head -3 "$f"; }; done
  grep -E "$pattern" "$B/ctest.log" | sort | uniq -c | head -20 || true
} >"$B/summary.txt"
cat "$B/summary.txt"
[ "$status" -eq 0 ] && [ "$n_reports" -eq 0 ]
