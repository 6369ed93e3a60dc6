#!/usr/bin/env bash
# The ASan + UBSan stage: builds the sanitizer tree (clang, RelWithDebInfo at -O1 -g1, the tests'
# own sources at -O0, warnings as errors, no benchmarks, not the bench programs and VM-rig drivers
# no test here runs; the libFuzzer targets in the same tree) and runs its tests.
# Not the VM rig (it boots the Release programs), and not the fault, soak and kill -9 runs:
# system tests of several real processes against wall-clock pacing and waits, which the
# instrumented programs (3-10x slower) cannot keep on 2 cores; they run in the Release stage, and
# the code they drive is under the sanitizers here through its unit tests and the fuzzers.
#
# The scene simulator (common/sim: storetrack_sim, storetrack_sim_render; test support that
# production libraries never link) is compiled here without ASan/UBSan, at -O2
# (storetrack_uninstrumented_in_sanitizer_tree, cmake/StoretrackWarnings.cmake). It generates the
# truth; the code under test is the product's, and every product library, the programs, the
# fuzzers and the tests' own sources stay instrumented: their loads, stores, arithmetic and
# allocations are checked whatever fed them (ASan's heap checks are in the allocator, linked for
# the whole executable). Not checked: the simulator's own code, and an inline or template function
# (an Eigen product) whose one kept copy in an executable is the simulator's. Measured
# 2026-12-06: the simulator's 8 sources 57.5 -> 38.4 s of CPU; the 25 slowest tests of this stage
# 1096 -> 780 s summed, 619 -> 437 s wall at -j2 (docs/performance.md "CI budget").
#
# clang, not GCC: the same sources compile about 3x faster under ASan + UBSan with clang 14
# (host_options.cpp 30 s against 85 s, exposure_processor.cpp 40 s against 127 s of CPU,
# docs/performance.md "CI budget"), and libFuzzer needs clang anyway.
#   SAN_STEP=build|run tools/sanitize-tests.sh   only that half (CI builds in the background and
#                                                runs later); default both. Extra arguments go
#                                                to ctest.
# Tree: build-asan/ (STORETRACK_ASAN_BUILD_DIR); tools/fuzz-decoders.sh runs its fuzzers with
# STORETRACK_FUZZ_BUILD_DIR pointing there.
set -euo pipefail
cd "$(dirname "$0")/.."
STEP=${SAN_STEP:-all}
case "$STEP" in build | run | all) ;; *) echo "sanitize-tests: SAN_STEP must be build, run or all" >&2; exit 2 ;; esac
B=${STORETRACK_ASAN_BUILD_DIR:-build-asan}
# The tests of this stage, as ctest selects them.
SELECT=(-LE 'realdrivers|e2e|faults' -E '^test_integration_host_kill$')

if [ "$STEP" != run ]; then
  cmake -S . -B "$B" -G Ninja -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
    -DCMAKE_BUILD_TYPE=RelWithDebInfo -DSTORETRACK_SANITIZE=ON -DSTORETRACK_FUZZERS=ON \
    -DSTORETRACK_BENCHMARKS=OFF -DSTORETRACK_WERROR=ON -DSTORETRACK_FIRMWARE_ONLY=OFF >/dev/null
  echo "sanitize-tests: building the tree (no benchmarks; the fuzzers are part of it) in $B"
  ninja -C "$B" -j"$(nproc)"
fi
[ "$STEP" != build ] || exit 0

ASAN_OPTIONS=detect_leaks=1:abort_on_error=1 UBSAN_OPTIONS=print_stacktrace=1 \
  ctest --test-dir "$B" --output-on-failure -j"$(nproc)" "${SELECT[@]}" "$@"
