#!/usr/bin/env bash
# Fuzzes the wire decoders (UDP datagram decoder, CAN FD reassembler) with libFuzzer for
# N seconds each (default 30), seeded with valid messages of both framings (docs/icd.md).
# The fuzzers are single-threaded, so they run side by side (one per core): N seconds of wall
# time for all of them. Exits non-zero on any crash, sanitizer report or non-canonical
# acceptance; each fuzzer's log is $B/<fuzzer>.log.
#   FUZZ_STEP=build|run tools/fuzz-decoders.sh N   only that half (CI builds in the background
#                                                  and runs later); default both.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-30}
STEP=${FUZZ_STEP:-all}
case "$STEP" in build | run | all) ;; *) echo "fuzz-decoders: FUZZ_STEP must be build, run or all" >&2; exit 2 ;; esac
B=${STORETRACK_FUZZ_BUILD_DIR:-build-fuzz}
# fuzzer target, corpus name, -max_len
FUZZERS=(
  "fuzz_msg_udp_decode udp 600"
  "fuzz_msg_canfd_reassemble canfd 4096"
)
if [ "$STEP" != run ]; then
  cmake -S . -B "$B" -G Ninja -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
    -DSTORETRACK_FUZZERS=ON -DSTORETRACK_BENCHMARKS=OFF >/dev/null
  targets=()
  for f in "${FUZZERS[@]}"; do targets+=("${f%% *}"); done
  ninja -C "$B" "${targets[@]}"
  python3 tests/common/msg/fuzz_seeds/make_seeds.py "$B/fuzz-seeds"
fi
[ "$STEP" != build ] || exit 0

pids=()
for f in "${FUZZERS[@]}"; do
  read -r target corpus max_len <<<"$f"
  mkdir -p "$B/corpus-$corpus"
  exe=$(find "$B/tests" -type f -name "$target" | head -1)
  "$exe" "$B/corpus-$corpus" "$B/fuzz-seeds/$corpus" -max_total_time="$seconds" \
    -max_len="$max_len" -print_final_stats=1 >"$B/$target.log" 2>&1 &
  pids+=($!)
done
failed=0
for i in "${!pids[@]}"; do
  target=${FUZZERS[$i]%% *}
  if wait "${pids[$i]}"; then
    echo "== $target: no crash in ${seconds} s"
  else
    echo "== $target: FAILED (log $B/$target.log)"
    failed=1
  fi
  tail -n 12 "$B/$target.log"
done
[ "$failed" -eq 0 ] || exit 1
echo "fuzz-decoders: no crash in ${seconds} s per fuzzer (${#pids[@]} fuzzers)"
