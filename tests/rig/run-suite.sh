#!/bin/bash
# run-suite.sh RESULTS_DIR TEST... : boots the VM once (vmrig.sh) and runs every named in-VM
# test (guest/<name>.sh) in it; per-test results land in RESULTS_DIR/<name>.{result,log} and are
# reported by check-result.sh (one ctest entry per in-VM test). Exit: 0 when the VM ran the suite
# (whatever the per-test results), 77 when the rig cannot start here, 1 when the VM failed.
set -uo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
RES=$1; shift
rm -rf "$RES"; mkdir -p "$RES"
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
