# A trigger change over Modbus that cannot start, on real gpio-sim lines (issue 12, "Modbus"):
# storetrack-unit is the 10 Hz trigger master (maintenance mode); its GPIO chip is taken away
# (configfs live=0) and a client writes trigger_rate_hz = 20. The new generator cannot start and
# neither can the previous one: the change is counted as not applied, the restart failure is
# counted, and the unit tries the previous trigger again once a second; when the chip is back the
# rig's trigger runs again at the old 10 Hz. (Before: the generator stayed stopped for the rest
# of the run, with nothing but a counter to say so.) Written again with the chip back, the change
# applies, and the exposures' numbering goes on across it (before: it restarted at 0).
. "$(dirname "$0")/lib.sh"
need_bin UNIT STORETRACK_BIN_UNIT storetrack-unit
command -v mbpoll >/dev/null || fail "mbpoll missing (tools/install-deps.sh)"
PORT=15021
gpiosim_new restart 1 st-trigger-restart
g=$GS_CFG
requested="gpioinfo \$(cat $g/bank0/chip_name) 2>/dev/null | grep -q storetrack-unit"
"$UNIT" run --source none --trigger gpio-master --gpio-chip st-trigger-restart --gpio-lines 0 \
  --rate-hz 10 --pulse-width-us 20000 --duration-s 11 --no-links --modbus 127.0.0.1:$PORT \
  --maintenance --edges-csv $T/edges.csv --stats-json $T/unit.json > $T/unit.out 2>&1 & UNITP=$!
waitfor "$requested" 400 || fail "unit did not request line 0"
sleep 1.5
echo 0 > "$g/live" || fail "gpio-sim: live=0 refused"
# holding register 3 = trigger_rate_hz (docs/modbus.md)
mbpoll -m tcp -t 4 -0 -r 3 -1 -p $PORT 127.0.0.1 20 > $T/write 2>&1 || { cat $T/write; fail "rate write refused"; }
sleep 1.5
echo 1 > "$g/live" || fail "gpio-sim: live=1 refused"
t_back=$(date +%s%N)
waitfor "$requested" 100 || fail "the trigger was not started again within 5 s of the chip's return"
echo "trigger running again $(( ($(date +%s%N) - t_back) / 1000000 )) ms after the chip came back"
# With the chip there, the same change applies: 20 Hz from then on, the numbering going on.
sleep 1.5
mbpoll -m tcp -t 4 -0 -r 3 -1 -p $PORT 127.0.0.1 20 > $T/write2 2>&1 || { cat $T/write2; fail "second rate write refused"; }
wait $UNITP; rc=$?
tail -5 $T/unit.out
[ $rc = 0 ] || fail "storetrack-unit exit $rc"
# The width register holds at most 5000 us: a rate write must keep the configured 20 ms width
# (before: it was clamped to 5 ms along with the rate change).
grep -q "trigger 20 Hz / 20000000 ns not started" $T/unit.out || fail "the rate change did not keep the 20 ms width"
python3 - "$T/unit.json" "$T/edges.csv" <<'PY' || fail "unit restart counters / rate"
import csv, json, statistics, sys
j = json.load(open(sys.argv[1]))
print({k: j[k] for k in ("config_apply_errors", "trigger_restart_failures", "trigger_restarts")})
rows = list(csv.DictReader(open(sys.argv[2])))
# An edge the pairer calls extra gets no sequence number: its -1 is a marker, not a number.
# The master drives no pulse off its grid (a late one is skipped as an overrun), so extras come
# only from a stamp delayed inside the set-value call; they are counted, not numbered.
extra = sum(r["verdict"] == "extra" for r in rows)
rows = [r for r in rows if r["verdict"] != "extra"]
line = j["trigger_line"]
print(f"{extra} extra edges; generator overruns {line['overruns']}, worst wake-up {line['max_late_ns'] / 1e6:.1f} ms")
t = [int(r["t_mono_ns"]) for r in rows]
seq = [int(r["trigger_seq"]) for r in rows]
gaps = [b - a for a, b in zip(t, t[1:])]
i = max(range(len(gaps)), key=lambda k: gaps[k])
resumed, last = gaps[i + 1:i + 6], gaps[-10:]
print(f"{len(t)} edges; outage {gaps[i] / 1e9:.2f} s; median interval of the 5 after it "
      f"{statistics.median(resumed) / 1e6:.1f} ms, of the last 10 {statistics.median(last) / 1e6:.1f} ms; "
      f"trigger_seq {seq[0]}..{seq[-1]}")
err = []
if j["config_apply_errors"] != 1: err.append(f"{j['config_apply_errors']} changes not applied, expected 1")
if j["trigger_restart_failures"] != 1: err.append(f"{j['trigger_restart_failures']} restart failures, expected 1")
if j["trigger_restarts"] != 1: err.append(f"{j['trigger_restarts']} restarts, expected 1")
if len(resumed) < 5 or not 90e6 <= statistics.median(resumed) <= 110e6:
    err.append("the trigger after the outage is not the old 10 Hz")
if not 45e6 <= statistics.median(last) <= 55e6: err.append("the applied change is not 20 Hz")
# Across the outage and the applied rate change the numbering only goes forwards (before: the
# applied change restarted it at 0, numbers this unit's earlier exposures already had).
back = [(a, b) for a, b in zip(seq, seq[1:]) if b <= a]
if extra != j["pairing"]["edges_extra"]:
    err.append(f"{extra} extra edges in the CSV, the pairer counted {j['pairing']['edges_extra']}")
if back: err.append(f"trigger_seq went back {len(back)} times, first {back[0][0]} -> {back[0][1]}")
for e in err: print("FAIL: " + e)
sys.exit(1 if err else 0)
PY
echo "gpio master restart OK"
