#!/usr/bin/env bash
# AddressSanitizer + UndefinedBehaviorSanitizer and libFuzzer, with clang, in
# one build (build-san/): every core unit test runs under ASan+UBSan, then
# each fuzz target runs for FUZZ_SECONDS (default 30) from its committed seed
# corpus (tests/fuzz/corpus/<target>/; new inputs go to build-san/corpus/,
# crashes to build-san/fuzz-artifacts/). Any report fails the script.
# Usage: scripts/sanitize.sh            (what CI runs)
#        FUZZ_SECONDS=600 scripts/sanitize.sh fuzz   (the 10-minute benchmark)
set -euo pipefail
cd "$(dirname "$0")/.."
WHAT=${1:-all}
FUZZ_SECONDS=${FUZZ_SECONDS:-30}
GEN=()
if [ ! -f build-san/CMakeCache.txt ] && command -v ninja > /dev/null; then GEN=(-G Ninja); fi
cmake -S . -B build-san "${GEN[@]}" -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
  -DCLNERF_SANITIZE=ON -DCLNERF_FUZZ=ON > build-san.configure.log 2>&1 || { cat build-san.configure.log; exit 1; }
TARGETS="fuzz_checkpoint fuzz_scan_assembler"
CORE_TESTS="core_data_tests core_field_tests core_io_tests core_render_tests core_train_tests core_continual_tests core_bake_tests"
[ "$WHAT" = fuzz ] || TARGETS="$CORE_TESTS $TARGETS"
# shellcheck disable=SC2086  # A list of targets.
cmake --build build-san -j "${JOBS:-$(nproc)}" --target $TARGETS
export ASAN_OPTIONS="detect_leaks=1:abort_on_error=1:strict_string_checks=1"
export UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1"
export LSAN_OPTIONS="suppressions=$PWD/scripts/lsan.supp"
# The unit tests under ASan+UBSan: every core test but the multi-update
# continual and stability suites and the replay tests that first train a
# model (ReplayWeightsModelTest, ReplayLabelsTest.*Renders*: Eigen's
# kernels are not inlined under the sanitizers, so training runs ~30x
# slower; these run for minutes here, >10 min in all, and uninstrumented in
# scripts/test.sh; ReplayWeightsTest still checks the weighting rule), the
# tests that repeat the content sweep on several captures (~3.5 min here,
# and the LLFF writer sweeps once per capture: EveryFormatLoads* 70 s; on
# ../shared/data, flower_4's sweep 102 s and lego_100's 100 images 27 s; the
# sweep itself still runs here in ContentSweepTest.RoomPoints*, the writers
# and loaders in the other CaptureWriter and loader tests), and the
# cascaded checkpoint's size test (12 s here; its plain twin still runs and
# RoundTripUnboundedSceneWithCascades round-trips the cascade's sections); the
# CRC test: this build skips the checkpoint CRC so the fuzzer can reach the
# sections (FUZZING_BUILD_MODE_UNSAFE_FOR_PRODUCTION, as OSS-Fuzz builds do);
# the baker's tests, which train a model first (the asset format, its
# hostile folders and the reference renderer still run here).
SAN_FILTER=${SAN_FILTER:-'-BakerTest*:ContinualUpdateTest*:ContinualUpdateTest/*:StabilityTest*:ReplayWeightsModelTest*:ReplayLabelsTest.LabelsAre*:ReplayLabelsTest.UpdateRenders*:CheckpointTest.FlippedByteIsDataLoss:CheckpointTest.FileIsAtMostOneAndAQuarterParameterBytesWithCascades:ContentSweepTest.NormalisationFollowsTheCamerasFrame:ContentSweepTest.ForwardFacing*:ContentSweepTest.Flower4*:BlenderLoaderRealDataTest.*:CaptureWriterTest.EveryFormat*'}
# Two lanes at a time (each binary keeps ~1.3 of the 2 cores busy): the data
# tests in one, the other six in the other; each lane's output is printed
# when it ends.
run_lane() {  # run_lane LOG BINARIES...
  local log=$1 t
  shift
  for t in "$@"; do
    echo "== $t (ASan+UBSan) =="
    "./build-san/core/$t" --gtest_brief=1 --gtest_filter="$SAN_FILTER" || { echo "$t FAILED"; return 1; }
  done > "$log" 2>&1
}
if [ "$WHAT" != fuzz ]; then
  run_lane build-san/lane1.log core_data_tests & lane1=$!
  run_lane build-san/lane2.log core_train_tests core_continual_tests core_field_tests core_io_tests \
    core_render_tests core_bake_tests & lane2=$!
  rc=0
  wait $lane1 || rc=1
  wait $lane2 || rc=1
  cat build-san/lane1.log build-san/lane2.log
  [ $rc -eq 0 ] || { echo "a sanitizer test failed (see above)" >&2; exit 1; }
fi
mkdir -p build-san/fuzz-artifacts
# Both fuzz targets at once (libFuzzer uses one core each).
fuzz() {  # fuzz TARGET
  local t=$1
  mkdir -p "build-san/corpus/$t"
  ./build-san/tests/fuzz/$t -max_total_time="$FUZZ_SECONDS" -rss_limit_mb=2048 -timeout=20 -print_final_stats=1 \
    -artifact_prefix=build-san/fuzz-artifacts/ "build-san/corpus/$t" "tests/fuzz/corpus/$t" > "build-san/$t.log" 2>&1 || true
}
for t in fuzz_checkpoint fuzz_scan_assembler; do fuzz $t & done
wait
for t in fuzz_checkpoint fuzz_scan_assembler; do
  echo "== $t: ${FUZZ_SECONDS} s =="
  grep -E "^#[0-9]+ +DONE|stat::number_of_executed_units|ERROR|SUMMARY|Done [0-9]+ runs" "build-san/$t.log" || true
  if grep -qE "ERROR: (AddressSanitizer|libFuzzer|UndefinedBehaviorSanitizer)|runtime error:|==[0-9]+==ERROR" "build-san/$t.log"; then
    echo "$t found a crash; see build-san/$t.log and build-san/fuzz-artifacts/" >&2
    exit 1
  fi
done
