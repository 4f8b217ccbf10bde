#!/usr/bin/env bash
# Builds clnerf and runs the whole test suite through CTest.
# Usage: scripts/test.sh [ctest args], e.g. scripts/test.sh -R Checkpoint
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/build.sh
cd "${BUILD_DIR:-build}"
ctest --output-on-failure -j "${CTEST_JOBS:-2}" "$@"
