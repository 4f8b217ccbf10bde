#!/usr/bin/env bash
# Builds the server tests with ThreadSanitizer (into build-tsan/) and runs
# them. OpenMP runs single-threaded here (OMP_THREAD_LIMIT=1): libgomp is not
# instrumented, so its own thread pool would only produce false reports; the
# threads under test (gRPC handlers, the update worker, concurrent renders,
# registry readers and writer) are all still there.
# Usage: scripts/tsan.sh [gtest filter]
# The default filter is what CI runs: the concurrency tests (registry under a
# swapping writer, renders during an update, the job queue, the training-slot
# scheduler, the model cache's single-flight loads), the full queue and the
# health service. Training under TSan is ~50x
# slower, so the rest (which repeat the same threads on more scenarios, e.g.
# UploadTrainPublishRenderAnyTimeStep: 65 s here for one worker thread and
# sequential calls) is left to `scripts/tsan.sh '*'`.
set -euo pipefail
cd "$(dirname "$0")/.."
FILTER=${1:-'ModelRegistry*:JobTracker*:TrainingScheduler*:ModelCache*:ServerFixture.RendersDuringAnUpdate*:ServerFixture.FullQueue*:ServerFixture.HealthServiceAnswers'}
# The default filter's tests live in five files, built as their own binary
# (tests/CMakeLists.txt: server_concurrency_tests), which spares CI compiling
# every other server test under TSan; a filter given here uses them all.
TARGET=server_concurrency_tests
if [ $# -gt 0 ]; then TARGET=server_tests; fi
# The core modules that run on one thread of the update worker (data,
# train, pose, bake) are linked uninstrumented from the plain build
# (CMakeLists.txt: CLNERF_TSAN_PLAIN_KERNELS_FROM; in CI the test stage has
# built them, so this is a no-op): TSan compiles and checks what threads
# share. TSAN_PLAIN_BUILD= (empty) instruments everything.
PLAIN=${TSAN_PLAIN_BUILD-build}
gen() { if [ ! -f "$1/CMakeCache.txt" ] && command -v ninja > /dev/null; then echo "-G Ninja"; fi; }
PLAIN_FLAGS=()
if [ -n "$PLAIN" ]; then
  # shellcheck disable=SC2046  # gen prints the generator flag words.
  if [ ! -f "$PLAIN/CMakeCache.txt" ]; then
    cmake -S . -B "$PLAIN" $(gen "$PLAIN") -DCMAKE_BUILD_TYPE=Release > "$PLAIN.configure.log" 2>&1 || {
      cat "$PLAIN.configure.log"; exit 1; }
  fi
  cmake --build "$PLAIN" -j "${JOBS:-$(nproc)}" --target clnerf_data clnerf_train clnerf_pose clnerf_bake clnerf_oiio
  PLAIN_FLAGS=(-DCLNERF_TSAN_PLAIN_KERNELS_FROM="$(cd "$PLAIN" && pwd)")
else
  PLAIN_FLAGS=(-DCLNERF_TSAN_PLAIN_KERNELS_FROM=)
fi
# shellcheck disable=SC2046
cmake -S . -B build-tsan $(gen build-tsan) -DCMAKE_BUILD_TYPE=RelWithDebInfo -DCLNERF_TSAN=ON "${PLAIN_FLAGS[@]}" \
  > build-tsan.configure.log 2>&1 || { cat build-tsan.configure.log; exit 1; }
cmake --build build-tsan -j "${JOBS:-$(nproc)}" --target "$TARGET"
OMP_NUM_THREADS=1 OMP_THREAD_LIMIT=1 TSAN_OPTIONS="halt_on_error=1 second_deadlock_stack=1 suppressions=$PWD/scripts/tsan.supp" \
  "./build-tsan/tests/$TARGET" --gtest_filter="$FILTER" --gtest_brief=1
