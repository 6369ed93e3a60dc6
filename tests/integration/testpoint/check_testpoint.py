#!/usr/bin/env python3
"""Checks a short test point's outputs against the simulator's truth (run_testpoint.sh)."""
import json
import os
import sys

import numpy as np

root, out = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.join(root, "host", "report"))
from storetrack_report import Checks, read_ch10, read_csv  # noqa: E402

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
sys.exit(1 if failures else 0)
