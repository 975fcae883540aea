#!/usr/bin/env bash
# All tests: set up (apt packages, configure, build incl. test executables), build the fuzz
# harnesses (clang, ASan + UBSan: ctest fuzz_replay replays their corpus; setup_packages reads
# their build), then every test.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
echo "[test] building the fuzz harnesses (build/fuzz)"
bash scripts/fuzz.sh build
cd build
ctest --output-on-failure -j"$(nproc)"
