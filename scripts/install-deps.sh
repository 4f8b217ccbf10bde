#!/usr/bin/env bash
# Installs every build and test dependency of clnerf from Debian bookworm packages.
# Used by the README's first command and by .ci/run, so a fresh machine and CI
# install exactly the same set. Safe to run repeatedly.
set -euo pipefail

PKGS=(
  build-essential cmake ninja-build pkg-config
  libgrpc-dev libgrpc++-dev protobuf-compiler-grpc libprotobuf-dev protobuf-compiler
  libabsl-dev libeigen3-dev libopenimageio-dev openimageio-tools libspdlog-dev libfmt-dev
  libgtest-dev libgmock-dev nlohmann-json3-dev libcli11-dev zlib1g-dev
  python3
  clang libclang-rt-dev libomp-dev
  libcpp-httplib-dev prometheus-cpp-dev
  etcd-server
  # Posing and registration of scans (core/pose): OpenCV's SIFT and PnP, COLMAP
  # for unposed uploads, ffmpeg for video frames.
  libopencv-dev colmap ffmpeg
)
# Charts of the benchmarks (bench/*.py draw them when matplotlib is there) and
# the profilers (perf, callgrind): CLNERF_BENCH_TOOLS=1 adds them. CI and a
# first run need neither.
if [ "${CLNERF_BENCH_TOOLS:-0}" = 1 ]; then
  PKGS+=(python3-matplotlib linux-perf valgrind)
fi
# The web viewer's end-to-end test drives a real headless Chromium
# (CLNERF_NO_BROWSER=1 skips these, e.g. for an image that builds no tests).
if [ "${CLNERF_NO_BROWSER:-0}" != 1 ]; then
  PKGS+=(chromium chromium-driver python3-selenium)
fi

missing=()
for p in "${PKGS[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#PKGS[@]} packages already installed"
  exit 0
fi
echo "install-deps: installing ${missing[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get update -qq
$SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
