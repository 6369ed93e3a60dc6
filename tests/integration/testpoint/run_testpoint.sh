#!/usr/bin/env bash
# A short store-separation test point (220 exposures, 4 cameras on 2 unit processes, UDP
# loopback, one unit drops 2 % of its messages), then check_testpoint.py compares the host's
# outputs with the simulator's truth and validates the Chapter 10 file.
set -euo pipefail
SIM="$1"; UNITS="$2"; HOST="$3"; ROOT="$4"; OUT="$5"
rm -rf "$OUT"; mkdir -p "$OUT/sim" "$OUT/setup"
PORT=$(( 45000 + $$ % 1000 ))
/usr/bin/python3 - "$ROOT/common/sim/scenarios/store_separation.json" "$OUT/scenario.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
s["timing"]["num_exposures"] = 220  # the scenario's 0.55 s of separation
json.dump(s, open(sys.argv[2], "w"))
PY
"$SIM" --scenario "$OUT/scenario.json" --seed 7 --out "$OUT/sim" --mode observations >/dev/null
"$UNITS" --scenario "$OUT/scenario.json" --seed 7 --write-setup "$OUT/setup"
"$HOST" --calibration "$OUT/setup/rig_calibration.json" --pylon-survey "$OUT/setup/pylon_survey.json" \
  --store-survey "$OUT/setup/store_survey.json" --initial-marks "$OUT/setup/initial_marks.json" \
  --udp-port "$PORT" --udp-bind 127.0.0.1 --ch10 "$OUT/out.ch10" --csv "$OUT/fti.csv" \
  --marks-csv "$OUT/marks.csv" --inetx "127.0.0.1:$((PORT + 1))" --stats-json "$OUT/stats.json" \
  --idle-exit-s 1.5 --expect-exposures 220 >"$OUT/host.log" 2>&1 &
HOST_PID=$!
trap 'kill $HOST_PID 2>/dev/null || true' EXIT
sleep 0.5
START=$(( $(date +%s%3N) + 500 ))
"$UNITS" --scenario "$OUT/scenario.json" --seed 7 --unit 0 --replay "$OUT/sim/observations.udp" \
  --dest "127.0.0.1:$PORT" --start-at-ms "$START" --quiet &
U0=$!
"$UNITS" --scenario "$OUT/scenario.json" --seed 7 --unit 1 --replay "$OUT/sim/observations.udp" \
  --dest "127.0.0.1:$PORT" --start-at-ms "$START" --loss 0.02 --quiet &
U1=$!
wait $U0; wait $U1
wait $HOST_PID || { cat "$OUT/host.log"; echo "storetrack-host failed"; exit 1; }
trap - EXIT
cat "$OUT/host.log"
/usr/bin/python3 "$(dirname "$0")/check_testpoint.py" "$ROOT" "$OUT"
