# Modbus TCP health server of storetrack-unit with a real peer client (mbpoll, Debian): reads the
# health input registers, is refused a write outside maintenance mode (exception 0x04), and the
# same write is accepted by a unit started with --maintenance. Runs in the VM and on loopback.
. "$(dirname "$0")/lib.sh"
need_bin UNIT STORETRACK_BIN_UNIT storetrack-unit
command -v mbpoll >/dev/null || fail "mbpoll missing (tools/install-deps.sh)"
PORT=${MODBUS_PORT:-15020}
# The static scenario has 100 exposures (0.25 s at 400 fps): a unit rendering them fast enough
# ended before the second read (seen on a quiet machine). 20 000 keep it running until
# --duration-s whatever the machine's speed.
python3 - "$STORETRACK_SOURCE_DIR/common/sim/scenarios/static.json" $T/scenario.json <<'PY' ||
import json, sys
s = json.load(open(sys.argv[1]))
s["timing"]["num_exposures"] = 20000
json.dump(s, open(sys.argv[2], "w"))
PY
  fail "scenario copy"
run_unit() {  # $1 = extra flag, $2 = stats file
  "$UNIT" run --source sim --scenario $T/scenario.json \
    --realtime --trigger sim --no-links --modbus 127.0.0.1:$PORT \
    --duration-s 25 $1 --stats-json "$2" > "$2.out" 2>&1 &
  UNITP=$!
  waitfor "kill -0 $UNITP 2>/dev/null || exit 0; mbpoll -m tcp -t 3 -0 -r 0 -c 2 -1 -p $PORT 127.0.0.1 >/dev/null 2>&1" 200 ||
    { cat "$2.out"; fail "unit's Modbus server did not answer on 127.0.0.1:$PORT"; }
  kill -0 $UNITP 2>/dev/null || { cat "$2.out"; fail "storetrack-unit exited at start"; }
}
stop_unit() { kill -INT $UNITP; wait $UNITP; }

run_unit "" $T/locked.json
mbpoll -m tcp -t 3 -0 -r 0 -c 8 -1 -p $PORT 127.0.0.1 > $T/read1 2>&1 || fail "input register read"
sleep 1.5
mbpoll -m tcp -t 3 -0 -r 0 -c 8 -1 -p $PORT 127.0.0.1 > $T/read2 2>&1 || fail "input register read"
cat $T/read2
# uptime_s (registers 0-1, u32 high word first) must advance between the reads
reg() { sed -n "s/^\[$2\]:[[:space:]]*\([0-9-]*\).*/\1/p" "$1"; }
up() { hi=$(reg "$1" 0); lo=$(reg "$1" 1); [ -n "$hi" ] && [ -n "$lo" ] && echo $((hi * 65536 + lo)); }
u1=$(up $T/read1); u2=$(up $T/read2)
echo "uptime_s $u1 -> $u2"
[ -n "$u1" ] && [ -n "$u2" ] && [ "$u2" -gt "$u1" ] || fail "uptime_s did not advance ($u1 -> $u2)"
# holding register 2 = exposure_us (docs/modbus.md): refused while not in maintenance
if mbpoll -m tcp -t 4 -0 -r 2 -1 -p $PORT 127.0.0.1 1500 > $T/write 2>&1; then
  cat $T/write; fail "write accepted outside maintenance mode"
fi
cat $T/write
stop_unit
python3 - $T/locked.json <<'PY' || fail "refused write not counted"
import json, sys
m = json.load(open(sys.argv[1]))["modbus"]; print("modbus:", m)
sys.exit(0 if m["refused_write_locked"] >= 1 and m["writes_accepted"] == 0 else 1)
PY
echo "-- same write with --maintenance"
run_unit --maintenance $T/maint.json
mbpoll -m tcp -t 4 -0 -r 2 -1 -p $PORT 127.0.0.1 1500 > $T/write2 2>&1 || { cat $T/write2; fail "write refused in maintenance mode"; }
mbpoll -m tcp -t 4 -0 -r 2 -c 1 -1 -p $PORT 127.0.0.1 > $T/readback 2>&1 || fail "holding read"
grep -q '^\[2\]:[[:space:]]*1500' $T/readback || { cat $T/readback; fail "exposure_us read back != 1500"; }
stop_unit
python3 - $T/maint.json <<'PY' || fail "accepted write not counted"
import json, sys
m = json.load(open(sys.argv[1]))["modbus"]; print("modbus:", m)
sys.exit(0 if m["writes_accepted"] >= 1 else 1)
PY
echo "modbus OK"
