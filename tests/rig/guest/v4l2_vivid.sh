# V4L2 with vivid as the camera: a simulator-rendered frame (storetrack-sim, 1920x1024 GREY) is
# written into vivid's HDMI output; vivid loops it to its HDMI capture input (1920x1080 GREY,
# byte-identical); storetrack-unit captures it through the real V4L2 path, centroids it, and its
# marks must match the simulator's truth (truth_marks.csv) within the centroiding tolerance.
. "$(dirname "$0")/lib.sh"
need_bin UNIT STORETRACK_BIN_UNIT storetrack-unit
need_bin SIM STORETRACK_BIN_SIM storetrack-sim
"$SIM" --scenario static --cameras 2 --seed 3 --mode frames --exposures 1 --out $T/sim > $T/sim.out 2>&1 ||
  { cat $T/sim.out; fail "storetrack-sim"; }
PGM=$(ls $T/sim/frames/cam*/frame_000000.pgm | head -1)
CAM=$(basename "$(dirname "$PGM")"); CAM=${CAM#cam}
# PGM (P5, 8-bit) -> one raw 1920x1080 GREY frame, rows 1024..1079 black
python3 - "$PGM" $T/frame.grey <<'PY' || fail "PGM conversion"
import sys
data = open(sys.argv[1], "rb").read()
fields, pos = [], 0
while len(fields) < 4:  # magic, width, height, maxval (no comments in our PGMs)
    while data[pos:pos + 1].isspace(): pos += 1
    start = pos
    while not data[pos:pos + 1].isspace(): pos += 1
    fields.append(data[start:pos])
w, h = int(fields[1]), int(fields[2])
assert fields[0] == b"P5" and int(fields[3]) == 255 and w == 1920 and h <= 1080, fields
pix = data[pos + 1:pos + 1 + w * h]
open(sys.argv[2], "wb").write(pix + bytes(w * (1080 - h)))
print(f"frame {w}x{h} -> 1920x1080 GREY")
PY
modprobe vivid n_devs=1 node_types=0x101 || fail "modprobe vivid"
C=/dev/video0; O=/dev/video1
v4l2-ctl -d $C -i 3 >/dev/null && v4l2-ctl -d $O -o 1 >/dev/null || fail "vivid HDMI in/out"
v4l2-ctl -d $C --list-dv-timings > $T/dv.txt
idx=$(awk '/Index/{i=$NF; w=0} /Active width: 1920$/{w=1} /Active height: 1080$/{if(w){print i; exit}}' $T/dv.txt | tr -d :)
[ -n "$idx" ] || { head -20 $T/dv.txt; fail "no 1920x1080 DV timing in vivid"; }
v4l2-ctl -d $C --set-dv-bt-timings index=$idx >/dev/null && v4l2-ctl -d $O --set-dv-bt-timings index=$idx >/dev/null ||
  fail "DV timings"
v4l2-ctl -d $O --set-fmt-video-out width=1920,height=1080,pixelformat=GREY || fail "output GREY"
v4l2-ctl -d $C --set-fmt-video width=1920,height=1080,pixelformat=GREY || fail "capture GREY"
v4l2-ctl -d $C -c loop_video=1,osd_text_mode=2 || fail "vivid loop_video"
v4l2-ctl -d $O --get-fmt-video-out | grep -E 'Width|Pixel'
v4l2-ctl -d $O --stream-out-mmap 3 --stream-from $T/frame.grey --stream-loop 2>/dev/null & OUTP=$!
sleep 1
# the rig itself: the frame must come back byte-identical, else the comparison below means nothing
timeout 30 v4l2-ctl -d $C --stream-mmap 3 --stream-skip 3 --stream-count 1 --stream-to $T/back.grey 2>/dev/null
cmp $T/frame.grey $T/back.grey || fail "vivid GREY loopback is not byte-identical"
# the unit: real V4L2 capture (VIDIOC_S_INPUT 3, GREY 1920x1080), centroiding, mark table
timeout 60 "$UNIT" snapshot --source v4l2 --device $C --input 3 --width 1920 --height 1080 \
  --skip 3 -o $T/snap > $T/snap.out 2>&1; rc=$?
kill $OUTP; wait $OUTP 2>/dev/null
cat $T/snap.out | head -40
[ $rc = 0 ] || fail "storetrack-unit snapshot exit $rc"
python3 "$RIG_GUEST/check_marks.py" --table $T/snap.out --truth $T/sim/truth_marks.csv --camera "$CAM" ||
  fail "unit marks vs simulator truth"
