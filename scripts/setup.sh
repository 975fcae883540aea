#!/usr/bin/env bash
# Installs every Debian 12 package endo_guidance needs (ROS 1 from Debian, OpenCV, Eigen, ViSP,
# GoogleTest/Benchmark, clang for the fuzz harnesses), then configures and builds the package with
# plain CMake into build/ (the fuzz harnesses are the tests' to build: scripts/test.sh).
# The list must hold every package the build and the scripts use, or a Depends of one (never a
# Recommends): ctest setup_packages checks it, scripts/fresh_debian_check.sh proves it.
# Idempotent: a second run with nothing changed only checks and re-runs an incremental build.
# Usage: scripts/setup.sh [--no-build]
set -euo pipefail
cd "$(dirname "$0")/.."

PKGS=(
  g++ cmake make pkg-config
  catkin ros-message-generation ros-message-runtime libroscpp-dev rosout
  libstd-msgs-dev ros-std-msgs libgeometry-msgs-dev ros-geometry-msgs
  libsensor-msgs-dev ros-sensor-msgs libvisualization-msgs-dev ros-visualization-msgs
  libdiagnostic-msgs-dev ros-diagnostic-msgs libstd-srvs-dev ros-std-srvs
  libnodelet-dev libnodeletlib-dev libnodeletlib-tools pluginlib-dev
  libimage-transport-dev libcv-bridge-dev libimage-geometry-dev libcamera-calibration-parsers-dev
  libcamera-info-manager-dev ros-camera-calibration python3-cv-bridge python3-image-geometry python3-diagnostic-msgs python3-tf2-msgs
  libtf2-ros-dev libtf2-geometry-msgs-dev libtf2-eigen-dev
  libdiagnostic-updater-dev libdynamic-reconfigure-config-init-mutex-dev python3-dynamic-reconfigure
  librosbag-dev libroslz4-dev libbz2-dev python3-rosbag python3-rostopic python3-sensor-msgs rosbash ros-core
  libopencv-dev libeigen3-dev libvisp-dev libyaml-cpp-dev
  libgtest-dev libgmock-dev libbenchmark-dev librostest-dev python3-rostest
  python3-tf2-ros python3-scipy
  rviz xvfb xauth imagemagick image-transport-tools python3-matplotlib python3-opencv
  chromium
  # the fuzz harnesses (scripts/fuzz.sh, the tests): clang with its sanitizer and libFuzzer
  # runtimes and OpenMP header, which clang-14 only recommends
  clang libclang-rt-14-dev libomp-14-dev
)

missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
  echo "[setup] installing ${#missing[@]} Debian packages: ${missing[*]}"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  export DEBIAN_FRONTEND=noninteractive
  $SUDO apt-get update -qq
  $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
fi

[ "${1:-}" = "--no-build" ] && exit 0

BUILD_TYPE="${CMAKE_BUILD_TYPE:-Release}"
if [ ! -f build/CMakeCache.txt ]; then
  mkdir -p build
  echo "[setup] configuring (CMake, $BUILD_TYPE) into build/"
  cmake -S . -B build -DCMAKE_BUILD_TYPE="$BUILD_TYPE" \
    -DPYTHON_EXECUTABLE=/usr/bin/python3 -DPython3_EXECUTABLE=/usr/bin/python3 >build/configure.log 2>&1 \
    || { cat build/configure.log; exit 1; }
fi
echo "[setup] building"
# (the build's own status, not grep's: a failed build fails the set-up)
status=0
cmake --build build -j"$(nproc)" --target all tests -- --no-print-directory >build/build.log 2>&1 || status=$?
grep -vE '^\[ *[0-9]+%\] (Built target|Generating|Building)|^Scanning' build/build.log || true
[ "$status" -eq 0 ] || { echo "[setup] build failed (build/build.log)" >&2; exit "$status"; }
