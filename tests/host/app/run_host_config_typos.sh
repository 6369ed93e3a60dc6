#!/usr/bin/env bash
# Issue 31: storetrack-host ran with exit 0 and the defaults on a configuration or survey typo.
# The real program, given each typo, must exit 2 before receiving anything and name the file,
# the key's path and the nearest known key on stderr; the same files without the typo start.
#   run_host_config_typos.sh STORETRACK_HOST SEEDS_DIR WORK_DIR
set -euo pipefail
host=$1 seeds=$2 work=$3
rm -rf "$work" && mkdir -p "$work"
rig=$seeds/rig_calibration/rig_2cam.json
pylon=$seeds/survey/pylon.json
store=$seeds/survey/store.json
failures=0

# expect_refused NAME CONFIG_JSON PYLON_FILE EXPECTED_STDERR_TEXT
expect_refused() {
  local name=$1 config=$2 pylon_file=$3 expected=$4
  printf '%s\n' "$config" >"$work/$name.json"
  local rc=0
  timeout 20 "$host" --config "$work/$name.json" --calibration "$rig" --pylon-survey "$pylon_file" \
    --store-survey "$store" --udp-port 0 --duration-s 0.1 >"$work/$name.out" 2>"$work/$name.err" \
    || rc=$?
  if [ "$rc" -ne 2 ] || ! grep -qF -- "$expected" "$work/$name.err"; then
    echo "FAIL $name: exit $rc (want 2), stderr:" >&2
    cat "$work/$name.err" >&2
    echo "  wanted: $expected" >&2
    failures=$((failures + 1))
  else
    echo "ok   $name: $(head -1 "$work/$name.err")"
  fi
}

expect_refused max_wait '{"aligner": {"max_wait": 10}}' "$pylon" \
  "$work/max_wait.json: aligner.max_wait: unknown key (did you mean max_wait_ms?)"
expect_refused algner '{"algner": {"max_wait_ms": 10}}' "$pylon" \
  "$work/algner.json: algner: unknown key (did you mean aligner?)"
expect_refused prot '{"udp": {"prot": 5}}' "$pylon" \
  "$work/prot.json: udp.prot: unknown key (did you mean port?)"
expect_refused aligner_array '{"aligner": [1, 2]}' "$pylon" \
  "$work/aligner_array.json: aligner: expected an object, got an array"
# A pylon survey with a misspelt key (sigma_m of the first mark written "sigma_mm").
sed '0,/"sigma_m"/s/"sigma_m"/"sigma_mm"/' "$pylon" >"$work/pylon_typo.json"
expect_refused pylon_survey '{}' "$work/pylon_typo.json" \
  "$work/pylon_typo.json: marks[0].sigma_m: missing (is sigma_mm a typo of it?)"
# An optional key misspelt in the survey: refused by name too.
sed '0,/"format"/s/"format"/"fromat"/' "$pylon" >"$work/pylon_format.json"
expect_refused pylon_optional '{}' "$work/pylon_format.json" \
  "$work/pylon_format.json: fromat: unknown key (did you mean format?)"

# Clearance (docs/clearance.md): a geometry file that does not exist, and a threshold that is
# not a number, refused by name before anything is received.
expect_refused clearance_missing \
  "{\"clearance\": {\"geometry\": \"$work/no_such_geometry.json\", \"alarm_threshold_m\": 0.3}}" \
  "$pylon" "clearance.geometry '$work/no_such_geometry.json'"
expect_refused clearance_threshold \
  '{"clearance": {"geometry": "g.json", "alarm_threshold_m": "low"}}' "$pylon" \
  "$work/clearance_threshold.json: clearance.alarm_threshold_m: expected a number"

# The same files without a typo: past the configuration, the program stops only for want of an
# input (no --udp-port, no --can): its own message, not a configuration refusal.
printf '{"aligner": {"max_wait_ms": 10}, "udp": {"port": 0}}\n' >"$work/good.json"
rc=0
timeout 20 "$host" --config "$work/good.json" --calibration "$rig" --pylon-survey "$pylon" \
  --store-survey "$store" --udp-port 0 --duration-s 0.1 2>"$work/good.err" >/dev/null || rc=$?
if ! grep -qF "no input: give --udp-port and/or --can" "$work/good.err"; then
  echo "FAIL good: exit $rc, stderr:" >&2
  cat "$work/good.err" >&2
  failures=$((failures + 1))
else
  echo "ok   good: read, then: $(head -1 "$work/good.err")"
fi
[ "$failures" -eq 0 ] || { echo "$failures failure(s)" >&2; exit 1; }
