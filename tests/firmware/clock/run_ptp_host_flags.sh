#!/usr/bin/env bash
# End to end: does the host flag the samples of a unit that lost PTP? A real ptp4l master and
# slave in two network namespaces over a veth pair (software time stamping, free_running 1: the
# machine's clock is never adjusted), four storetrack-unit processes (the static scenario's four
# cameras, paced at 5 exposures/s: rendering four cameras' frames on two cores manages ~10) reading their clock state from the slave ptp4l
# (--clock-state ptp4l, measure-only: free_running keeps ptp4l's port UNCALIBRATED), and
# storetrack-host writing its CSV. 6 s after the units start, the master is SIGKILLed.
# Checked, in the CSV's trigger order: samples are flagged clock_not_locked (FTI status bit 3)
# until every unit is LOCKED, then not flagged, then flagged again from the master's death to the
# end (HOLDOVER, then FREE_RUNNING once the 3 s holdover is over): the pattern F* U+ F+, with
# enough samples in each part; and the units' stats end FREE_RUNNING with the transitions seen,
# stating a time uncertainty grown since the master died (1 ppm drift bound).
# Needs root and ptp4l: exits 77 (skipped) otherwise.
set -euo pipefail
SIM="$1"; UNIT="$2"; HOST="$3"; ROOT="$4"; OUT="$5"; PTP4L="$6"
[ -x "$PTP4L" ] || { echo "SKIP: ptp4l not installed (apt-get install linuxptp)"; exit 77; }
[ "$(id -u)" -eq 0 ] || { echo "SKIP: needs root for network namespaces"; exit 77; }
TAG=$$
NSM="stclkm-$TAG" NSS="stclks-$TAG" VM="sem$TAG" VS="ses$TAG"
ip netns add "$NSM" 2>/dev/null || { echo "SKIP: cannot create a network namespace"; exit 77; }
# The UNIX sockets live in a short directory of their own: a socket path may have 107 bytes, and
# the build tree of a deep checkout alone can take more (the test must not depend on where the
# checkout lies).
SOCK=$(mktemp -d /tmp/stclk.XXXXXX)
PIDS=""
cleanup() {
  for p in $PIDS; do kill -9 "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  ip netns del "$NSM" 2>/dev/null || true
  ip netns del "$NSS" 2>/dev/null || true
  rm -rf "$SOCK"
}
trap cleanup EXIT
rm -rf "$OUT"; mkdir -p "$OUT/sim"

ip netns add "$NSS"
ip link add "$VM" address 02:00:00:00:01:01 type veth peer name "$VS" address 02:00:00:00:01:02
ip link set "$VM" netns "$NSM"; ip link set "$VS" netns "$NSS"
ip -n "$NSM" addr add 10.232.0.1/24 dev "$VM"; ip -n "$NSS" addr add 10.232.0.2/24 dev "$VS"
ip -n "$NSM" link set "$VM" up; ip -n "$NSS" link set "$VS" up
for role in master slave; do
  {
    echo "[global]"
    echo "free_running 1"; echo "time_stamping software"
    echo "logAnnounceInterval -2"; echo "announceReceiptTimeout 2"
    echo "logSyncInterval -3"; echo "logMinDelayReqInterval -3"
    echo "uds_address $SOCK/$role.uds"
    [ "$role" = master ] && echo "priority1 10" || echo "slaveOnly 1"
  } >"$OUT/$role.cfg"
done

NEXP=70 RATE=5  # 14 s
/usr/bin/python3 - "$ROOT/common/sim/scenarios/static.json" "$OUT/scenario.json" "$NEXP" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
s["timing"]["num_exposures"] = int(sys.argv[3])
json.dump(s, open(sys.argv[2], "w"))
PY
"$SIM" --scenario "$OUT/scenario.json" --seed 3 --out "$OUT/sim" --mode observations >/dev/null
/usr/bin/python3 "$ROOT/tools/sim_setup.py" --initial-marks "$OUT/sim/truth_marks.csv" \
  "$OUT/initial_marks.json" 0
cat >"$OUT/unit.json" <<JSON
{"health": {"period_ms": 250},
 "ptp4l": {"uds_path": "$SOCK/slave.uds", "client_dir": "$SOCK", "reply_timeout_ms": 50,
           "lock_threshold_ns": 500000, "lock_polls": 3, "holdover_s": 3, "measure_only": true,
           "holdover_drift_ppb": 1000}}
JSON

ip netns exec "$NSM" "$PTP4L" -f "$OUT/master.cfg" -i "$VM" -m >"$OUT/master.log" 2>&1 &
MASTER=$!; PIDS="$PIDS $MASTER"
ip netns exec "$NSS" "$PTP4L" -f "$OUT/slave.cfg" -i "$VS" -m >"$OUT/slave.log" 2>&1 &
PIDS="$PIDS $!"
PORT=$(( 25000 + TAG % 1000 ))
# The units are paced at RATE (200 ms per exposure) and, rendering whole frames on a loaded
# machine, drift up to ~75 ms apart (seen in CI: each "real time kept, at most 55-74 ms behind");
# the production 10 ms wait would then time out nearly every exposure as partial (1 valid of 70).
# The wait spans that skew and stays under the exposure period.
"$HOST" --calibration "$OUT/sim/rig_calibrated.json" --pylon-survey "$OUT/sim/survey_pylon.json" \
  --store-survey "$OUT/sim/survey_store.json" --initial-marks "$OUT/initial_marks.json" \
  --udp-port "$PORT" --udp-bind 127.0.0.1 --max-wait-ms 150 --csv "$OUT/samples.csv" \
  --stats-json "$OUT/host_stats.json" --idle-exit-s 3 >"$OUT/host.log" 2>&1 &
HOST_PID=$!; PIDS="$PIDS $HOST_PID"
sleep 0.5
UNITS=""
for c in 0 1 2 3; do
  "$UNIT" run --config "$OUT/unit.json" --source sim --scenario "$OUT/scenario.json" \
    --camera-index "$c" --seed 3 --trigger sim --udp "127.0.0.1:$PORT" --no-modbus \
    --realtime --sim-pace-hz "$RATE" --clock-state ptp4l --stats-json "$OUT/unit$c.json" \
    >"$OUT/unit$c.log" 2>&1 &
  UNITS="$UNITS $!"
done
PIDS="$PIDS $UNITS"
sleep 6
{ kill -9 "$MASTER"; wait "$MASTER"; } 2>/dev/null || true
echo "master ptp4l killed 6 s after the units started"
for p in $UNITS; do wait "$p" || { cat "$OUT"/unit*.log; echo "FAIL storetrack-unit"; exit 1; }; done
wait "$HOST_PID" || { cat "$OUT/host.log"; echo "FAIL storetrack-host"; exit 1; }

/usr/bin/python3 - "$OUT" "$RATE" <<'PY'
import csv, json, re, sys
out, rate = sys.argv[1], int(sys.argv[2])
rows = list(csv.DictReader(open(out + "/samples.csv")))
rows.sort(key=lambda r: int(r["trigger_seq [1]"]))
flags = "".join("F" if int(r["status [bitfield]"]) & 8 else "U" for r in rows)
runs = [(m.group(0)[0], len(m.group(0))) for m in re.finditer(r"F+|U+", flags)]
print("samples %d; clock_not_locked runs in trigger order: %s" % (len(rows), runs))
failures = []
def check(cond, what):
    print(("ok   " if cond else "FAIL ") + what)
    if not cond:
        failures.append(what)
check(re.fullmatch(r"F*U+F+", flags) is not None, "flags follow F* U+ F+ (not locked, locked, lost)")
locked = max((n for k, n in runs if k == "U"), default=0)
lost = runs[-1][1] if runs and runs[-1][0] == "F" else 0
# Locked from ~1.8 s to the kill at 6 s (+0.5-0.75 s until ptp4l notices): >= 2 s of samples
# even on a loaded machine.
check(locked >= 2 * rate, "%d unflagged samples >= %d (2 s)" % (locked, 2 * rate))
# From ~6.7 s to the end at 14 s: >= 3 s of flagged samples.
check(lost >= 3 * rate, "%d flagged samples after the loss >= %d (3 s)" % (lost, 3 * rate))
for c in range(4):
    clock = json.load(open("%s/unit%d.json" % (out, c)))["clock"]
    p = clock["ptp4l"]
    check(clock["state"] == 0 and clock["ptp_offset_ns"] == -2**31,
          "unit %d ends FREE_RUNNING with the offset unknown (%d, %d)"
          % (c, clock["state"], clock["ptp_offset_ns"]))
    # The stated time uncertainty grew from the last measurement (just before the kill at 6 s)
    # at 1 us/s to the units' end at 14 s: >= 6 us with 2 s margin for a late start.
    check(clock["exposure_time_sigma_ns_now"] >= 6000 and p["new_offsets"] >= 3,
          "unit %d states %d ns at the end (%d offsets measured, RMS %.0f ns while locked)"
          % (c, clock["exposure_time_sigma_ns_now"], p["new_offsets"], p["offset_rms_ns"]))
    # FREE_RUNNING -> LOCKING -> LOCKED -> HOLDOVER -> FREE_RUNNING: at least 4 transitions.
    check(p["transitions"] >= 4 and p["malformed"] == 0,
          "unit %d: %d transitions, %d polls, port %s" % (c, p["transitions"], p["polls"], p["port_state"]))
health = json.load(open(out + "/host_stats.json")).get("unit_health", {})
print("host's last UnitHealth per unit:", {k: v.get("clock_state") for k, v in health.items()})
sys.exit(1 if failures else 0)
PY
