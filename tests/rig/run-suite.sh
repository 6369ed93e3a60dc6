#!/bin/bash
# run-suite.sh RESULTS_DIR TEST... : boots the VM once (vmrig.sh) and runs every named in-VM
# test (guest/<name>.sh) in it; per-test results land in RESULTS_DIR/<name>.{result,log} and are
# reported by check-result.sh (one ctest entry per in-VM test). Exit: 0 when the VM ran the suite
# (whatever the per-test results), 77 when the rig cannot start here, 1 when the VM failed.
set -uo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
RES=$1; shift
rm -rf "$RES"; mkdir -p "$RES"
# Host-side preparation of a test's inputs that are too costly to make under TCG (e2e: the
# simulator's rendered frames): guest/<name>.host.sh DIR runs here before the VM boots, only when
# the rig can start; DIR = RESULTS_DIR/<name>.host is visible in the VM at the same path. Its
# log is RESULTS_DIR/<name>.host.log; the in-VM test checks DIR/ok and reports a failure there.
if "$HERE/vmrig.sh" --prepare-only 2>/dev/null; then
  for name in "$@"; do
    [ -e "$HERE/guest/$name.host.sh" ] || continue
    start=$(date +%s.%N)
    sh "$HERE/guest/$name.host.sh" "$RES/$name.host" > "$RES/$name.host.log" 2>&1
    echo "== host-side preparation of $name: exit $?, $(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN{printf "%.1f", b-a}') s" |
      tee -a "$RES/$name.host.log"
  done
fi
VM_TIMEOUT=${VM_TIMEOUT:-1400} "$HERE/vmrig.sh" --out "$RES" "sh $HERE/guest/suite.sh $*" 2> >(tee "$RES/vmrig.err" >&2)
rc=$?
wait
if [ $rc = 77 ]; then
  echo "SKIP $(sed -n 's/^vmrig: SKIPPED: //p' "$RES/vmrig.err" | head -1)" > "$RES/STATUS"
  exit 77
fi
if [ ! -e "$RES/suite.done" ]; then
  echo "FAIL the VM did not finish the suite (vmrig exit $rc); see $RES/console.log" > "$RES/STATUS"
  exit 1
fi
echo "RAN" > "$RES/STATUS"
echo "== in-VM results:"; cat "$RES/summary.txt"
exit 0
