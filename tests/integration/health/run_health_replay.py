#!/usr/bin/python3
"""A camera moved in its mount, live and replayed (issue 27): storetrack-sim's camera_step scene
(camera 1 rotates 0.02 deg about x and shifts 0.5 mm along x; the calibration stays the old one),
shortened to N exposures with the step at exposure STEP, sent over UDP from the units' address
into the real storetrack-host once per calibration_health mode (flag, correct, exclude; windows
of 40 exposures, a 10-window baseline), each run recorded; then storetrack-post replays every
recording.

Checked against the simulator's truth (only camera 1 moved, at STEP):
  live: camera 1 and only camera 1 declared moved, never before the step; the log names it;
        flag: the samples after it flagged, no correction; correct: the processor rebuilt on the
        corrected rig; exclude: no sample after the detection used camera 1 (cameras_used <= 3);
  replay: every sample bit-identical to the live one in every mode (correct and exclude change the
        samples, so the replay must run the test as live did), and the replay's calibration
        health (moved cameras, first alarm, alarms, corrections) equal to the live stats;
        --report writes calibration_health.csv with camera 1's alarm windows after the step.

Usage: run_health_replay.py SIM HOST POST ROOT OUT [--fps F]
"""
import argparse
import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import time
import zlib

ap = argparse.ArgumentParser()
for name in ("sim", "host", "post", "root", "out"):
    ap.add_argument(name)
ap.add_argument("--fps", type=float, default=200.0)
a = ap.parse_args()
sys.path.insert(0, os.path.join(a.root, "tools"))
sys.path.insert(0, os.path.join(a.root, "host", "report"))
import sim_setup  # noqa: E402
from storetrack_report import Checks, read_csv  # noqa: E402
from host_listening import wait_until_listening  # noqa: E402

N, STEP, MOVED = 900, 560, 1
WINDOW, BASELINE_WINDOWS = 40, 10
check = Checks()
os.makedirs(a.out, exist_ok=True)


def simulate():
    s = json.load(open(os.path.join(a.root, "common", "sim", "scenarios", "camera_step.json")))
    s["timing"]["num_exposures"] = N
    moved = [c for c in s["cameras"] if c["camera_id"] == MOVED][0]
    moved["motion"]["start_s"] = (STEP - 0.5) / s["timing"]["frame_rate_hz"]
    scenario = os.path.join(a.out, "scenario.json")
    json.dump(s, open(scenario, "w"))
    sim_dir = os.path.join(a.out, "sim")
    subprocess.run([a.sim, "--scenario", scenario, "--seed", "5", "--out", sim_dir,
                    "--mode", "observations"], check=True, stdout=subprocess.DEVNULL)
    sim_setup.write_initial_marks(os.path.join(sim_dir, "truth_marks.csv"),
                                  os.path.join(a.out, "initial_marks.json"))
    return sim_dir, sim_setup.read_observation_groups(os.path.join(sim_dir, "observations.udp"))


def fly(mode, sim_dir, groups):
    out = os.path.join(a.out, mode)
    shutil.rmtree(out, ignore_errors=True)  # this test's own scratch: the tools never overwrite
    os.makedirs(out)
    json.dump({"aligner": {"max_wait_ms": 5000, "max_pending": len(groups)},
               "calibration_health": {"mode": mode, "window_exposures": WINDOW,
                                      "baseline_windows": BASELINE_WINDOWS}},
              open(os.path.join(out, "host.json"), "w"))
    port = 23000 + os.getpid() % 500 * 4
    host = subprocess.Popen(
        [a.host, "--calibration", os.path.join(sim_dir, "rig_calibrated.json"),
         "--pylon-survey", os.path.join(sim_dir, "survey_pylon.json"),
         "--store-survey", os.path.join(sim_dir, "survey_store.json"),
         "--initial-marks", os.path.join(a.out, "initial_marks.json"),
         "--udp-port", str(port), "--udp-bind", "127.0.0.1",
         "--udp-source", "0@127.0.0.1", "--udp-source", "1@127.0.0.1",
         "--csv", os.path.join(out, "fti.csv"), "--ch10", os.path.join(out, "out.ch10"),
         "--stats-json", os.path.join(out, "stats.json"), "--config", os.path.join(out, "host.json"),
         "--expect-exposures", str(len(groups)), "--idle-exit-s", "6"],
        stdout=open(os.path.join(out, "host.log"), "w"), stderr=subprocess.STDOUT)
    try:
        wait_until_listening(host, port, os.path.join(out, "host.log"))
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        dseq, t0 = {}, time.monotonic() + 0.05
        for k, group in enumerate(groups):
            due = t0 + k / a.fps
            if due > time.monotonic():
                time.sleep(due - time.monotonic())
            for d in group:
                b = bytearray(d)
                unit = b[12]
                struct.pack_into(">I", b, 8, dseq.get(unit, 0))  # the framing's datagram number
                dseq[unit] = dseq.get(unit, 0) + 1
                tx.sendto(bytes(b) + struct.pack(">I", zlib.crc32(bytes(b)) & 0xFFFFFFFF),
                          ("127.0.0.1", port))
        host.wait(timeout=120)
    finally:
        if host.poll() is None:
            host.kill()
            host.wait()
    check(host.returncode == 0, "%s: storetrack-host exit %s" % (mode, host.returncode))
    return out


def health_of(stats):
    h = stats["calibration_health"]
    return h, {c["camera_id"]: c for c in h["cameras"]}


def check_live(mode, out):
    stats = json.load(open(os.path.join(out, "stats.json")))
    h, cams = health_of(stats)
    moved = sorted(c for c, v in cams.items() if v["moved"])
    check(moved == [MOVED], "%s: cameras declared moved %s (truth: [%d])" % (mode, moved, MOVED))
    if MOVED not in cams or not cams[MOVED]["moved"]:
        return None
    first = cams[MOVED]["first_alarm_exposure"]  # the monitor's count: exposures 0..first-1
    check(first > STEP, "%s: declared at exposure %d, after the step at %d (%d exposures later)"
          % (mode, first - 1, STEP, first - 1 - STEP))
    log = open(os.path.join(out, "host.log")).read()
    check("camera %d declared MOVED" % MOVED in log, "%s: the log names camera %d" % (mode, MOVED))
    if mode == "flag":
        check(h["samples_flagged"] > 0 and h["corrections"] == 0,
              "flag: %d samples flagged, %d corrections" % (h["samples_flagged"], h["corrections"]))
    if mode == "correct":
        check(h["corrections"] >= 1 and "processor rebuilt on the corrected rig" in log,
              "correct: %d correction(s), the processor rebuilt" % h["corrections"])
    if mode == "exclude":
        fti = read_csv(os.path.join(out, "fti.csv"))
        after = [int(c) for s, c in zip(fti["trigger_seq"], fti["cameras_used"]) if s >= 1000 + first]
        used = max(after, default=-1)
        check(after and used <= 3 and h["exposures_excluding"] > 0,
              "exclude: %d samples after the detection, at most %d cameras used, %d exposures "
              "without camera %d" % (len(after), used, h["exposures_excluding"], MOVED))
    return h


def check_replay(mode, out, live):
    report = os.path.join(out, "report")
    r = subprocess.run([a.post, os.path.join(out, "out.ch10"), "--verify", "--stats-json",
                        os.path.join(out, "post_stats.json"), "--report", report],
                       stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    open(os.path.join(out, "post.log"), "w").write(r.stdout)
    if not check(os.path.exists(os.path.join(out, "post_stats.json")),
                 "%s: storetrack-post exit %d wrote its stats%s"
                 % (mode, r.returncode, "" if r.returncode == 0 else " (log: %s)" % r.stdout[-300:])):
        return
    stats = json.load(open(os.path.join(out, "post_stats.json")))
    v = stats.get("verify", {})
    check(r.returncode == 0 and v.get("different") == 0 and v.get("identical") == v.get("recorded") > 0,
          "%s: replay exit %d, %s of %s samples bit-identical" % (mode, r.returncode,
                                                                   v.get("identical"), v.get("recorded")))
    if live is None or "calibration_health" not in stats:
        check(False, "%s: the replay states its calibration health" % mode)
        return
    replayed, cams = health_of(stats)
    _, live_cams = health_of({"calibration_health": live})
    keys = ("moved", "first_alarm_exposure", "alarms", "windows_tested")
    same = all(cams[c].get(k) == live_cams[c].get(k) for c in live_cams for k in keys) and \
        all(replayed[k] == live[k] for k in ("samples_flagged", "corrections", "exposures_excluding"))
    check(same, "%s: the replay's calibration health equals the live run's (%s)" % (mode, ", ".join(keys)))
    # The residuals' calibration part per span of one calibration: one span more than the
    # processor's rebuilds (correct mode), each camera once per span, the spans in order.
    per_camera = json.load(open(os.path.join(report, "report.json")))["calibration_residuals"]["per_camera"]
    spans = sorted({c["span"] for c in per_camera})
    bounds = {c["span"]: (c["first_trigger_seq"], c["last_trigger_seq"]) for c in per_camera}
    ordered = all(bounds[k][1] < bounds[k + 1][0] for k in spans[:-1])
    check(spans == list(range(replayed["corrections"] + 1)) and ordered,
          "%s: report.json's calibration part in %d span(s) for %d correction(s): %s; %s"
          % (mode, len(spans), replayed["corrections"], bounds,
             ", ".join("camera %d span %d chi2 %.1f (band %.1f .. %.1f)"
                       % (c["camera_id"], c["span"], c["chi2"], c["band_low"], c["band_high"])
                       for c in per_camera)))
    windows = read_csv(os.path.join(report, "calibration_health.csv"))
    alarm = windows["alarm"] == 1
    cams_alarmed = sorted({int(c) for c in windows["camera_id"][alarm]})
    early = int((windows["trigger_seq"][alarm] < 1000 + STEP).sum())
    check(cams_alarmed == [MOVED] and early == 0,
          "%s: calibration_health.csv: %d windows, alarms only on camera %s, %d before the step"
          % (mode, len(windows["camera_id"]), cams_alarmed, early))


sim_dir, groups = simulate()
check(len(groups) == N, "the simulator gave %d exposures" % len(groups))
for mode in ("flag", "correct", "exclude"):
    out = fly(mode, sim_dir, groups)
    live = check_live(mode, out)
    check_replay(mode, out, live)
sys.exit(1 if check.failures else 0)
