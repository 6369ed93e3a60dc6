#!/bin/bash
# check-result.sh RESULTS_DIR NAME : reports one in-VM test run by run-suite.sh (the ctest
# fixture that boots the VM once): exit 0 PASS, 1 FAIL, 77 SKIP (with the reason).
RES=$1; NAME=$2
status=$(cat "$RES/STATUS" 2>/dev/null || echo "FAIL the VM suite did not run (no $RES/STATUS)")
case "$status" in
  SKIP*) echo "rig unavailable: ${status#SKIP }"; exit 77 ;;
  FAIL*) echo "${status#FAIL }"; exit 1 ;;
esac
[ -e "$RES/$NAME.log" ] && cat "$RES/$NAME.log"
result=$(cat "$RES/$NAME.result" 2>/dev/null || echo "FAIL no result for $NAME (suite crashed? see $RES/console.log)")
echo "== $NAME: $result"
case "$result" in
  PASS*) exit 0 ;;
  SKIP*) exit 77 ;;
  *) exit 1 ;;
esac
