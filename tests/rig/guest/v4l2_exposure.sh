# Exposure written over Modbus to a real V4L2 control (issue 12, Modbus: "the exposure control's
# result is ignored"): storetrack-unit captures vivid's webcam input with its exposure control
# mapped to vivid's "brightness" (0..255, 1 us per step here: a stand-in with a range the
# driver enforces). A client writes exposure_us = 100: the driver must hold 100 afterwards (read
# back with v4l2-ctl, the truth). Then exposure_us = 1000: vivid clamps it to 255, as
# VIDIOC_S_CTRL allows a driver to; the unit must say so, count the change as not applied as
# asked, and show and use what the camera does (holding register 2 reads 255).
# (Before: the control's result was ignored, and the unit reported the 1000 us the camera did
# not use, in the register and in every observation's exposure time.)
. "$(dirname "$0")/lib.sh"
need_bin UNIT STORETRACK_BIN_UNIT storetrack-unit
command -v mbpoll >/dev/null || fail "mbpoll missing (tools/install-deps.sh)"
PORT=15023
modprobe vivid n_devs=1 node_types=0x1 || fail "modprobe vivid"
C=/dev/video0
v4l2-ctl -d $C -C brightness > /dev/null 2>&1 || fail "vivid has no brightness control"
cat > $T/unit.json.in <<EOF
{"source": {"type": "v4l2", "v4l2": {"device": "$C", "input": 0, "width": 640, "height": 360,
  "exposure_control": "brightness", "exposure_control_unit_us": 1}},
 "trigger": {"mode": "none"}, "modbus": {"address": "127.0.0.1", "port": $PORT}}
EOF
"$UNIT" run --config $T/unit.json.in --duration-s 8 --no-links --maintenance \
  --stats-json $T/unit.json > $T/unit.out 2>&1 & UNITP=$!
waitfor "mbpoll -m tcp -t 3 -0 -r 0 -c 2 -1 -p $PORT 127.0.0.1 >/dev/null 2>&1" 200 ||
  { cat $T/unit.out; fail "unit's Modbus server did not answer"; }
brightness() { v4l2-ctl -d $C -C brightness | sed -n 's/^brightness: *//p'; }
mbpoll -m tcp -t 4 -0 -r 2 -1 -p $PORT 127.0.0.1 100 > $T/w1 2>&1 || { cat $T/w1; fail "exposure_us 100 write refused"; }
waitfor "[ \"\$(v4l2-ctl -d $C -C brightness | sed -n 's/^brightness: *//p')\" = 100 ]" 100 ||
  fail "the driver's control is $(brightness), not 100, after exposure_us = 100"
mbpoll -m tcp -t 4 -0 -r 2 -1 -p $PORT 127.0.0.1 1000 > $T/w2 2>&1 || { cat $T/w2; fail "exposure_us 1000 write refused by Modbus"; }
sleep 1
b=$(brightness)
mbpoll -m tcp -t 4 -0 -r 2 -c 1 -1 -p $PORT 127.0.0.1 > $T/readback 2>&1 || fail "holding read"
reg=$(sed -n 's/^\[2\]:[[:space:]]*\([0-9]*\).*/\1/p' $T/readback)
wait $UNITP; rc=$?
tail -4 $T/unit.out
[ $rc = 0 ] || fail "storetrack-unit exit $rc"
echo "after exposure_us = 1000: driver brightness $b, holding register 2 = $reg"
[ "$b" = 255 ] || fail "vivid's brightness is $b after 1000, expected its clamp 255"
[ "$reg" = 255 ] || fail "holding register 2 reads $reg, not the 255 us the camera uses"
grep -q "exposure 1000 us clamped by the driver to 255 us" $T/unit.out || fail "the clamp was not reported"
python3 - "$T/unit.json" <<'PY' || fail "unit counters"
import json, sys
j = json.load(open(sys.argv[1]))
print("config_apply_errors", j["config_apply_errors"], "frames", j["frames_captured"])
sys.exit(0 if j["config_apply_errors"] == 1 and j["frames_captured"] > 0 else 1)
PY
echo "v4l2 exposure OK"
