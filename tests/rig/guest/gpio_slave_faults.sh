# GPIO trigger faults, slave mode, on real gpio-sim lines (issue 12, "Trigger"): storetrack-unit
# waits for rising edges on a gpio-sim line (found by its label) driven from outside at ~10 Hz
# through the simulator's pull attribute; the chip is taken away (configfs live=0) for 1.5 s and
# brought back. The unit must notice the dead line, count it, request the line again once the
# chip is back, and time-stamp the pulses that follow; it must not exit or wait for ever on the
# dead line.
. "$(dirname "$0")/lib.sh"
need_bin UNIT STORETRACK_BIN_UNIT storetrack-unit
gpiosim_new slavefaults 1 st-slave-faults
g=$GS_CFG
pin() { echo "/sys/devices/platform/$(cat "$g/dev_name")/$(cat "$g/bank0/chip_name")/sim_gpio0/pull"; }
# pulses SECONDS FILE: rising edges through the pull attribute (at most 10 Hz; a shell under TCG
# manages a few per second), one line per pulse appended to FILE
pulses() {
  p=$(pin); end=$(($(date +%s) + $1))
  while [ "$(date +%s)" -lt "$end" ]; do
    echo pull-up > "$p"; sleep 0.02; echo pull-down > "$p"; echo x >> "$2"; sleep 0.08
  done
}
"$UNIT" run --source none --trigger gpio-slave --gpio-chip st-slave-faults --gpio-line 0 \
  --rate-hz 10 --duration-s 10 --no-links --no-modbus --edges-csv $T/edges.csv \
  --stats-json $T/unit.json > $T/unit.out 2>&1 & UNITP=$!
waitfor "gpioinfo $(cat $g/bank0/chip_name) 2>/dev/null | grep -q storetrack-unit" 400 ||
  fail "unit did not request line 0"
pulses 2 $T/sent_before
echo 0 > "$g/live" || fail "gpio-sim: live=0 refused"
sleep 1.5
echo 1 > "$g/live" || fail "gpio-sim: live=1 refused"
# The unit requests the line again at its next once-a-second retry.
waitfor "gpioinfo $(cat $g/bank0/chip_name) 2>/dev/null | grep -q storetrack-unit" 100 ||
  fail "line not requested again within 5 s of the chip's return"
pulses 2 $T/sent_after
wait $UNITP; rc=$?
tail -4 $T/unit.out
[ $rc = 0 ] || fail "storetrack-unit exit $rc (it must survive the GPIO chip going away)"
before=$(wc -l < $T/sent_before); after=$(wc -l < $T/sent_after)
python3 - "$T/unit.json" "$T/edges.csv" "$before" "$after" <<'PY' || fail "unit trigger counters"
import csv, json, sys
j = json.load(open(sys.argv[1]))
t = j["trigger_line"]
print("unit trigger_line:", t)
rows = list(csv.DictReader(open(sys.argv[2])))
ts = [int(r["t_mono_ns"]) for r in rows]
gap = max((b - a for a, b in zip(ts, ts[1:])), default=0)
i = max(range(1, len(ts)), key=lambda k: ts[k] - ts[k - 1]) if len(ts) > 1 else 0
sent_before, sent_after = int(sys.argv[3]), int(sys.argv[4])
print(f"{len(rows)} edges: {i} before the largest gap ({gap / 1e9:.2f} s) of {sent_before} pulses "
      f"sent, {len(rows) - i} after of {sent_after} sent once the line was requested again")
err = []
if t["line_errors"] < 1: err.append("the dead line was never noticed (no line error)")
if t["reopens"] < 1: err.append("the line was never requested again")
if t["errors_reported"] != t["line_errors"]: err.append(f"{t['errors_reported']} reported of {t['line_errors']}")
# Every pulse time-stamped while the line was up (the last one before the outage may fall in it).
if not sent_before - 1 <= i <= sent_before: err.append(f"{i} edges before the outage of {sent_before} sent")
if not max(1, sent_after - 1) <= len(rows) - i <= sent_after:
    err.append(f"{len(rows) - i} edges after the line came back, of {sent_after} sent")
for e in err: print("FAIL: " + e)
sys.exit(1 if err else 0)
PY
echo "gpio slave faults OK"
