#!/usr/bin/env bash
# Fuzzes the wire decoders (UDP datagram decoder, CAN FD reassembler) with libFuzzer for
# N seconds each (default 30), seeded with valid messages of both framings (docs/icd.md).
# Exits non-zero on any crash, sanitizer report or non-canonical acceptance.
set -euo pipefail
cd "$(dirname "$0")/.."
seconds=${1:-30}
B=${STORETRACK_FUZZ_BUILD_DIR:-build-fuzz}
cmake -S . -B "$B" -G Ninja -DCMAKE_C_COMPILER=clang -DCMAKE_CXX_COMPILER=clang++ \
  -DSTORETRACK_FUZZERS=ON -DSTORETRACK_BENCHMARKS=OFF >/dev/null
ninja -C "$B" fuzz_msg_udp_decode fuzz_msg_canfd_reassemble
python3 tests/common/msg/fuzz_seeds/make_seeds.py "$B/fuzz-seeds"
mkdir -p "$B/corpus-udp" "$B/corpus-canfd"
"$B/tests/common/msg/fuzz_msg_udp_decode" "$B/corpus-udp" "$B/fuzz-seeds/udp" \
  -max_total_time="$seconds" -max_len=600 -print_final_stats=1 2>&1 | tail -n 12
"$B/tests/common/msg/fuzz_msg_canfd_reassemble" "$B/corpus-canfd" "$B/fuzz-seeds/canfd" \
  -max_total_time="$seconds" -max_len=4096 -print_final_stats=1 2>&1 | tail -n 12
echo "fuzz-decoders: no crash in ${seconds} s per decoder"
