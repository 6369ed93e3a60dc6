#!/usr/bin/env bash
# storetrack-post on the recording test_integration_testpoint just made (issue 26): replayed
# through the host's aligner, matcher and processor, every sample must be the live run's, bit for
# bit, and as many. The truth is the live run itself: its Chapter 10 sample channel (compared by
# --verify) and its CSV (written by the host from the same samples, compared with cmp). Then the
# bad inputs: an existing output (refused, untouched), a torn copy (replayed to its last whole
# packet, said so, a prefix of the live samples), a file that is not a recording, and a
# substituted calibration (the same bytes: identical; moved by 2 px: the samples move).
set -euo pipefail
POST="$1"; RUN="$2"
REC="$RUN/out.ch10"; OUT="$RUN/post"
fail() { echo "FAIL: $*"; exit 1; }
pass() { echo "ok: $*"; }
[ -s "$REC" ] || fail "no recording $REC (test_integration_testpoint makes it)"
rm -rf "$OUT"; mkdir -p "$OUT"

# 1. Bit-identical samples, every one, same count.
rc=0; "$POST" --verify "$REC" --csv "$OUT/fti.csv" --stats-json "$OUT/stats.json" \
  >"$OUT/verify.log" 2>&1 || rc=$?
cat "$OUT/verify.log"
[ "$rc" -eq 0 ] || fail "storetrack-post --verify exited $rc"
/usr/bin/python3 - "$OUT/stats.json" "$RUN/stats.json" <<'PY'
import json, sys
post, live = json.load(open(sys.argv[1])), json.load(open(sys.argv[2]))
v, n = post["verify"], live["samples_written"]
print("samples: %d replayed, %d recorded, %d identical, %d different; live host wrote %d"
      % (v["replayed"], v["recorded"], v["identical"], v["different"], n))
assert n > 0 and v["recorded"] == n, "the recording holds the %d samples the host wrote" % n
assert v["replayed"] == n and v["identical"] == n and v["different"] == 0, "bit-identical"
assert post["replay"]["flush_events"] == 1, "the host's final flush replayed"
assert post["replay"]["undecodable"] == 0 and post["replay"]["unknown_kind"] == 0
PY
cmp "$RUN/fti.csv" "$OUT/fti.csv" || fail "replayed CSV differs from the live run's"
# The clearance replayed with the geometry the recording carries (not read from disk).
grep -q "clearance: the geometry recorded in $REC" "$OUT/verify.log" \
  || fail "the clearance was not replayed from the recorded geometry"
pass "every sample bit-identical to the live run's ($(($(wc -l <"$OUT/fti.csv") - 1)) CSV rows identical too)"

# 2. Never over an existing file: refused before the replay, the file untouched.
before=$(sha256sum <"$RUN/fti.csv")
rc=0; "$POST" "$REC" --csv "$RUN/fti.csv" >"$OUT/exists.log" 2>&1 || rc=$?
[ "$rc" -eq 2 ] || fail "an existing --csv: exit $rc, expected 2"
grep -q "$RUN/fti.csv: exists" "$OUT/exists.log" || fail "no message naming the existing file"
[ "$(sha256sum <"$RUN/fti.csv")" = "$before" ] || fail "the existing CSV was changed"
pass "an existing output file is refused and left as it was"

# 3. A torn copy (a crash inside the last packet): replayed to its last whole packet, said so;
# its samples are the live run's first ones.
size=$(stat -c %s "$REC")
head -c $((size - 5)) "$REC" >"$OUT/torn.ch10"
rc=0; "$POST" --verify "$OUT/torn.ch10" --csv "$OUT/torn.csv" >"$OUT/torn.log" 2>&1 || rc=$?
cat "$OUT/torn.log"
[ "$rc" -eq 0 ] || fail "torn copy: exit $rc"
grep -q "$OUT/torn.ch10: .*ends inside.*: replaying up to its last whole packet" "$OUT/torn.log" \
  || fail "no message naming the torn file"
rows=$(wc -l <"$OUT/torn.csv")
[ "$rows" -gt 100 ] || fail "torn copy: only $rows CSV lines"
head -n "$rows" "$RUN/fti.csv" | cmp - "$OUT/torn.csv" || fail "torn copy's samples are not the live run's first"
pass "torn copy: $((rows - 1)) samples, the live run's first, bit-identical"

# 4. Not a recording: exit 2 naming the file.
printf 'not a chapter 10 file\n' >"$OUT/junk.ch10"
rc=0; "$POST" "$OUT/junk.ch10" >"$OUT/junk.log" 2>&1 || rc=$?
[ "$rc" -eq 2 ] && grep -q "$OUT/junk.ch10" "$OUT/junk.log" || fail "junk file: exit $rc: $(cat "$OUT/junk.log")"
pass "a file that is not a recording: exit 2, named"

# 5. Substitution: the recorded calibration's own bytes change nothing; moved by 2 px they must.
rc=0; "$POST" --verify "$REC" --calibration "$RUN/sim/rig_calibrated.json" >"$OUT/same.log" 2>&1 || rc=$?
[ "$rc" -eq 0 ] || fail "the same calibration substituted: exit $rc: $(cat "$OUT/same.log")"
/usr/bin/python3 - "$RUN/sim/rig_calibrated.json" "$OUT/moved.json" <<'PY'
import json, sys
rig = json.load(open(sys.argv[1]))
rig["cameras"][0]["intrinsics"]["cx"] += 2.0
json.dump(rig, open(sys.argv[2], "w"))
PY
rc=0; "$POST" --verify "$REC" --calibration "$OUT/moved.json" --stats-json "$OUT/moved_stats.json" \
  >"$OUT/moved.log" 2>&1 || rc=$?
[ "$rc" -eq 1 ] || fail "a moved calibration substituted: exit $rc, expected 1 (samples differ)"
/usr/bin/python3 -c "
import json, sys; v = json.load(open(sys.argv[1]))['verify']
assert v['different'] > 0, v; print('moved calibration: %d of %d samples differ' % (v['different'], v['replayed']))
" "$OUT/moved_stats.json"
pass "substituted calibration used (same bytes: identical; moved: samples differ)"

# 6. The smoothed trajectory (host/smooth): with --verify still bit-identical; a NEW file only;
# one line per exposure of a tracked segment, units in the header, every u finite and positive,
# the total at least each of its parts.
rc=0; "$POST" --verify "$REC" --smoothed-csv "$OUT/smoothed.csv" >"$OUT/smoothed.log" 2>&1 || rc=$?
cat "$OUT/smoothed.log"
[ "$rc" -eq 0 ] || fail "--verify with --smoothed-csv: exit $rc"
grep -q "^smoothed: [1-9][0-9]* segment" "$OUT/smoothed.log" || fail "no smoother summary"
/usr/bin/python3 - "$OUT/smoothed.csv" "$RUN/fti.csv" <<'PY'
import csv, math, sys
rows = list(csv.DictReader(open(sys.argv[1])))
samples = sum(1 for _ in open(sys.argv[2])) - 1
assert rows, "no smoothed rows"
for name in ("x_m", "yaw_rad", "vz_m_s", "az_m_s2", "wy_rad_s", "u_x_m", "u_noise_vz_m_s",
             "u_shared_pitch_rad"):
    assert name in rows[0], "header lacks " + name
for r in rows:
    for q in ("x_m", "y_m", "z_m", "yaw_rad", "pitch_rad", "roll_rad", "vx_m_s", "wy_rad_s"):
        u, un, us = float(r["u_" + q]), float(r["u_noise_" + q]), float(r["u_shared_" + q])
        assert math.isfinite(float(r[q])) and u > 0 and u * (1 + 1e-3) >= max(un, us), (q, r)
print("smoothed: %d rows (%d samples in the recording), %d measured" %
      (len(rows), samples, sum(int(r["measured"]) for r in rows)))
assert len(rows) >= samples // 2, "fewer smoothed rows than half the samples"
PY
rc=0; "$POST" "$REC" --smoothed-csv "$OUT/smoothed.csv" >"$OUT/smoothed_exists.log" 2>&1 || rc=$?
[ "$rc" -eq 2 ] && grep -q "$OUT/smoothed.csv: exists" "$OUT/smoothed_exists.log" \
  || fail "an existing --smoothed-csv: exit $rc"
pass "smoothed trajectory written (new file only), samples still bit-identical"

# 7. The data product (host/smooth), from the recording alone (the scenario's store survey
# carries a CG, drawn with its sigma by the simulator): the release t0 is found against the
# scenario's truth within its stated uncertainty, and so is the captive CG, in pylon and in
# aircraft axes (|z| <= 3.29 each,
# two-sided 0.1 %: one deterministic run); the CSV has units, U = 2u, the displacement from the
# carriage is 0 at the carriage. A store survey without "cg" is refused naming it and the
# field, nothing written; an existing path is refused before any other output is created.
rc=0; "$POST" --verify "$REC" --product-csv "$OUT/product.csv" >"$OUT/product.log" 2>&1 || rc=$?
cat "$OUT/product.log"
[ "$rc" -eq 0 ] || fail "--product-csv: exit $rc"
grep -q "verify: 220 replayed, 220 recorded: 220 identical" "$OUT/product.log" \
  || fail "the product changed the samples"
/usr/bin/python3 - "$OUT/product.csv" "$OUT/product.log" "$RUN/scenario.json" "$RUN/sim/true_survey_store.json" <<'PY'
import csv, json, math, re, sys
rows = list(csv.DictReader(open(sys.argv[1])))
log = open(sys.argv[2]).read()
sc = json.load(open(sys.argv[3]))
t0 = int(re.search(r"release: t0 = (\d+) TAI ns", log).group(1))
truth = sc["timing"]["start_tai_ns"] + round(sc["separation"]["release_time_s"] * 1e9)
u = float(rows[0]["u_t0_s"])
z = (t0 - truth) * 1e-9 / u
print("t0: %+.1f us from the truth, u(t0) %.1f us, z %.2f" % ((t0 - truth) * 1e-3, u * 1e6, z))
assert abs(z) <= 3.29, "t0 outside its stated uncertainty"
# The captive CG: T_p_s0 cg (the scenario's carriage pose has no rotation).
sep = sc["separation"]["T_p_s0"]
assert sep["ypr_deg"] == [0.0, 0.0, 0.0]
cg = json.load(open(sys.argv[4]))["cg"]["p_body_m"]
first = rows[0]
for a, q in enumerate(("cg_x_m", "cg_y_m", "cg_z_m")):
    zc = (float(first[q]) - (sep["translation_m"][a] + cg[a])) / float(first["u_" + q])
    print("captive %s: z %.2f (u %.2f mm)" % (q, zc, float(first["u_" + q]) * 1e3))
    assert abs(zc) <= 3.29, "captive CG outside its stated uncertainty"
# In aircraft axes (the rig's world frame, where the simulator's pylon sits at its nominal pose).
Twp = sc["T_w_p"]
assert Twp["ypr_deg"] == [0.0, 0.0, 0.0]
for a, q in enumerate(("cg_ac_x_m", "cg_ac_y_m", "cg_ac_z_m")):
    true = Twp["translation_m"][a] + sep["translation_m"][a] + cg[a]
    zc = (float(first[q]) - true) / float(first["u_" + q])
    print("captive %s: z %.2f (u %.2f mm)" % (q, zc, float(first["u_" + q]) * 1e3))
    assert abs(zc) <= 3.29, "captive CG in aircraft axes outside its stated uncertainty"
names = ["cg_x_m", "pitch_rad", "vz_m_s", "az_m_s2", "q_rad_s", "dcg_z_m", "cg_ac_z_m", "pitch_ac_rad"]
for r in rows:
    assert abs(float(r["t_since_t0_s"]) - (int(r["exposure_mid_tai_ns"]) - t0) * 1e-9) < 1e-9
    for q in names:
        uq, Uq = float(r["u_" + q]), float(r["U_" + q])
        assert math.isfinite(float(r[q])) and uq > 0 and abs(Uq - 2 * uq) <= 1e-3 * Uq, (q, r)
carriage = [r for r in rows if float(r["dcg_z_m"]) == 0.0]
assert len(carriage) == 1 and float(carriage[0]["t_since_t0_s"]) < 0, "one carriage row before t0"
last = rows[-1]
print("product: %d rows; at %.3f s after t0 the CG moved %.4f +- %.4f m (U) down" %
      (len(rows), float(last["t_since_t0_s"]), float(last["dcg_z_m"]), float(last["U_dcg_z_m"])))
PY
before=$(sha256sum <"$OUT/product.csv")
rc=0; "$POST" "$REC" --csv "$OUT/not_written.csv" --product-csv "$OUT/product.csv" \
  >"$OUT/product_exists.log" 2>&1 || rc=$?
[ "$rc" -eq 2 ] && grep -q "$OUT/product.csv: exists" "$OUT/product_exists.log" \
  || fail "an existing --product-csv: exit $rc"
[ "$(sha256sum <"$OUT/product.csv")" = "$before" ] || fail "the existing product was changed"
[ ! -e "$OUT/not_written.csv" ] || fail "another output was created beside a refused one"
/usr/bin/python3 -c "
import json, sys; s = json.load(open(sys.argv[1])); del s['cg']; json.dump(s, open(sys.argv[2], 'w'))
" "$RUN/sim/survey_store.json" "$OUT/store_nocg.json"
rc=0; "$POST" "$REC" --store-survey "$OUT/store_nocg.json" --product-csv "$OUT/product_nocg.csv" \
  >"$OUT/product_nocg.log" 2>&1 || rc=$?
[ "$rc" -eq 2 ] && grep -q "$OUT/store_nocg.json: no \"cg\" field" "$OUT/product_nocg.log" \
  || fail "a store survey without a CG: exit $rc: $(cat "$OUT/product_nocg.log")"
[ ! -e "$OUT/product_nocg.csv" ] || fail "a product was written without a CG"
pass "data product written (t0 and captive CG against the truth, new file only), samples bit-identical; no CG refused"
# 8. Is a substituted calibration's change significant? (--differences-csv.) The recorded
# calibration's own bytes: every sample solved in both, d = 0 on every axis. Camera 0 turned by
# 0.1 deg about its y axis (its stated rotation sigma: 0.05 mrad): significant, max |z| > 5 (an
# honest substitute reaches |z| > 5 on one of 220 x 6 values with probability < 1e-3 even were
# they independent). A calibration of another rig (a camera fewer): exit 2, named, nothing written.
rc=0; "$POST" "$REC" --calibration "$RUN/sim/rig_calibrated.json" --differences-csv "$OUT/d_same.csv" \
  --smoothed-differences-csv "$OUT/sd_same.csv" --stats-json "$OUT/d_same.json" \
  >"$OUT/d_same.log" 2>&1 || rc=$?
[ "$rc" -eq 0 ] || fail "--differences-csv with the same calibration: exit $rc: $(cat "$OUT/d_same.log")"
/usr/bin/python3 - "$RUN/sim/rig_calibrated.json" "$OUT/turned.json" "$OUT/fewer.json" <<'PY'
import json, math, sys
def rot(v):  # Rodrigues
    th = math.sqrt(sum(x * x for x in v))
    if th == 0:
        return [[float(i == j) for j in range(3)] for i in range(3)]
    k = [x / th for x in v]; c, s = math.cos(th), math.sin(th)
    K = [[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]]
    return [[float(i == j) + s * K[i][j] + (1 - c) * sum(K[i][m] * K[m][j] for m in range(3))
             for j in range(3)] for i in range(3)]
def vec(R):
    th = math.acos(max(-1.0, min(1.0, (R[0][0] + R[1][1] + R[2][2] - 1) / 2)))
    w = [R[2][1] - R[1][2], R[0][2] - R[2][0], R[1][0] - R[0][1]]
    return [x * th / (2 * math.sin(th)) for x in w]
rig = json.load(open(sys.argv[1]))
T = rig["cameras"][0]["T_c_w"]
D = rot([0.0, math.radians(0.1), 0.0])  # left of T_c_w: the camera turned about its own y axis
R = rot(T["rotation_vector_rad"])
T["rotation_vector_rad"] = vec([[sum(D[i][m] * R[m][j] for m in range(3)) for j in range(3)]
                                for i in range(3)])
T["translation_m"] = [sum(D[i][m] * T["translation_m"][m] for m in range(3)) for i in range(3)]
json.dump(rig, open(sys.argv[2], "w"))
rig = json.load(open(sys.argv[1])); rig["cameras"].pop(); json.dump(rig, open(sys.argv[3], "w"))
PY
rc=0; "$POST" "$REC" --calibration "$OUT/turned.json" --differences-csv "$OUT/d_turned.csv" \
  --smoothed-differences-csv "$OUT/sd_turned.csv" --stats-json "$OUT/d_turned.json" \
  >"$OUT/d_turned.log" 2>&1 || rc=$?
cat "$OUT/d_turned.log"
[ "$rc" -eq 0 ] || fail "--differences-csv with a turned camera: exit $rc"
/usr/bin/python3 - "$OUT/d_same.json" "$OUT/d_same.csv" "$OUT/d_turned.json" "$OUT/sd_same.csv" <<'PY'
import csv, json, sys
same = json.load(open(sys.argv[1]))
assert same["differences"]["compared"] == same["differences"]["recorded_samples"] > 0, same
assert same["smoothed_differences"]["compared"] == same["smoothed_differences"]["recorded_states"] > 0
for path in (sys.argv[2], sys.argv[4]):
    for r in csv.DictReader(open(path)):
        assert r.get("u_basis", "noise_cancels") == "noise_cancels", r
        for k, v in r.items():
            if k.startswith("d_"):
                assert float(v) == 0.0, (path, k, r)
            if k.startswith("u_d_"):
                assert float(v) > 0, (path, k, r)
turned = json.load(open(sys.argv[3]))
for what, axes in (("differences", "axes"), ("smoothed_differences", "quantities")):
    t = turned[what]
    worst = max(t[axes].values(), key=lambda a: a["max_abs_z"])
    print("turned camera, %s: %d compared, max |z| %.2f" % (what, t["compared"], worst["max_abs_z"]))
    # |z| > 5 on one of 220 x 18 honest values: probability < 3e-3 even were they independent.
    assert t["compared"] > 100 and worst["max_abs_z"] > 5, t
PY
rc=0; "$POST" "$REC" --calibration "$OUT/fewer.json" --differences-csv "$OUT/d_fewer.csv" \
  >"$OUT/d_fewer.log" 2>&1 || rc=$?
[ "$rc" -eq 2 ] && grep -q "$OUT/fewer.json: a calibration of another rig" "$OUT/d_fewer.log" \
  || fail "another rig's calibration: exit $rc: $(cat "$OUT/d_fewer.log")"
[ ! -e "$OUT/d_fewer.csv" ] || fail "another rig's calibration: an output was written"
pass "differences (per exposure and smoothed): same calibration d = 0; turned camera significant; another rig refused"

# 7. The truth-free report (--report DIR) of the recording and of the torn copy, rendered by
# host/report/storetrack_post_report.py: its integrity counts are the files' own (the live
# run's packets, no errors; the torn copy torn), every exposure the live host wrote is there,
# and a non-empty directory is refused by name, its files untouched.
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../../.." && pwd)"
rc=0; "$POST" "$REC" --report "$OUT/report" >"$OUT/report.log" 2>&1 || rc=$?
[ "$rc" -eq 0 ] || fail "--report: exit $rc: $(cat "$OUT/report.log")"
/usr/bin/python3 "$ROOT/host/report/storetrack_post_report.py" "$OUT/report" >"$OUT/report_render.log" \
  || fail "storetrack_post_report.py failed: $(cat "$OUT/report_render.log")"
[ -s "$OUT/report/index.html" ] && [ -s "$OUT/report/residual_windows.png" ] \
  && [ -s "$OUT/report/camera_usage.png" ] || fail "report: index.html or its plots missing"
rc=0; "$POST" "$OUT/torn.ch10" --report "$OUT/report_torn" >"$OUT/report_torn.log" 2>&1 || rc=$?
[ "$rc" -eq 0 ] || fail "--report of the torn copy: exit $rc"
/usr/bin/python3 - "$OUT/report/report.json" "$OUT/report_torn/report.json" "$RUN/stats.json" "$REC" <<'PY'
import json, os, struct, sys
rep, torn, live = (json.load(open(p)) for p in sys.argv[1:4])
data = open(sys.argv[4], "rb").read()
packets, at = 0, 0  # the recording's packets, counted here from the headers' lengths
while at + 24 <= len(data):
    packets += 1
    at += struct.unpack_from("<I", data, at + 4)[0]
i = rep["integrity"]
f = i["files"][0]
print("report: %d packets (%d counted here), %d exposures, %d samples recorded; noise windows %d "
      "of %d inside (acceptance %d .. %d); torn copy: %s" % (
          f["packets"], packets, i["exposures_processed"], i["samples_recorded"],
          rep["residual_windows"]["inside"], rep["residual_windows"]["windows"],
          rep["residual_windows"]["inside_band_low"], rep["residual_windows"]["inside_band_high"],
          torn["integrity"]["files"][0]["stop_reason"]))
for c in rep["calibration_residuals"]["per_camera"]:
    print("report: calibration part camera %d: chi2 %.1f on %d dof (band %.1f .. %.1f)%s" % (
        c["camera_id"], c["chi2"], c["dof"], c["band_low"], c["band_high"],
        "" if c["inside"] else " OUTSIDE"))
assert f["packets"] == packets and f["file_bytes"] == len(data) and not f["torn"], f
assert f["header_checksum_errors"] == f["data_checksum_errors"] == f["sequence_gap_packets"] == 0, f
assert i["continuation_files"] == 0 and i["exposures_missing"] == 0 and i["host_ended_normally"], i
assert i["samples_recorded"] == live["samples_written"] == i["exposures_processed"], i
t = torn["integrity"]["files"][0]
assert t["torn"] and t["file_bytes"] == len(data) - 5 and t["packets"] == packets - 1, t
PY
touch "$OUT/report_kept"; mkdir -p "$OUT/report_full"; cp "$OUT/report_kept" "$OUT/report_full/kept"
rc=0; "$POST" "$REC" --report "$OUT/report_full" >"$OUT/report_full.log" 2>&1 || rc=$?
[ "$rc" -eq 2 ] && grep -q "$OUT/report_full: not empty" "$OUT/report_full.log" \
  || fail "a non-empty report directory: exit $rc: $(cat "$OUT/report_full.log")"
[ "$(ls "$OUT/report_full")" = kept ] || fail "a non-empty report directory was written into"
pass "report: integrity counts the file's own, the torn copy torn, a non-empty directory refused"

# 7. The recorded clearance geometry's bytes no longer match their SHA-256 (one character of the
# geometry file changed in a copy): refused, exit 2, the input named; a recording without a
# usable geometry is never replayed with a wrong one.
/usr/bin/python3 - "$REC" "$OUT/bad_geometry.ch10" <<'PY'
import sys
data = bytearray(open(sys.argv[1], "rb").read())
at = data.find(b'"storetrack-clearance-geometry"')
assert at > 0 and data.find(b'"storetrack-clearance-geometry"', at + 1) < 0, "one geometry copy"
data[at + 1] = ord("S")
open(sys.argv[2], "wb").write(data)
PY
rc=0; "$POST" "$OUT/bad_geometry.ch10" --csv "$OUT/bad_geometry.csv" >"$OUT/bad_geometry.log" 2>&1 || rc=$?
[ "$rc" -eq 2 ] && grep -q "recorded input '.*geometry.json' does not match its recorded SHA-256" \
  "$OUT/bad_geometry.log" || fail "corrupted geometry bytes: exit $rc: $(cat "$OUT/bad_geometry.log")"
[ ! -e "$OUT/bad_geometry.csv" ] || fail "corrupted geometry bytes: an output was written"
pass "recorded geometry bytes that fail their SHA-256: exit 2, the input named, nothing written"

# 8. The geometry from disk instead (--clearance-geometry, the same files): identical samples; a
# configuration naming a geometry the recording does not carry (the forged test's toy) and no
# --clearance-geometry: "clearance NOT replayed", the clearance fields then differ (exit 1).
GEOMETRY=$(cd "$(dirname "$0")/../../.." && pwd)/common/sim/scenarios/store_separation_geometry/geometry.json
TOY=$(cd "$(dirname "$0")/.." && pwd)/forged/clearance/geometry.json
rc=0; "$POST" --verify "$REC" --clearance-geometry "$GEOMETRY" >"$OUT/disk_geometry.log" 2>&1 || rc=$?
[ "$rc" -eq 0 ] && grep -q "clearance: the geometry read from $GEOMETRY" "$OUT/disk_geometry.log" \
  || fail "--clearance-geometry with the same files: exit $rc: $(cat "$OUT/disk_geometry.log")"
printf '{"clearance": {"geometry": "%s", "alarm_threshold_m": 0.10}}\n' "$TOY" >"$OUT/toy_host.json"
rc=0; "$POST" --verify "$REC" --config "$OUT/toy_host.json" >"$OUT/toy.log" 2>&1 || rc=$?
[ "$rc" -eq 1 ] && grep -q "clearance NOT replayed: .*does not carry the clearance geometry '$TOY'" \
  "$OUT/toy.log" || fail "a geometry the recording does not carry: exit $rc: $(cat "$OUT/toy.log")"
pass "--clearance-geometry from disk: identical; a geometry not recorded: clearance NOT replayed, named"
