#!/usr/bin/env bash
# Fuzzes every reader of outside input with libFuzzer (ASan + UBSan) for N seconds each
# (default 30): the wire decoders (UDP datagram decoder, CAN FD reassembler), seeded with valid
# messages of both framings (docs/icd.md), and the host's readers (Chapter 10 reader, rig
# calibration, survey, host config, initial marks, the ExposureAligner on arbitrary decoded
# observations) and the unit's (replay PGM files, triggers.csv, the unit configuration, Modbus
# requests to the live server), seeded with the committed corpora
# tests/host/fuzz/seeds/<corpus>/ and tests/firmware/fuzz/seeds/<corpus>/
# (docs/reliability.md, "Fuzzing"). The fuzzers are single-threaded, so they run side by side,
# one per core. Exits non-zero on any crash, sanitizer report or
# violated property; each fuzzer's log is $B/<fuzzer>.log, a crash's input $B/crash-*.
#   FUZZ_STEP=build|run tools/fuzz-decoders.sh N   only that half (CI builds them in the
#                                                  sanitizer tree, tools/sanitize-tests.sh, and
#                                                  runs them with STORETRACK_FUZZ_BUILD_DIR
#                                                  there); default both.
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
  "fuzz_ch10_reader ch10_reader 4096"
  "fuzz_rig_calibration rig_calibration 16384"
  "fuzz_survey survey 8192"
  "fuzz_host_config host_config 8192"
  "fuzz_initial_marks initial_marks 8192"
  "fuzz_exposure_aligner exposure_aligner 4096"
  "fuzz_replay_pgm replay_pgm 1024"
  "fuzz_trigger_csv trigger_csv 2048"
  "fuzz_unit_config unit_config 8192"
  "fuzz_modbus_request modbus_request 2048"
)
[[ "$seconds" =~ ^[0-9]+$ ]] && [ "$seconds" -ge 1 ] || { echo "fuzz-decoders: N must be seconds >= 1" >&2; exit 2; }
if [ "$STEP" != run ]; then
  cmake -S . -B "$B" -G Ninja -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
    -DSTORETRACK_FUZZERS=ON -DSTORETRACK_BENCHMARKS=OFF >/dev/null
  targets=()
  for f in "${FUZZERS[@]}"; do targets+=("${f%% *}"); done
  ninja -C "$B" "${targets[@]}"
fi
[ "$STEP" != build ] || exit 0
python3 tests/common/msg/fuzz_seeds/make_seeds.py "$B/fuzz-seeds"

# One fuzzer per core at a time (each is single-threaded): every fuzzer gets N seconds of a
# whole core, and the run takes ceil(fuzzers / cores) x N seconds.
run_fuzzer() {
  local target=$1 corpus=$2 max_len=$3 exe seeds
  mkdir -p "$B/corpus-$corpus"
  exe=$(find "$B/tests" -type f -name "$target" | head -1)
  seeds="$B/fuzz-seeds/$corpus"  # generated (wire decoders) or committed (host, unit readers)
  for committed in "tests/host/fuzz/seeds/$corpus" "tests/firmware/fuzz/seeds/$corpus"; do
    [ -d "$committed" ] && seeds="$committed"
  done
  "$exe" "$B/corpus-$corpus" "$seeds" -max_total_time="$seconds" -max_len="$max_len" \
    -print_final_stats=1 -artifact_prefix="$B/" >"$B/$target.log" 2>&1
}
report() {
  local target=$1 rc=$2
  if [ "$rc" -eq 0 ]; then
    echo "== $target: no crash in ${seconds} s"
  else
    echo "== $target: FAILED (log $B/$target.log)"
    failed=1
  fi
  tail -n 12 "$B/$target.log"
}
cores=$(nproc)
failed=0
for ((first = 0; first < ${#FUZZERS[@]}; first += cores)); do
  pids=()
  names=()
  for f in "${FUZZERS[@]:first:cores}"; do
    read -r target corpus max_len <<<"$f"
    run_fuzzer "$target" "$corpus" "$max_len" &
    pids+=($!)
    names+=("$target")
  done
  for i in "${!pids[@]}"; do
    rc=0
    wait "${pids[$i]}" || rc=$?
    report "${names[$i]}" "$rc"
  done
done
[ "$failed" -eq 0 ] || exit 1
echo "fuzz-decoders: no crash in ${seconds} s per fuzzer (${#FUZZERS[@]} fuzzers, $cores at a time)"
