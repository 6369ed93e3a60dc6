#!/bin/sh
# In-VM test suite: runs guest/<name>.sh for every name given, each in its own process with a
# timeout, and records PASS / FAIL / SKIP (exit 77) with the reason in $VMRIG_OUT/<name>.result.
# Runs as root inside the VM (Debian 6.1 kernel; host root read-only + tmpfs overlay).
HERE=$(cd "$(dirname "$0")" && pwd)
OUT=${VMRIG_OUT:?}
: > "$OUT/summary.txt"
for name in "$@"; do
  start=$(date +%s.%N)
  echo "== [vm] $name"
  timeout -k 5 "${VMTEST_TIMEOUT:-180}" sh "$HERE/$name.sh" > "$OUT/$name.log" 2>&1
  rc=$?
  secs=$(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN{printf "%.1f", b-a}')
  last=$(grep -E '^(FAIL|SKIP):' "$OUT/$name.log" | tail -1)
  case $rc in
    0) r="PASS ($secs s)" ;;
    77) r="SKIP ${last#SKIP: }" ;;
    124|137) r="FAIL timed out after ${VMTEST_TIMEOUT:-180} s" ;;
    *) r="FAIL exit $rc: ${last#FAIL: }" ;;
  esac
  echo "$r" > "$OUT/$name.result"
  printf '%-16s %s\n' "$name" "$r" | tee -a "$OUT/summary.txt"
done
touch "$OUT/suite.done"
