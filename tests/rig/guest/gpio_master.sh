# GPIO trigger, master mode: storetrack-unit drives trigger line 0 of a gpio-sim chip at 5 Hz;
# the test samples the simulated pin (sim_gpio0/value) independently and checks the pulse count
# against the unit's own report, the rate, and that every edge the unit logged is on the pin.
. "$(dirname "$0")/lib.sh"
need_bin UNIT STORETRACK_BIN_UNIT storetrack-unit
gpiosim_new master 2
python3 "$RIG_GUEST/gpio_edges.py" poll $GS_SYS/sim_gpio0/value 60 > $T/poll & POLL=$!
waitfor "[ -s $T/poll ]" 400 || fail "poller did not start"
"$UNIT" run --source none --trigger gpio-master --gpio-chip "$GS_CHIP" --gpio-lines 0 \
  --rate-hz 5 --pulse-width-us 60000 --frames 20 --duration-s 30 --no-links --no-modbus \
  --edges-csv $T/edges.csv --stats-json $T/unit.json > $T/unit.out 2>&1
rc=$?
sleep 0.3; kill $POLL; wait $POLL 2>/dev/null
tail -3 $T/unit.out
[ $rc = 0 ] || fail "storetrack-unit exit $rc"
python3 - "$T/unit.json" <<'PY' || fail "unit report"
import json, sys
j = json.load(open(sys.argv[1]))
t = j["trigger_line"]
print("unit trigger_line:", t)
sys.exit(0 if j["trigger_mode"] == "gpio-master" and t["edges"] >= 20 else 1)
PY
n=$(python3 -c "import json; print(json.load(open('$T/unit.json'))['trigger_line']['edges'])")
late=$(python3 -c "import json; print(json.load(open('$T/unit.json'))['trigger_line']['max_late_ns'])")
# The pin is sampled by a poller (an output line cannot also be monitored for events): slow
# pulses (5 Hz, 60 ms) so a TCG vCPU on a loaded host still sees every one.
python3 "$RIG_GUEST/gpio_edges.py" check --edges $T/poll --format poll --rate 5 \
  --expect-count "$n" --rate-tol 0.05 --source-late-ns "$late" || fail "pin edges vs the unit's report ($n pulses)"
# every pulse the unit logged is on the pin, within the poller's resolution under TCG
python3 - "$T/edges.csv" "$T/poll" <<'PY' || fail "unit edge times vs pin"
import csv, sys
unit = [int(r["t_mono_ns"]) for r in csv.DictReader(open(sys.argv[1]))]
lines = [l.split() for l in open(sys.argv[2]) if l.strip()]
pin = [int(t) for i, (t, v) in enumerate(lines) if i > 0 and v == "1"]
worst = max(min(abs(p - u) for p in pin) for u in unit)
print(f"{len(unit)} unit edges, worst distance to a pin edge {worst / 1e6:.2f} ms")
sys.exit(0 if worst < 40e6 else 1)
PY
echo "gpio master OK"
