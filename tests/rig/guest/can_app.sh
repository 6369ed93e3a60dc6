# CAN FD, program level: storetrack-unit (simulated camera, centroided on the unit) sends its
# observations on vcan0 (CAN FD, mtu 72) and storetrack-host receives them over SocketCAN.
# candump sees the ICD's identifiers and lengths; injected malformed frames (cansend) are
# counted and dropped by the host; vcan0 going down mid-stream is survived and reported by both.
. "$(dirname "$0")/lib.sh"
need_bin UNIT STORETRACK_BIN_UNIT storetrack-unit
need_bin HOST STORETRACK_BIN_HOST storetrack-host
need_bin SIM STORETRACK_BIN_SIM storetrack-sim
SCEN=$STORETRACK_SOURCE_DIR/common/sim/scenarios/static.json
[ -e "$SCEN" ] || fail "no scenario $SCEN"
vcan_up vcan0
# The host's setup (calibrated rig, surveys, initial marks) from the simulator run with the same
# scenario and seed as the unit, extracted as tools/testpoint does. One exposure is enough: the
# calibration and survey draws do not depend on the exposure count (same files), and simulating
# all 100 would cost a minute under TCG.
"$SIM" --scenario "$SCEN" --seed 1 --exposures 1 --out $T/sim > $T/sim.out 2>&1 ||
  { cat $T/sim.out; fail "storetrack-sim"; }
python3 "$RIG_GUEST/../../../tools/sim_setup.py" "$SCEN" $T/sim $T/setup || fail "setup extraction (sim_setup.py)"
# The unit below runs as unit 1: the calibration must say so (the host drops observations whose
# unit id is not their camera's calibrated one, as spoofed).
python3 - $T/setup/rig_calibration.json <<'PY' || fail "calibration unit id"
import json, sys
rig = json.load(open(sys.argv[1]))
for c in rig["cameras"]:
    if c["camera_id"] == 0:
        c["unit_id"] = 1
json.dump(rig, open(sys.argv[1], "w"), indent=1)
PY

candump -L vcan0 > $T/candump.log & DUMP=$!
"$HOST" --calibration $T/setup/rig_calibration.json --pylon-survey $T/setup/pylon_survey.json \
  --store-survey $T/setup/store_survey.json --udp-port 0 --can vcan0 --min-cameras 1 \
  --idle-exit-s 8 --duration-s 150 --stats-json $T/host.json --log-level warn > $T/host.out 2>&1 &
HOSTP=$!
# both candump and the host have a receiver on vcan0 (python-free wait: TCG is slow)
waitfor "[ \$(grep -c vcan0 /proc/net/can/rcvlist_all) -ge 2 ]" 400 || echo "note: receivers not seen in rcvlist_all"
# Paced at 10 exposures/s, so the stream lasts ~10 s and spans the faults below (3-6.5 s) however
# fast the unit renders: at the scenario's 400 Hz the real-time source's background pool sends
# all 100 exposures in the first seconds, before the interface goes down.
"$UNIT" run --source sim --scenario "$SCEN" --camera-index 0 --seed 1 --trigger sim --can vcan0 \
  --no-modbus --unit-id 1 --camera-id 0 --duration-s 12 --realtime --sim-pace-hz 10 \
  --stats-json $T/unit.json \
  > $T/unit.out 2>&1 & UNITP=$!
# mid-stream: malformed frames, then the interface goes down and comes back
sleep 3
cansend vcan0 123#DEADBEEF                                   # classic CAN, 11-bit id
# unit 1 / camera 0 MarkObservations id (docs/icd.md; version 2 in bits 2..0), one-fragment
# transfer of garbage: bad CRC
cansend vcan0 08080802##0FFFF00.00.11.22.33.44.55.66.77.88.99.AA.BB.CC
sleep 2
ip link set vcan0 down; sleep 1.5; ip link set vcan0 up
wait $UNITP; urc=$?
wait $HOSTP; hrc=$?
kill $DUMP 2>/dev/null; wait $DUMP 2>/dev/null
echo "unit exit $urc, host exit $hrc"; tail -5 $T/unit.out; tail -5 $T/host.out
[ $urc = 0 ] || fail "storetrack-unit exit $urc after the interface went down"
[ $hrc = 0 ] || fail "storetrack-host exit $hrc"
python3 "$RIG_GUEST/check_can_app.py" --unit $T/unit.json --host $T/host.json \
  --candump $T/candump.log --unit-id 1 --camera-id 0 || fail "CAN FD checks"
