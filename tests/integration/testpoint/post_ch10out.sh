#!/usr/bin/env bash
# storetrack-post --output-ch10 on the recording test_integration_testpoint made (issue 26): the
# reprocessed run as a new Chapter 10 recording. The truths: the live run (its samples, its CSV,
# its raw channel, its recorded inputs), the substitute file's own bytes and sha256sum, and the
# independent Chapter 10 reader (rig_ch10_dump, tests/rig; not built in the sanitizer tree, where
# its checks are left to the Release stage and said so). Checked:
# 1. recorded inputs: the new recording's samples reprocess to themselves bit for bit (--verify),
#    and are the live run's (same CSV); its raw channel is the source's record for record, its
#    inputs the source's; TMATS names the source file with its SHA-256 and no substitute;
# 2. a substituted calibration (camera 0's cx moved by 2 px): the new recording carries it (its
#    bytes, its sha256sum, a command line naming it) and reprocesses to its own samples bit for
#    bit, which equal the same run's --csv value for value and differ from the live run's;
# 3. an existing --output-ch10 path: exit 2 naming it, its bytes and mtime untouched, no other
#    output created.
set -euo pipefail
POST="$1"; DUMP="$2"; RUN="$3"
REC="$RUN/out.ch10"; OUT="$RUN/post_ch10out"
fail() { echo "FAIL: $*"; exit 1; }
pass() { echo "ok: $*"; }
[ -s "$REC" ] || fail "no recording $REC (test_integration_testpoint makes it)"
rm -rf "$OUT"; mkdir -p "$OUT"
HAVE_DUMP=0; [ -x "$DUMP" ] && HAVE_DUMP=1
[ "$HAVE_DUMP" -eq 1 ] || echo "note: the independent reader ($DUMP) is not built in this tree: its checks run in the Release stage"

# The TMATS comments (G\COM) of a file's first packet (the setup record: 24-byte header, CSDW).
tmats_comments() {
  /usr/bin/python3 - "$1" <<'PY'
import struct, sys
d = open(sys.argv[1], "rb").read()
assert struct.unpack_from("<H", d, 0)[0] == 0xEB25, "no packet sync at offset 0"
text = d[28:struct.unpack_from("<I", d, 4)[0]].decode("ascii", "replace")
for line in text.split(";"):
    if line.strip().startswith("G\\COM:"):
        print(line.strip()[6:])
PY
}

# 1. The recorded inputs.
rc=0; "$POST" --verify "$REC" --output-ch10 "$OUT/same.ch10" --csv "$OUT/same.csv" \
  --stats-json "$OUT/same_stats.json" >"$OUT/same.log" 2>&1 || rc=$?
cat "$OUT/same.log"
[ "$rc" -eq 0 ] || fail "--output-ch10 with the recorded inputs: exit $rc"
/usr/bin/python3 - "$OUT/same_stats.json" "$OUT/same.ch10" <<'PY'
import json, os, sys
s = json.load(open(sys.argv[1]))
o, r = s["output_ch10"], s["replay"]
assert o["files"] == [sys.argv[2]] and o["bytes"] == os.path.getsize(sys.argv[2]), o
assert o["samples"] == r["samples"] and o["raw_records"] == r["records"], (o, r)
assert o["samples_in_no_file"] == o["raw_records_in_no_file"] == 0, o
PY
grep -q "^new recording: $OUT/same.ch10: 220 samples, .* 0 samples and 0 raw records in no file" "$OUT/same.log" \
  || fail "no summary of the new recording"
rc=0; "$POST" --verify "$OUT/same.ch10" --csv "$OUT/same_again.csv" >"$OUT/same_again.log" 2>&1 || rc=$?
grep -q "verify: 220 replayed, 220 recorded: 220 identical, 0 different" "$OUT/same_again.log" && [ "$rc" -eq 0 ] \
  || fail "the new recording reprocessed: exit $rc: $(cat "$OUT/same_again.log")"
cmp "$RUN/fti.csv" "$OUT/same.csv" && cmp "$OUT/same.csv" "$OUT/same_again.csv" \
  || fail "the new recording's samples are not the live run's"
tmats_comments "$OUT/same.ch10" >"$OUT/same_tmats.txt"
grep -qx "reprocessed from '$REC' sha256 $(sha256sum <"$REC" | cut -c1-64)" "$OUT/same_tmats.txt" \
  || fail "TMATS does not name the source and its SHA-256: $(cat "$OUT/same_tmats.txt")"
grep -q "^reprocessed recording: written by storetrack-post [0-9.]* from 1 source file" "$OUT/same_tmats.txt" \
  && grep -qx "reprocessed with substituted inputs: none (the recorded inputs)" "$OUT/same_tmats.txt" \
  || fail "TMATS: no version or substitution line"
if [ "$HAVE_DUMP" -eq 1 ]; then
  "$DUMP" --raw "$REC" >"$OUT/source.json"; "$DUMP" --raw "$OUT/same.ch10" >"$OUT/same.json"
  /usr/bin/python3 - "$OUT/source.json" "$OUT/same.json" <<'PY'
import json, sys
src, new = (json.load(open(p)) for p in sys.argv[1:3])
assert not new["truncated"] and new["stop_reason"] == "", new["stop_reason"]
assert new["header_checksum_errors"] == new["data_checksum_errors"] == 0
assert new["message_decode_errors"] == new["fti_block_errors"] == 0
assert new["raw_observations_error"] == "" and new["recorded_inputs_error"] == ""
assert new["raw_observations"] == src["raw_observations"], "raw channel not copied record for record"
assert new["recorded_inputs"] == src["recorded_inputs"], "inputs differ from the recorded ones"
assert new["samples"] == src["samples"], "samples differ (independent reader)"
print("independent reader: %d packets, %d raw records and %d samples, the source's; %d inputs"
      % (new["packets"], new["raw_observation_count"], len(new["samples"]), len(new["recorded_inputs"])))
PY
fi
pass "recorded inputs: the new recording reprocesses to itself bit for bit, holds the live run's samples and raw channel, TMATS names the source"

# 2. A substituted calibration.
/usr/bin/python3 - "$RUN/sim/rig_calibrated.json" "$OUT/moved.json" <<'PY'
import json, sys
rig = json.load(open(sys.argv[1]))
rig["cameras"][0]["intrinsics"]["cx"] += 2.0
json.dump(rig, open(sys.argv[2], "w"))
PY
rc=0; "$POST" "$REC" --calibration "$OUT/moved.json" --output-ch10 "$OUT/moved.ch10" --csv "$OUT/moved.csv" \
  >"$OUT/moved.log" 2>&1 || rc=$?
[ "$rc" -eq 0 ] || fail "--output-ch10 with a substituted calibration: exit $rc: $(cat "$OUT/moved.log")"
rc=0; "$POST" --verify "$OUT/moved.ch10" --csv "$OUT/moved_again.csv" >"$OUT/moved_again.log" 2>&1 || rc=$?
cat "$OUT/moved_again.log"
[ "$rc" -eq 0 ] || fail "the substituted run's recording reprocessed with its own inputs: exit $rc"
cmp "$OUT/moved.csv" "$OUT/moved_again.csv" || fail "reprocessed again: another CSV"
tmats_comments "$OUT/moved.ch10" | grep -qx \
  "reprocessed with substituted inputs: calibration '$OUT/moved.json' sha256 $(sha256sum <"$OUT/moved.json" | cut -c1-64)" \
  || fail "TMATS does not name the substituted calibration and its SHA-256"
if [ "$HAVE_DUMP" -eq 1 ]; then
  "$DUMP" "$OUT/moved.ch10" >"$OUT/moved.json.dump"
  /usr/bin/python3 - "$OUT/moved.json.dump" "$OUT/source.json" "$OUT/moved.json" "$OUT/moved.csv" <<'PY'
import csv, hashlib, json, struct, sys
new, src = json.load(open(sys.argv[1])), json.load(open(sys.argv[2]))
moved = open(sys.argv[3], "rb").read()
ins = {i["kind"]: i for i in new["recorded_inputs"]}
by_name = {(i["kind"], i["name"]): i for i in new["recorded_inputs"]}  # meshes share kind 7
cal = ins[0]
assert bytes.fromhex(cal["bytes_hex"]) == moved and cal["name"] == sys.argv[3], "calibration bytes"
assert cal["sha256"] == hashlib.sha256(moved).hexdigest(), "calibration SHA-256"
for i in src["recorded_inputs"]:
    if i["kind"] not in (0, 5):
        assert by_name[(i["kind"], i["name"])] == i, "input %d (%s) changed" % (i["kind"], i["name"])
argv = bytes.fromhex(ins[5]["bytes_hex"]).split(b"\0")[:-1]
assert argv[argv.index(b"--calibration") + 1] == sys.argv[3].encode(), argv
def f32(v):  # the block's float32; NaN (invalid) is null in the reader's JSON, "nan" in the CSV
    v = float("nan") if v is None else float(v)
    return "nan" if v != v else struct.unpack("f", struct.pack("f", v))[0]
rows = list(csv.DictReader(open(sys.argv[4])))
assert len(rows) == len(new["samples"]) == 220, (len(rows), len(new["samples"]))
axes = ("x", "y", "z", "yaw", "pitch", "roll")
for r, s in zip(rows, new["samples"]):
    for col, key in (("trigger_seq [1]", "trigger_seq"), ("exposure_mid_tai_ns [ns]", "exposure_mid_tai_ns"),
                     ("status [bitfield]", "status"), ("cameras_used [1]", "cameras_used"),
                     ("marks_used [1]", "marks_used")):
        assert int(r[col]) == s[key], (col, r[col], s[key])
    for a, name in enumerate(axes):
        unit = "m" if a < 3 else "rad"
        assert f32(r["%s [%s]" % (name, unit)]) == f32(s["pose"][a]), (name, r, s)
        assert f32(r["u_%s [%s]" % (name, unit)]) == f32(s["uncertainty"][a]), (name, r, s)
differ = sum(a["pose"] != b["pose"] for a, b in zip(new["samples"], src["samples"]))
assert differ > 0, "the substitute changed no sample"
print("substituted calibration: 220 samples equal the run's --csv (float32 exact), %d differ from the live run's" % differ)
PY
fi
pass "substituted calibration: carried (bytes, SHA-256, command line), reprocesses to itself bit for bit, samples = its --csv"

# 3. Never over an existing file.
cp -p "$OUT/same.ch10" "$OUT/kept.ch10"
before="$(sha256sum <"$OUT/kept.ch10") $(stat -c %Y.%y "$OUT/kept.ch10")"
rc=0; "$POST" "$REC" --csv "$OUT/not_written.csv" --output-ch10 "$OUT/kept.ch10" >"$OUT/exists.log" 2>&1 || rc=$?
[ "$rc" -eq 2 ] && grep -q "$OUT/kept.ch10: exists" "$OUT/exists.log" || fail "an existing --output-ch10: exit $rc: $(cat "$OUT/exists.log")"
[ "$(sha256sum <"$OUT/kept.ch10") $(stat -c %Y.%y "$OUT/kept.ch10")" = "$before" ] || fail "the existing file was touched"
[ ! -e "$OUT/not_written.csv" ] || fail "another output was created beside a refused one"
rc=0; "$POST" "$REC" --output-ch10 "$REC" >"$OUT/over_source.log" 2>&1 || rc=$?
[ "$rc" -eq 2 ] && grep -q "$REC: exists" "$OUT/over_source.log" || fail "--output-ch10 over the source: exit $rc"
pass "an existing output (the source itself too) refused by name, untouched, nothing else written"
