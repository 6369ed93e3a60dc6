# storetrack-trigger-emu on gpio-sim: (1) sim-pull backend drives line 0 from outside with
# missing/double/burst faults, gpiomon (libgpiod) timestamps the edges, and the edges must match
# the emulator's log, rate and faults; (2) gpiod backend requests line 1 as an output and the
# pulses appear on the simulated pin's value.
. "$(dirname "$0")/lib.sh"
need_bin EMU STORETRACK_BIN_TRIGGER_EMU storetrack-trigger-emu
gpiosim_new emu 2
echo "-- sim-pull backend: 24 nominal at 20 Hz, missing 5, double 10, burst 15 (x2)"
# sent = 24 - 1 + 1 + 2 = 26 rising edges
timeout 60 gpiomon -b -n 52 -F '%e %s %n' "$GS_CHIP" 0 > $T/mon & P=$!
waitfor "gpioinfo $GS_CHIP | grep -q gpiomon" || fail "gpiomon did not request line 0"
"$EMU" --chip "$GS_CHIP" --backend sim-pull --lines 0 --rate-hz 20 --width-us 5000 --count 24 \
  --missing 5 --double 10 --double-gap-us 20000 --burst 15 --burst-count 2 --burst-gap-us 15000 \
  --log $T/emu.csv || fail "trigger-emu (sim-pull) exit $?"
wait $P || fail "gpiomon did not see 52 edges: $(wc -l < $T/mon) lines"
python3 "$RIG_GUEST/gpio_edges.py" check --edges $T/mon --format gpiomon --rate 20 \
  --expect-count 26 --expect-missing 1 --expect-extra 3 --log $T/emu.csv --rate-tol 0.05 \
  --tol-ms 60 || fail "edges vs log"
echo "-- gpiod backend: line 1 as output, 5 pulses at 4 Hz, 60 ms wide"
python3 "$RIG_GUEST/gpio_edges.py" poll $GS_SYS/sim_gpio1/value 3 > $T/poll & P=$!
waitfor "[ -s $T/poll ]" || fail "poller did not start"   # python starts slowly under TCG
"$EMU" --chip "$GS_CHIP" --lines 1 --rate-hz 4 --width-us 60000 --count 5 --log $T/emu2.json ||
  fail "trigger-emu (gpiod) exit $?"
wait $P
python3 "$RIG_GUEST/gpio_edges.py" check --edges $T/poll --format poll --rate 4 --rate-tol 0.05 \
  --expect-count 5 || fail "gpiod output pulses"
python3 -c "import json,sys; j=json.load(open('$T/emu2.json')); \
  sys.exit(0 if j['clock']=='CLOCK_MONOTONIC' and len(j['pulses'])==5 else 1)" || fail "JSON log"
echo "trigger-emu OK"
