# GPIO trigger faults on real gpio-sim lines (issue 12, "Trigger"): storetrack-unit is the
# trigger master on a gpio-sim chip, found by its label; the chip is taken away (configfs
# live=0: the GPIO device and every line handle on it vanish, as a GPIO expander does in a power
# dip or on a loose connector) for 1.5 s and brought back. The unit must keep running: the pulses
# it cannot drive are counted and reported (status bit trigger_error, stats), its lines are
# requested again once the chip is back, pulses reach the pin again, and every edge keeps its
# place on the 10 Hz grid (trigger_seq follows time across the outage: nothing renumbered).
# (Before: the first failed gpiod_line_set_value ended the generator thread, left the line high
# and the unit exited 5; nothing said why.)
. "$(dirname "$0")/lib.sh"
need_bin UNIT STORETRACK_BIN_UNIT storetrack-unit
gpiosim_new faults 2 st-trigger-faults
g=$GS_CFG
chip=$GS_CHIP
"$UNIT" run --source none --trigger gpio-master --gpio-chip st-trigger-faults --gpio-lines 0 \
  --rate-hz 10 --pulse-width-us 20000 --duration-s 9 --no-links --no-modbus \
  --edges-csv $T/edges.csv --stats-json $T/unit.json > $T/unit.out 2>&1 & UNITP=$!
waitfor "gpioinfo $chip 2>/dev/null | grep -q storetrack-unit" 400 || fail "unit did not request line 0"
sleep 2
echo 0 > "$g/live" || fail "gpio-sim: live=0 refused"
t_down=$(date +%s%N)
sleep 1.5
echo 1 > "$g/live" || fail "gpio-sim: live=1 refused"
chip=$(cat "$g/bank0/chip_name")
sysdir=/sys/devices/platform/$(cat "$g/dev_name")/$chip
# The unit requests the lines again at its next once-a-second retry; then pulses are on the pin.
waitfor "gpioinfo $chip 2>/dev/null | grep -q storetrack-unit" 100 || fail "lines not requested again within 5 s"
python3 "$RIG_GUEST/gpio_edges.py" poll "$sysdir/sim_gpio0/value" 1.5 > $T/poll_after
wait $UNITP; rc=$?
tail -4 $T/unit.out
[ $rc = 0 ] || fail "storetrack-unit exit $rc (it must survive the GPIO chip going away)"
python3 - "$T/unit.json" "$T/edges.csv" "$T/poll_after" <<'PY' || fail "unit trigger counters / grid"
import csv, json, sys
j = json.load(open(sys.argv[1]))
t = j["trigger_line"]
print("unit trigger_line:", t)
err = []
# 1.5 s down at 10 Hz, plus up to 1 s until the once-a-second retry finds the chip: 15-26 pulses.
if not 10 <= t["line_errors"] <= 30: err.append(f"{t['line_errors']} pulses not driven, expected 15-26")
if t["reopens"] < 1: err.append("lines never requested again")
if t["errors_reported"] != t["line_errors"]: err.append(f"{t['errors_reported']} reported of {t['line_errors']}")
rows = list(csv.DictReader(open(sys.argv[2])))
period = 100_000_000
t0, s0 = int(rows[0]["t_mono_ns"]), int(rows[0]["trigger_seq"])
off = [int(r["trigger_seq"]) - s0 - round((int(r["t_mono_ns"]) - t0) / period) for r in rows]
gaps = [int(b["trigger_seq"]) - int(a["trigger_seq"]) for a, b in zip(rows, rows[1:])]
print(f"{len(rows)} edges, largest sequence step {max(gaps)}, sequence - grid index in [{min(off)}, {max(off)}]")
# A pulse the generator itself set more than a quarter period late (a starved TCG vCPU on a
# loaded host) is off the grid in fact; the grid check is then reported, not asserted, as in
# gpio_master.sh.
if any(o != 0 for o in off):
    if t["max_late_ns"] > period / 4:
        print(f"NOTE: the unit set a pulse {t['max_late_ns'] / 1e6:.1f} ms late (loaded host): grid check reported only")
    else:
        err.append("an edge's trigger_seq is not its place on the grid")
if max(gaps) < 10: err.append("no outage seen in the edge sequence")
if len(rows) < 40: err.append(f"only {len(rows)} edges in 9 s")
pin = [l.split() for l in open(sys.argv[3]) if l.strip()]
rises = sum(1 for a, b in zip(pin, pin[1:]) if a[1] == "0" and b[1] == "1")
print(f"{rises} rising edges on the pin in 1.5 s after the chip came back")
# The poller under TCG misses short pulses on a loaded host (2 of ~15 seen once): one proves
# the line is driven again; the unit's own edges after the outage are counted above.
if rises < 1: err.append("no pulse on the pin after the chip came back")
for e in err: print("FAIL: " + e)
sys.exit(1 if err else 0)
PY
echo "gpio faults OK"
