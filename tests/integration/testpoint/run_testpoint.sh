#!/usr/bin/env bash
# A short store-separation test point with the real camera-unit program: storetrack-sim writes
# the calibrated rig, surveys and truth; four storetrack-unit processes (one per camera, unit
# ids 0,0,1,1) render their camera's frames from the same scenario and seed, centroid them and
# send MarkObservations over UDP loopback; storetrack-host aligns, triangulates and writes
# Chapter 10 + iNET-X + CSV. Camera 3's unit stops 20 frames early (a camera that died), so the
# last exposures must come out partial after the bounded wait. The host evaluates the
# store-to-aircraft clearance with the scenario's checked-in geometry (docs/clearance.md, "In the
# main job") and records it. check_testpoint.py then compares the host's outputs with the
# simulator's truth (the clearance against the clearance at the true pose, evaluated by
# CLEARANCE_AT_POSES) and validates the Chapter 10 file.
set -euo pipefail
SIM="$1"; UNIT="$2"; HOST="$3"; ROOT="$4"; OUT="$5"; CLEARANCE_AT_POSES="$6"
NEXP=220
# The aligner's wait must exceed the host's backlog: under ASan/UBSan the host (the clearance
# under the pylon ~10x slower) falls ~4 s behind the units, so the sanitizer tree sets both longer
# (CMakeLists.txt); the idle exit stays above the wait so the dead camera's exposures time out.
MAX_WAIT_MS="${STORETRACK_TESTPOINT_MAX_WAIT_MS:-3000}"
IDLE_EXIT_S="${STORETRACK_TESTPOINT_IDLE_EXIT_S:-5}"
rm -rf "$OUT"; mkdir -p "$OUT/sim"
PORT=$(( 22000 + $$ % 1000 ))  # below the ephemeral ports (32768-60999)
/usr/bin/python3 - "$ROOT/common/sim/scenarios/store_separation.json" "$OUT/scenario.json" "$NEXP" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
s["timing"]["num_exposures"] = int(sys.argv[3])  # the scenario's 0.55 s of separation
json.dump(s, open(sys.argv[2], "w"))
PY
"$SIM" --scenario "$OUT/scenario.json" --seed 7 --out "$OUT/sim" --mode observations >/dev/null
# Initial mark positions as an installation survey would give them (exposure 0, 1 mm noise).
/usr/bin/python3 "$ROOT/tools/sim_setup.py" --initial-marks "$OUT/sim/truth_marks.csv" "$OUT/initial_marks.json"
STORE_SURVEY="$OUT/sim/survey_store.json"
GEOMETRY="$ROOT/common/sim/scenarios/store_separation_geometry/geometry.json"
printf '{"clearance": {"geometry": "%s", "alarm_threshold_m": 0.10}}\n' "$GEOMETRY" >"$OUT/host.json"
"$HOST" --calibration "$OUT/sim/rig_calibrated.json" --pylon-survey "$OUT/sim/survey_pylon.json" \
  --store-survey "$STORE_SURVEY" --initial-marks "$OUT/initial_marks.json" \
  --udp-port "$PORT" --udp-bind 127.0.0.1 --udp-source 0@127.0.0.1 --udp-source 1@127.0.0.1 --ch10 "$OUT/out.ch10" --csv "$OUT/fti.csv" \
  --marks-csv "$OUT/marks.csv" --inetx "127.0.0.1:$((PORT + 1))" --stats-json "$OUT/stats.json" \
  --config "$OUT/host.json" --max-wait-ms "$MAX_WAIT_MS" --idle-exit-s "$IDLE_EXIT_S" --expect-exposures "$NEXP" >"$OUT/host.log" 2>&1 &
HOST_PID=$!
UNIT_PIDS=""
trap 'for p in $HOST_PID $UNIT_PIDS; do kill "$p" 2>/dev/null || true; done' EXIT
# The units start once the host listens (its "waiting for observations" line comes after the UDP
# socket is bound): a datagram sent before is lost, and the raw channel is checked against what
# the units sent. A fixed 0.5 s raced the host's start on a loaded machine (11 datagrams lost).
for _ in $(seq 600); do
  grep -q "waiting for observations" "$OUT/host.log" && break
  kill -0 $HOST_PID 2>/dev/null || break
  sleep 0.1
done
grep -q "waiting for observations" "$OUT/host.log" ||
  { cat "$OUT/host.log"; echo "storetrack-host did not start listening within 60 s"; exit 1; }
for c in 0 1 2 3; do
  FRAMES=$NEXP; [ "$c" -eq 3 ] && FRAMES=$(( NEXP - 20 ))
  "$UNIT" run --source sim --scenario "$OUT/scenario.json" --camera-index "$c" --seed 7 \
    --trigger sim --udp "127.0.0.1:$PORT" --no-modbus --frames "$FRAMES" \
    --stats-json "$OUT/unit_cam$c.json" >"$OUT/unit_cam$c.log" 2>&1 &
  UNIT_PIDS="$UNIT_PIDS $!"
done
for p in $UNIT_PIDS; do wait "$p" || { cat "$OUT"/unit_cam*.log; echo "storetrack-unit failed"; exit 1; }; done
UNIT_PIDS=""
wait $HOST_PID || { cat "$OUT/host.log"; echo "storetrack-host failed"; exit 1; }
trap - EXIT
cat "$OUT/host.log"
/usr/bin/python3 "$(dirname "$0")/check_testpoint.py" "$ROOT" "$OUT" "$CLEARANCE_AT_POSES"
