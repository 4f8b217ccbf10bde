#!/usr/bin/env bash
# Builds clnerf and runs the whole test suite through CTest.
# Usage: scripts/test.sh [ctest args], e.g. scripts/test.sh -R Checkpoint
set -euo pipefail
cd "$(dirname "$0")/.."
ROOT=$PWD
bash scripts/build.sh
cd "${BUILD_DIR:-build}"
# Longest tests first, also on a fresh build folder: CTest orders by the
# durations it measured before, so a new folder starts from ours
# (tests/ctest_costs.txt, measured on a 2-core Xeon; a stale or missing entry
# only changes the order).
if [ ! -f Testing/Temporary/CTestCostData.txt ]; then
  mkdir -p Testing/Temporary
  { cat "$ROOT/tests/ctest_costs.txt"; echo "---"; } > Testing/Temporary/CTestCostData.txt
fi
# Two tests at once, each with its own OpenMP team: idle OpenMP threads
# sleep rather than spin (two concurrent training tests: 15-17 s -> 12.5 s).
export OMP_WAIT_POLICY=${OMP_WAIT_POLICY:-passive}
ctest --output-on-failure -j "${CTEST_JOBS:-2}" "$@"
