#!/usr/bin/env bash
# The test suite under ASan + UBSan (gcc): configures build/sanitize with CMAKE_BUILD_TYPE=Sanitize,
# builds everything and the tests, and runs ctest there. ROS' own programs (the nodelet manager,
# roslaunch, rostest's Python) are not instrumented: libasan is preloaded into every process so
# that the instrumented nodelets load into them. Leak checking is off (ROS and Python leak at exit).
# Reports go to build/sanitize/reports/; the verdict to build/sanitize/summary.txt.
# Exit 0 only when every test passed and no sanitizer reported anything.
#   scripts/sanitize.sh [-j N] [ctest args...]      e.g. scripts/sanitize.sh -R test_servo
set -euo pipefail
cd "$(dirname "$0")/.."
jobs="$(nproc)"
if [ "${1:-}" = "-j" ]; then
  [[ "${2:-}" =~ ^[0-9]+$ ]] || { echo "sanitize.sh: -j needs a number" >&2; exit 2; }
  jobs="$2"; shift 2
fi
libasan="$(g++ -print-file-name=libasan.so)"
[ -f "$libasan" ] || { echo "sanitize.sh: libasan not found (g++ -print-file-name=libasan.so)" >&2; exit 2; }
B=build/sanitize
mkdir -p "$B"
if [ ! -f "$B/CMakeCache.txt" ]; then
  cmake -S . -B "$B" -DCMAKE_BUILD_TYPE=Sanitize -DPYTHON_EXECUTABLE=/usr/bin/python3 >"$B/configure.log" 2>&1 \
    || { cat "$B/configure.log"; exit 1; }
fi
echo "[sanitize] building $B (-j$jobs)"
built=0
cmake --build "$B" -j"$jobs" --target all tests -- --no-print-directory >"$B/build.log" 2>&1 || built=$?
[ "$built" -eq 0 ] || { grep -m20 -E "error|Error" "$B/build.log" >&2; echo "sanitize.sh: build failed ($B/build.log)" >&2; exit 1; }
reports="$PWD/$B/reports"
rm -rf "$reports"; mkdir -p "$reports"
# libstdc++ after libasan: ASan's __cxa_throw interceptor finds the real one at start-up, and a
# C program (python) that loads C++ later would otherwise abort on its first exception.
export LD_PRELOAD="$libasan $(g++ -print-file-name=libstdc++.so.6)"
export ASAN_OPTIONS="detect_leaks=0:halt_on_error=1:abort_on_error=0:log_path=$reports/asan"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1:log_path=$reports/ubsan"
start=$(date +%s)
status=0
# fuzz_replay is the clang build's (already ASan + UBSan); behaviour_digest digests the Release
# build's floating point (-O3), not this one's; the rest run here.
(cd "$B" && ctest --output-on-failure -j"$jobs" -E '^(fuzz_replay|behaviour_digest)$' "$@") >"$B/ctest.log" 2>&1 || status=$?
unset LD_PRELOAD
minutes=$(( ($(date +%s) - start + 59) / 60 ))
# Reports go to log_path where the runtime honours it, else to the test's output (rostest nodes,
# UBSan beside ASan): both are counted.
in_log=$(grep -cE 'runtime error:|ERROR: AddressSanitizer|AddressSanitizer: CHECK failed' "$B/ctest.log" || true)
n_reports=$(( $(find "$reports" -type f | wc -l) + in_log ))
tests_line="$(grep -E 'tests passed|tests failed' "$B/ctest.log" | tail -1)"
{
  echo "sanitize: $(git rev-parse --short HEAD) $(date -u +%Y-%m-%dT%H:%MZ), ${minutes} min of tests"
  echo "tests: ${tests_line:-no ctest summary (see $B/ctest.log)}"
  echo "sanitizer reports: $n_reports"
  for f in "$reports"/*; do [ -f "$f" ] && { echo "--- $f"; grep -m3 -E 'ERROR|runtime error' "$f" || head -3 "$f"; }; done
  grep -E 'runtime error:|ERROR: AddressSanitizer|AddressSanitizer: CHECK failed' "$B/ctest.log" | sort | uniq -c | head -20
} >"$B/summary.txt"
cat "$B/summary.txt"
[ "$status" -eq 0 ] && [ "$n_reports" -eq 0 ]
