#!/usr/bin/env bash
# All tests: set up (apt packages, configure, build incl. test executables), then every test.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
cd build
ctest --output-on-failure -j"$(nproc)"
