#!/usr/bin/env python3
"""Checks a short test point's outputs against the simulator's truth (run_testpoint.sh):
check_testpoint.py ROOT OUT CLEARANCE_AT_POSES."""
import json
import os
import sys

import numpy as np

root, out, clearance_at_poses = sys.argv[1], sys.argv[2], sys.argv[3]
sys.path.insert(0, os.path.join(root, "host", "report"))
from storetrack_report import Checks, binomial_acceptance, read_ch10, read_csv  # noqa: E402
from clearance_report import ALARM_BIT, P_BOUND_HELD, P_INSIDE, clearance_statistics, truth_clearance  # noqa: E402

check = Checks()
failures = check.failures


fti = read_csv(os.path.join(out, "fti.csv"))
truth = read_csv(os.path.join(out, "sim", "truth_poses.csv"))
stats = json.load(open(os.path.join(out, "stats.json")))
n = len(fti["trigger_seq"])
al = stats["aligner"]
# Every exposure comes out once, in order, even with one camera unit stopping 20 frames early.
check(n == 220, "220 samples written (got %d)" % n)
check(np.all(np.diff(fti["trigger_seq"]) > 0), "samples in trigger order")
check(al["exposures_partial_timeout"] > 0, "the stopped camera gave partial exposures (%d)" % al["exposures_partial_timeout"])
check(al["observations_in"] == al["observations_used"] + al["dropped_duplicate"] + al["dropped_late"]
      + al["dropped_time_mismatch"] + al["dropped_unknown_camera"] + al["dropped_invalid"],
      "every observation used or counted as dropped")
valid = (fti["status"].astype(int) & 1) == 1
check(valid.mean() > 0.95, "valid samples %.1f %% > 95 %%" % (100 * valid.mean()))

# Pose against truth: errors within 4 standard uncertainties (|z| <= 4 for >= 99 % of samples)
# and the k = 2 coverage not far below 95 % on the position axes.
idx = {int(s): i for i, s in enumerate(truth["trigger_seq"])}
sel = np.array([idx[int(s)] for s in fti["trigger_seq"]])
for a, unit in (("x", "m"), ("y", "m"), ("z", "m"), ("yaw", "rad"), ("pitch", "rad"), ("roll", "rad")):
    e = fti[a][valid] - truth["T_p_s_%s_%s" % (a, unit)][sel[valid]]
    if unit == "rad":
        e = (e + np.pi) % (2 * np.pi) - np.pi
    z = np.abs(e) / fti["u_" + a][valid]
    rms = np.sqrt(np.mean(e ** 2))
    print("     %-5s RMS error %.3g %s, inside k=2: %.1f %%" % (a, rms, unit, 100 * np.mean(z <= 2)))
    check(np.mean(z <= 4) >= 0.99, "%s: >= 99 %% of errors within 4 u" % a)
    if unit == "m":
        # Median, not RMS: degraded exposures (3 marks, flagged) carry large errors AND large u.
        med = np.median(np.abs(e))
        check(med < 2e-3, "%s: median |error| %.2f mm < 2 mm" % (a, med * 1e3))

# Chapter 10: TMATS first, no checksum errors, no partial packet, one message per sample.
ch10 = read_ch10(os.path.join(out, "out.ch10"))
check(ch10["first_type"] == 0x01, "Chapter 10 starts with TMATS")
check(ch10["header_checksum_errors"] == 0 and ch10["truncated_bytes"] == 0, "Chapter 10 checksums, no partial packet")
check(ch10["messages"] == n, "Chapter 10 messages %d == samples %d" % (ch10["messages"], n))
check(ch10["by_type"].get(0x11, 0) >= 1, "Chapter 10 time packets present")
check(stats["outputs"]["inetx_sent"] == n, "one iNET-X packet per sample")

# Raw channel: exactly the datagrams the units sent (their own counters: observations and
# health reports on the UDP link, none failed), each as sent, read with this independent parser.
sent = 0
for c in range(4):
    unit = json.load(open(os.path.join(out, "unit_cam%d.json" % c)))
    for link in unit["links"]:
        check(link["tx_errors"] == 0, "unit %d link %s: no send errors" % (c, link["name"]))
        sent += link["observations_sent"] + link["health_sent"]
records = ch10["raw_observations"]
raw = [r for r in records if r["source_kind"] in (0, 1)]  # messages; 2, 3: the aligner's clock
check(ch10["raw_channel"] == 3, "TMATS names the raw channel RAWOBS (channel %s)" % ch10["raw_channel"])
check(len(raw) == sent, "raw channel holds %d datagrams == %d the units sent" % (len(raw), sent))
check(len(raw) == stats["udp"]["datagrams"], "raw channel == host datagrams received (%d)" % stats["udp"]["datagrams"])
check(sum(1 for r in raw if r["flags"] & 1) == stats["udp"]["decoded"], "accepted raw observations == host decoded")
check(all(r["bytes"][:2] == b"ST" and len(r["bytes"]) == r["received_bytes"] for r in raw),
      "every raw observation is a whole storetrack datagram")
check(all(raw[i]["arrival_tai_ns"] <= raw[i + 1]["arrival_tai_ns"] for i in range(len(raw) - 1)),
      "raw observations in arrival order")
check(all(records[i]["host_mono_ns"] <= records[i + 1]["host_mono_ns"] for i in range(len(records) - 1)),
      "raw channel records in the order the aligner was given them (host loop time)")
check(sum(1 for r in records if r["source_kind"] == 3) == 1 and records[-1]["source_kind"] == 3,
      "the host's final flush is the raw channel's last record")
rs = stats["recording"]["raw_observations"]
check(rs["dropped_queue_full"] == 0 and rs["messages_dropped"] == 0, "no raw observation dropped")

# Inputs channel: the files given, byte for byte, with their SHA-256 (hashlib here).
import hashlib  # noqa: E402
given = {0: os.path.join(out, "sim", "rig_calibrated.json"), 1: os.path.join(out, "sim", "survey_pylon.json"),
         2: os.path.join(out, "sim", "survey_store.json"), 4: os.path.join(out, "initial_marks.json")}
inputs = {i["kind"]: i for i in ch10["inputs"]}
for kind, path in given.items():
    want = open(path, "rb").read()
    got = inputs.get(kind)
    check(got is not None and got["bytes"] == want and got["total_bytes"] == len(want),
          "input %d (%s): recorded bytes == the file" % (kind, os.path.basename(path)))
    check(got is not None and got["sha256"] == hashlib.sha256(want).hexdigest(),
          "input %d: recorded SHA-256 == hashlib's" % kind)
check(5 in inputs and b"--ch10\0" in inputs[5]["bytes"], "the command line is recorded")

# The clearance geometry and its meshes: recorded byte for byte (the checked-in files), under the
# paths the host read them at, each with its SHA-256 (hashlib here).
geometry_dir = os.path.join(root, "common", "sim", "scenarios", "store_separation_geometry")
geometry = os.path.join(geometry_dir, "geometry.json")
recorded = [i for i in ch10["inputs"] if i["kind"] in (6, 7)]
expected = {geometry: 6}
for name in ("store.stl", "pylon.stl", "wing_lower.stl", "adjacent_store.stl"):
    expected[os.path.join(geometry_dir, name)] = 7
check(sorted((i["name"], i["kind"]) for i in recorded) == sorted(expected.items()),
      "the geometry file (kind 6) and its 4 meshes (kind 7) are recorded under their paths")
for i in recorded:
    want = open(i["name"], "rb").read() if os.path.exists(i["name"]) else None
    check(want is not None and i["bytes"] == want and i["sha256"] == hashlib.sha256(want).hexdigest(),
          "%s: recorded bytes == the checked-in file, SHA-256 == hashlib's (%s...)"
          % (os.path.basename(i["name"]), i["sha256"][:16]))

# Clearance against truth: the live clearance (nearest part, k = 2 band) against the same meshes
# at the simulator's true pose: |d - d_true| <= 2u expected on 95.45 % of the samples, the count
# held to its Binomial(n, 0.9545) acceptance band (2.5 % per side), and truth >= the k = 2 lower
# bound on >= 97.72 %. The samples of this run share ONE calibration and survey draw (seed 7):
# its errors are a common offset plus small per-exposure noise (measured: z = e/u from -1.9 to
# +0.7, slowly varying), so the count inside 2u is not Binomial(n) on either side: a draw whose
# offset is under 2u puts every sample inside, one near 2u (this seed's -1.9) puts a run-dependent
# share outside (the sanitizer tree's partial exposures moved 1 sample across: 203 of 220). Judged
# on this one draw: its offset, the mean of z, a draw of N(0, <= 1) (|mean z| <= 3.29: two-sided
# 0.1 %), and every |z| <= 4; the count is printed (docs/clearance.md, "In the main job"); the
# two-sided coverage over independent draws is test_clearance_separation's (300 seeds).
d_true, parts = truth_clearance(clearance_at_poses, geometry, fti, truth)
t = (fti["exposure_mid_tai_ns"] - fti["exposure_mid_tai_ns"][0]) * 1e-9
st = clearance_statistics(fti, d_true, t, binomial_acceptance)
n_c = st["n"]
low, high = round(st["band"][0] * n_c), round(st["band"][1] * n_c)
check(n_c == int(valid.sum()), "a clearance and a truth on every valid sample (%d)" % n_c)
print("     clearance k = 2 coverage %d of %d = %.1f %% (the band [%d, %d] of Binomial(%d, %.4f) "
      "holds for independent draws, not for this run's one shared draw: printed)"
      % (st["inside"], n_c, 100 * st["coverage"], low, high, n_c, P_INSIDE))
check(st["held"] >= round(st["held_band_low"] * n_c),
      "truth >= the k = 2 lower bound on %d of %d (>= %d: Binomial(n, %.4f) at 2.5 %%)"
      % (st["held"], n_c, round(st["held_band_low"] * n_c), P_BOUND_HELD))
z = st["error"][st["mask"]] / fti["u_clearance"][st["mask"]]
check(abs(np.mean(z)) <= 3.29,
      "the run's shared clearance offset: mean e/u %.2f within +-3.29 (one draw of N(0, <= 1))"
      % np.mean(z))
check(np.all(np.abs(z) <= 4), "every clearance error within 4 u (max |e|/u %.2f)" % np.max(np.abs(z)))
lb = fti["clearance_lower_bound"]
alarm = (fti["status"].astype(int) & ALARM_BIT) != 0
check(np.array_equal(alarm, np.isfinite(lb) & (lb < 0.10)),
      "alarm bit exactly on the %d samples whose lower bound is below 0.10 m" % alarm.sum())
sc = stats.get("clearance", {})
check(sc.get("samples_evaluated") == n_c and sc.get("alarm_samples") == int(alarm.sum())
      and sc.get("alarm_episodes") == len(st["episodes"]),
      "stats.json clearance: %s evaluated, %s alarm samples, %s episodes"
      % (sc.get("samples_evaluated"), sc.get("alarm_samples"), sc.get("alarm_episodes")))
print("     clearance: parts %s; min live %.4f m, min true %.4f m; RMS error %.3f mm"
      % (parts, st["min_live"][0], st["min_true"][0],
         1e3 * np.sqrt(np.mean(st["error"][st["mask"]] ** 2))))
sys.exit(1 if failures else 0)
