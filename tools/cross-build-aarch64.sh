#!/usr/bin/env bash
# aarch64 cross build of common/ + firmware/ (+ hw/ bench tools) and their tests under qemu-user.
#   tools/cross-build-aarch64.sh [build-dir]       (default: build-aarch64 in the checkout)
#   CROSS_STEP=build|test tools/cross-build-aarch64.sh   only that half (CI builds in the
#                                                        background and tests later); default both
# Installs the cross toolchain and arm64 -dev packages on first use (tools/install-deps.sh --cross),
# configures with cmake/toolchain-aarch64.cmake, STORETRACK_FIRMWARE_ONLY=ON, builds, checks that
# the binaries are AArch64, and runs ctest (each test through qemu-aarch64-static). Exit status:
# ctest's. Extra ctest arguments: CTEST_ARGS env var.
set -euo pipefail
cd "$(dirname "$0")/.."
BUILD=${1:-build-aarch64}
STEP=${CROSS_STEP:-all}
case "$STEP" in build | test | all) ;; *) echo "cross-build: CROSS_STEP must be build, test or all" >&2; exit 2 ;; esac
t0=$(date +%s)

# realdrivers tests boot an x86 VM: they belong to the native build, not to qemu-user. The
# scene simulator's tests (common/sim: the host's truth generator, heavy rendering) run natively;
# under qemu-user they take minutes. test_firmware_unit_integration spawns storetrack-unit as
# a child process, which needs binfmt_misc for aarch64 on the build host (CI has none); it runs
# in the native build. (test_firmware_health, libmodbus server + client threads on loopback, was
# excluded as stalling under qemu-user: that was the mismatched loader and libc that hung every
# first pthread_create, cmake/toolchain-aarch64.cmake; it passes under qemu-user in 2.2 s.)
# test_firmware_unit_allocations renders 380 simulated frames and sends them over loopback UDP:
# the simulator's cost; it runs natively. test_window_tracker renders the store separation's
# frames with the simulator likewise (its GCC 12 cross build also trips a known false
# -Warray-bounds in std::string's operator+ when the checkout's path is long); it runs natively.
# The excluded GoogleTest programs are not even built here (STORETRACK_TESTS_NOT_BUILT);
# CROSS_EXCLUDE='' builds and runs them too.
exclude=${CROSS_EXCLUDE-^test_sim_|^test_firmware_unit_integration\$|^test_firmware_unit_allocations\$|^test_window_tracker\$}

build_tree() {
  tools/install-deps.sh --cross
  mkdir -p "$BUILD"
  cmake -S . -B "$BUILD" -G Ninja -DCMAKE_TOOLCHAIN_FILE="$PWD/cmake/toolchain-aarch64.cmake" \
    -DCMAKE_BUILD_TYPE=RelWithDebInfo -DSTORETRACK_FIRMWARE_ONLY=ON -DSTORETRACK_BENCHMARKS=OFF \
    -DSTORETRACK_WERROR=ON -DSTORETRACK_TESTS_NOT_BUILT="$exclude" >"$BUILD/configure.log"
  grep 'test not built' "$BUILD/configure.log" | sed 's/^-- /cross-build: /' || true
  cmake --build "$BUILD" -j"$(nproc)"
  # Every linked program must be an AArch64 ELF: catches a host library leaking into the link.
  local n=0 f m
  while IFS= read -r -d '' f; do
    if head -c 4 "$f" | grep -q $'\x7fELF'; then
      m=$(LC_ALL=C readelf -h "$f" | awk -F: '/Machine:/{gsub(/^ +/,"",$2); print $2}')
      [ "$m" = AArch64 ] || { echo "cross-build: $f is '$m', not AArch64" >&2; exit 1; }
      n=$((n + 1))
    fi
  done < <(find "$BUILD" -path "$BUILD/CMakeFiles" -prune -o -type f -perm -u+x -print0)
  echo "cross-build: $n AArch64 executables, build $(($(date +%s) - t0)) s"
}

test_tree() {
  local rc=0
  # shellcheck disable=SC2086 # CTEST_ARGS is a list of words
  ctest --test-dir "$BUILD" --output-on-failure -j"$(nproc)" --no-tests=error -LE realdrivers \
    ${exclude:+-E "$exclude"} ${CTEST_ARGS:-} || rc=$?
  echo "cross-build: tests $(($(date +%s) - t0)) s, ctest exit $rc"
  return $rc
}

[ "$STEP" = test ] || build_tree
[ "$STEP" = build ] || test_tree
