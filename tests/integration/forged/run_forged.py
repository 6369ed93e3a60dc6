#!/usr/bin/python3
"""One forged datagram, end to end (issue 31): storetrack-sim's observations of the main job's
test point (store_separation, 220 exposures, 4 cameras on units 0 and 1) replayed into the real
storetrack-host from the units' own address, with ONE extra datagram: a copy of camera 1's
observation (unit 0, correct framing and CRC) renumbered LEAD exposures ahead, its times moved
with it (the worst case: sequence and time agree with a future trigger edge).

Settings (--settings):
  testpoint   tools/testpoint's host: aligner max_wait 5 s, max_pending = the run
  production  the host's defaults: 10 ms wait, 64 pending
  gate        production, --min-cameras 3, and three exposures made too weak to be samples: one
              only camera 0 sent (the aligner drops it), one whose cameras all saw nothing
              (cameras_used 0), one where only cameras 0 and 1 saw marks (cameras_used <= 2)

Checked: the forged datagram costs at most --max-lost of the samples the same run without it
gives (run both: --lead 0 is the reference run), no sample anywhere (CSV, Chapter 10, iNET-X)
has cameras_used 0 or fewer than min_cameras, the outputs agree sample for sample, and the host
accounts for every exposure: released = processed = written + withheld by reason.

The replay is paced (--fps, default 100; the main job's units deliver about 20-50 exposures/s of
host time on two cores): slow motion, the exposures keep their 400 fps time stamps.

With --clearance-geometry G --clearance-threshold-m X (docs/clearance.md, "In the host"):
the host evaluates the clearance per sample; checked: every valid sample carries a finite
clearance, u > 0 and lower bound <= distance, status bit 8 clearance_alarm exactly on the samples
whose lower bound is below X, and stats.json counts them and their episodes. The host's
--clearance-csv (every aircraft part per sample) against truth: one row per part of every sample
with a clearance, the nearest part's row equal to the FTI CSV's clearance fields (float32), and
for the toy geometry (store triangle under horizontal part planes z = PLANES[part]) the closed
forms: distance = the lowest store vertex's height under the plane (store vertices posed by the
FTI CSV's pose, yaw-pitch-roll Z-Y'-X''), the part's closest point the store point projected onto
the plane, distance = |p_store - p_aircraft|, normal = (p_store - p_aircraft) / distance, the
store point on the posed store triangle. With --post P: storetrack-post's --clearance-csv from
the recording byte-identical to the host's; refusals (exit 2, nothing written): post over an
existing file, the host without a clearance geometry; without --clearance-geometry, post's
--clearance-csv of the recording (which has none).

Usage: run_forged.py SIM HOST ROOT OUT [--settings S] [--lead N] [--fps F] [--max-lost N]
                     [--clearance-geometry G --clearance-threshold-m X [--post P]]
"""
import argparse
import csv
import json
import math
import os
import socket
import struct
import subprocess
import sys
import threading
import time
import zlib

import numpy as np

ap = argparse.ArgumentParser()
ap.add_argument("sim")
ap.add_argument("host")
ap.add_argument("root")
ap.add_argument("out")
ap.add_argument("--settings", choices=("testpoint", "production", "gate"), default="testpoint")
ap.add_argument("--leads", default="600", help="comma-separated leads; 0 = no forged datagram")
ap.add_argument("--fps", type=float, default=100.0)
ap.add_argument("--max-lost", type=int, default=5)
ap.add_argument("--ch10-dump", default="",
                help="rig_ch10_dump (the project's independent Chapter 10 reader): also check "
                     "every recorded sample's cameras_used and trigger_seq")
ap.add_argument("--clearance-geometry", default="", help="clearance geometry file (host config)")
ap.add_argument("--clearance-threshold-m", type=float, default=0.3)
ap.add_argument("--post", default="", help="storetrack-post: replay the clearance CSV")
a = ap.parse_args()
sys.path.insert(0, os.path.join(a.root, "tools"))
sys.path.insert(0, os.path.join(a.root, "host", "report"))
import sim_setup  # noqa: E402
from host_listening import wait_until_listening  # noqa: E402
from storetrack_report import Checks, read_ch10, read_csv  # noqa: E402

HDR = 12
PERIOD_NS = 2_500_000
FORGED_AT = 50          # injected before this exposure's observations
FORGED_CAMERA = 1       # unit 0
# The toy clearance geometry (tests/integration/forged/clearance): the store triangle's vertices
# (frame s) and each aircraft part's plane height z [m] in frame p, in file order.
STORE_VERTICES = [(0.0, 0.0, 0.0), (0.5, 0.0, 0.0), (0.0, 0.3, 0.0)]
PLANES = {"wing": -0.5, "tank": -3.0}
WEAK = {100: "one_camera", 120: "no_marks", 140: "two_cameras_marks"}  # --settings gate
os.makedirs(a.out, exist_ok=True)


def crc(b):
    return bytes(b) + struct.pack(">I", zlib.crc32(bytes(b)) & 0xFFFFFFFF)


def without_marks(b):
    """The same observation with no mark (the camera saw nothing): 50 bytes (docs/icd.md,
    MarkObservations version 2: mark_count at payload offset 33, the marks from 34)."""
    e = bytearray(b[:HDR + 34])
    e[HDR + 33] = 0
    struct.pack_into(">H", e, 6, len(e) + 4)
    return e


def forged_copy(d, lead):
    f = bytearray(d)
    struct.pack_into(">I", f, HDR + 2, struct.unpack_from(">I", f, HDR + 2)[0] + lead)
    for off in (HDR + 6, HDR + 14):
        struct.pack_into(">q", f, off, struct.unpack_from(">q", f, off)[0] + lead * PERIOD_NS)
    return f


def setup(sim_dir):
    s = json.load(open(os.path.join(a.root, "common", "sim", "scenarios", "store_separation.json")))
    json.dump(s, open(os.path.join(a.out, "scenario.json"), "w"))
    observations = os.path.join(sim_dir, "observations.udp")
    # Kept between runs of one build tree, but not past a rebuilt simulator (the wire format or
    # the scenario may have changed).
    if not os.path.exists(observations) or os.path.getmtime(observations) < os.path.getmtime(a.sim):
        subprocess.run([a.sim, "--scenario", os.path.join(a.out, "scenario.json"), "--seed", "1",
                        "--out", sim_dir, "--mode", "observations"], check=True,
                       stdout=subprocess.DEVNULL)
    sim_setup.write_initial_marks(os.path.join(sim_dir, "truth_marks.csv"),
                                  os.path.join(a.out, "initial_marks.json"))
    return sim_setup.read_observation_groups(os.path.join(sim_dir, "observations.udp"))


def listen_inetx(sock, packets, stop):
    sock.settimeout(0.2)
    while not stop.is_set():
        try:
            packets.append(sock.recv(2048))
        except socket.timeout:
            pass


def run(groups, sim_dir, lead):
    out = os.path.join(a.out, "%s-lead%d" % (a.settings, lead))
    os.makedirs(out, exist_ok=True)
    for f in os.listdir(out):
        os.remove(os.path.join(out, f))  # the host never overwrites a recording
    port = 21000 + os.getpid() % 800 * 4
    inetx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    inetx.bind(("127.0.0.1", port + 1))
    packets, stop = [], threading.Event()
    listener = threading.Thread(target=listen_inetx, args=(inetx, packets, stop))
    listener.start()
    config = {"aligner": {"max_wait_ms": 5000, "max_pending": len(groups)}} \
        if a.settings == "testpoint" else {}
    if a.clearance_geometry:
        config["clearance"] = {"geometry": os.path.abspath(a.clearance_geometry),
                               "alarm_threshold_m": a.clearance_threshold_m}
    json.dump(config, open(os.path.join(out, "host.json"), "w"))
    args = [a.host, "--calibration", os.path.join(sim_dir, "rig_calibrated.json"),
            "--pylon-survey", os.path.join(sim_dir, "survey_pylon.json"),
            "--store-survey", os.path.join(sim_dir, "survey_store.json"),
            "--initial-marks", os.path.join(a.out, "initial_marks.json"),
            "--udp-port", str(port), "--udp-bind", "127.0.0.1",
            "--udp-source", "0@127.0.0.1", "--udp-source", "1@127.0.0.1",
            "--inetx", "127.0.0.1:%d" % (port + 1), "--csv", os.path.join(out, "fti.csv"),
            "--ch10", os.path.join(out, "out.ch10"), "--stats-json", os.path.join(out, "stats.json"),
            "--config", os.path.join(out, "host.json"), "--idle-exit-s", "6" if a.settings == "testpoint" else "1",
            "--log-level", "warn"]
    if a.clearance_geometry:
        args += ["--clearance-csv", os.path.join(out, "clearance.csv")]
    if a.settings == "gate":
        args += ["--min-cameras", "3"]
    else:  # every exposure is processed: stop at the last one rather than after the idle time
        args += ["--expect-exposures", str(len(groups))]
    host = subprocess.Popen(args, stdout=open(os.path.join(out, "host.log"), "w"),
                            stderr=subprocess.STDOUT)
    try:
        wait_until_listening(host, port, os.path.join(out, "host.log"))
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        dseq = {}
        t0 = time.monotonic() + 0.05

        def send(b):
            u = b[HDR]
            struct.pack_into(">I", b, 8, dseq.get(u, 0) & 0xFFFFFFFF)
            dseq[u] = dseq.get(u, 0) + 1
            tx.sendto(crc(b), ("127.0.0.1", port))

        for k, g in enumerate(groups):
            due = t0 + k / a.fps
            if due > time.monotonic():
                time.sleep(due - time.monotonic())
            if k == FORGED_AT and lead > 0:
                send(forged_copy(g[FORGED_CAMERA], lead))
            for c, d in enumerate(g):
                weak = WEAK.get(k) if a.settings == "gate" else None
                if weak == "one_camera" and c != 0:
                    continue
                if weak == "no_marks" or (weak == "two_cameras_marks" and c >= 2):
                    d = without_marks(d)
                send(bytearray(d))
        host.wait(timeout=60)
    finally:
        if host.poll() is None:
            host.kill()
            host.wait()
        time.sleep(0.3)
        stop.set()
        listener.join()
    return out, host.returncode, packets


def check_clearance(ok, tag, s, fti):
    """The clearance columns and the alarm bit against the threshold, the stats' counts."""
    valid = (fti["status"].astype(int) & 1) == 1
    alarm = (fti["status"].astype(int) >> 8) & 1 == 1
    d, u, lb = fti["clearance"], fti["u_clearance"], fti["clearance_lower_bound"]
    finite = [all(math.isfinite(x) for x in (d[i], u[i], lb[i])) for i in range(len(d))]
    ok(all(f == v for f, v in zip(finite, valid)),
       tag + "clearance finite exactly on the %d valid samples" % int(valid.sum()))
    ok(all(u[i] > 0 and lb[i] <= d[i] for i in range(len(d)) if finite[i]),
       tag + "u > 0 and lower bound <= distance on every sample with a clearance")
    below = [finite[i] and lb[i] < a.clearance_threshold_m for i in range(len(d))]
    ok(all(b == al for b, al in zip(below, alarm)),
       tag + "status bit 8 on exactly the %d samples whose lower bound < %g m"
       % (sum(below), a.clearance_threshold_m))
    episodes = sum(1 for i in range(len(below)) if below[i] and (i == 0 or not below[i - 1]))
    c = s.get("clearance", {})
    ok(c.get("samples_evaluated") == int(valid.sum()) and c.get("alarm_samples") == sum(below)
       and c.get("alarm_episodes") == episodes,
       tag + "stats.json clearance %s: evaluated %d, alarm samples %d, episodes %d"
       % (c, int(valid.sum()), sum(below), episodes))


def rotation_zyx(yaw, pitch, roll):
    """R = Rz(yaw) Ry(pitch) Rx(roll) (docs/fti-output.md: pylon->store Z-Y'-X'')."""
    cy, sy, cp, sp, cr, sr = (math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch),
                              math.cos(roll), math.sin(roll))
    return [[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr]]


def on_store_triangle(p, R, t, tol):
    """p (frame p) on the posed store triangle: back in frame s, z = 0 and inside the triangle."""
    d = [p[i] - t[i] for i in range(3)]
    q = [sum(R[j][i] * d[j] for j in range(3)) for i in range(3)]  # R^T (p - t)
    return abs(q[2]) < tol and q[0] > -tol and q[1] > -tol and q[0] / 0.5 + q[1] / 0.3 < 1 + tol


def clearance_row_errors(row, fti_row):
    """One row against the closed forms of its plane part; the largest error [m] of each check."""
    z_plane = PLANES[row["part"]]
    ps = [float(row["p_store_%s_p" % c]) for c in "xyz"]
    pa = [float(row["p_aircraft_%s_p" % c]) for c in "xyz"]
    n = [float(row["normal_%s_p" % c]) for c in "xyz"]
    d = float(row["clearance_m"])
    R = rotation_zyx(fti_row["yaw"], fti_row["pitch"], fti_row["roll"])
    t = [fti_row["x"], fti_row["y"], fti_row["z"]]
    lowest = min(sum(R[2][k] * v[k] for k in range(3)) + t[2] for v in STORE_VERTICES)
    projection = max(abs(pa[0] - ps[0]), abs(pa[1] - ps[1]), abs(pa[2] - z_plane))
    norm = math.dist(ps, pa)
    normal = max(abs(n[i] - (ps[i] - pa[i]) / norm) for i in range(3))
    return {"distance vs lowest posed vertex": abs(d - (lowest - z_plane)),
            "closest part point vs projection": projection,
            "distance vs |p_store - p_aircraft|": abs(d - norm),
            "normal vs (p_store - p_aircraft) / d": normal,
            "store point off the posed triangle": 0.0 if on_store_triangle(ps, R, t, 1e-5) else 1.0}


def check_clearance_csv(ok, tag, out, fti):
    """The host's every-part CSV against the FTI CSV and the toy geometry's closed forms."""
    path = os.path.join(out, "clearance.csv")
    with open(path, newline="") as f:
        reader = csv.reader(f)
        header = [h.split(" [")[0] for h in next(reader)]
        rows = [dict(zip(header, r)) for r in reader]
    parts = list(PLANES)
    fti_rows = {int(q): {k: fti[k][i] for k in ("x", "y", "z", "yaw", "pitch", "roll", "clearance",
                                                 "u_clearance", "clearance_lower_bound",
                                                 "clearance_part")}
                for i, q in enumerate(fti["trigger_seq"])}
    with_clearance = [q for q, r in fti_rows.items() if math.isfinite(r["clearance"])]
    ok(len(rows) == len(with_clearance) * len(parts)
       and [int(r["trigger_seq"]) for r in rows[::len(parts)]] == with_clearance
       and all(r["part"] == parts[i % len(parts)] for i, r in enumerate(rows)),
       tag + "clearance.csv: %d rows = %d samples with a clearance x %d parts, in file order"
       % (len(rows), len(with_clearance), len(parts)))
    f32 = [(np.float32(float(r["clearance_m"])), np.float32(float(r["u_clearance_m"])),
            np.float32(float(r["clearance_lower_bound_m"])))
           for r in rows if r["part"] == parts[int(fti_rows[int(r["trigger_seq"])]["clearance_part"])]]
    want = [(np.float32(fti_rows[q]["clearance"]), np.float32(fti_rows[q]["u_clearance"]),
             np.float32(fti_rows[q]["clearance_lower_bound"])) for q in with_clearance]
    ok(f32 == want, tag + "the nearest part's row = the FTI CSV's clearance, u, lower bound "
       "(float32) on all %d samples" % len(want))
    worst = {}
    for r in rows:
        for k, e in clearance_row_errors(r, fti_rows[int(r["trigger_seq"])]).items():
            worst[k] = max(worst.get(k, 0.0), e)
    # The FTI pose is float32 (~1e-7 relative): 1e-5 m; the CSV's points have 9 digits.
    tolerance = {"distance vs lowest posed vertex": 1e-5, "closest part point vs projection": 1e-8,
                 "distance vs |p_store - p_aircraft|": 1e-8, "normal vs (p_store - p_aircraft) / d":
                 1e-7, "store point off the posed triangle": 0.5}
    ok(rows and all(worst[k] <= tolerance[k] for k in tolerance),
       tag + "closed forms on all %d rows, worst: %s" % (len(rows), ", ".join(
           "%s %.2g (<= %g)" % (k, worst.get(k, float("nan")), tolerance[k]) for k in tolerance)))
    alarms = [int(r["alarm"]) == (float(r["clearance_lower_bound_m"]) < a.clearance_threshold_m)
              for r in rows]
    ok(all(alarms), tag + "alarm column = the part's lower bound < %g m" % a.clearance_threshold_m)


def check_post_clearance(ok, tag, out, sim_dir):
    """storetrack-post's replay writes the host's clearance.csv byte for byte; its refusals."""
    replayed = os.path.join(out, "clearance_post.csv")
    for f in (replayed,):
        if os.path.exists(f):
            os.remove(f)
    r = subprocess.run([a.post, os.path.join(out, "out.ch10"), "--clearance-csv", replayed],
                       capture_output=True, text=True)
    same = r.returncode == 0 and open(replayed, "rb").read() == \
        open(os.path.join(out, "clearance.csv"), "rb").read()
    ok(same, tag + "storetrack-post --clearance-csv from the recording byte-identical to the "
       "host's (exit %d %s)" % (r.returncode, r.stderr.strip()[-300:]))
    before = open(replayed, "rb").read()
    r = subprocess.run([a.post, os.path.join(out, "out.ch10"), "--clearance-csv", replayed,
                        "--csv", os.path.join(out, "refused_post.csv")], capture_output=True,
                       text=True)
    ok(r.returncode == 2 and replayed in r.stderr and open(replayed, "rb").read() == before
       and not os.path.exists(os.path.join(out, "refused_post.csv")),
       tag + "post over an existing --clearance-csv: exit %d, named, nothing written (%s)"
       % (r.returncode, r.stderr.strip()))
    json.dump({}, open(os.path.join(out, "no_geometry.json"), "w"))
    refused = [os.path.join(out, n) for n in ("refused_clearance.csv", "refused_fti.csv")]
    r = subprocess.run([a.host, "--calibration", os.path.join(sim_dir, "rig_calibrated.json"),
                        "--pylon-survey", os.path.join(sim_dir, "survey_pylon.json"),
                        "--store-survey", os.path.join(sim_dir, "survey_store.json"),
                        "--udp-port", "1", "--udp-bind", "127.0.0.1",
                        "--config", os.path.join(out, "no_geometry.json"),
                        "--clearance-csv", refused[0], "--csv", refused[1]],
                       capture_output=True, text=True)
    ok(r.returncode == 2 and "--clearance-csv" in r.stderr and "clearance.geometry" in r.stderr
       and not any(os.path.exists(f) for f in refused),
       tag + "host --clearance-csv without a clearance geometry: exit %d, named, nothing "
       "written (%s)" % (r.returncode, r.stderr.strip()))


def check_post_refuses_clearance_csv(ok, tag, out):
    """A recording without a clearance geometry: post's --clearance-csv refused, nothing written."""
    refused = [os.path.join(out, n) for n in ("refused_clearance.csv", "refused_fti.csv")]
    r = subprocess.run([a.post, os.path.join(out, "out.ch10"), "--clearance-csv", refused[0],
                        "--csv", refused[1]], capture_output=True, text=True)
    ok(r.returncode == 2 and refused[0] in r.stderr and "--clearance-geometry" in r.stderr
       and not any(os.path.exists(f) for f in refused),
       tag + "post --clearance-csv of a recording without a clearance geometry: exit %d, named, "
       "nothing written (%s)" % (r.returncode, r.stderr.strip()))


def check_run(ok, out, rc, packets, lead, groups):
    s = json.load(open(os.path.join(out, "stats.json")))
    al = s["aligner"]
    fti = read_csv(os.path.join(out, "fti.csv"))
    n = len(fti["trigger_seq"]) if fti else 0
    ch10 = read_ch10(os.path.join(out, "out.ch10"))
    min_cameras = 3 if a.settings == "gate" else 1
    tag = "[%s, lead %d] " % (a.settings, lead)
    ok(rc == 0, tag + "host exited 0")
    released = al["exposures_complete"] + al["exposures_partial_timeout"] + al["exposures_partial_overflow"]
    withheld = s["samples_withheld"]
    ok(released == s["exposures_processed"] == s["samples_written"] + sum(withheld.values()),
       tag + "released %d = processed %d = written %d + withheld %s"
       % (released, s["exposures_processed"], s["samples_written"], withheld))
    ok(n == s["samples_written"] and ch10 is not None and ch10["messages"] == n and len(packets) == n,
       tag + "one sample per written exposure in every output: CSV %d, Chapter 10 %s, iNET-X %d, written %d"
       % (n, ch10 and ch10["messages"], len(packets), s["samples_written"]))
    dropped = sum(v for k, v in al.items() if k.startswith("dropped_"))
    ok(al["observations_in"] == al["observations_used"] + dropped,
       tag + "every observation used or dropped by a counted reason")
    if a.clearance_geometry and n:
        check_clearance(ok, tag, s, fti)
        check_clearance_csv(ok, tag, out, fti)
        if a.post:
            check_post_clearance(ok, tag, out, os.path.join(a.out, "sim"))
    elif a.post:
        check_post_refuses_clearance_csv(ok, tag, out)
    used_csv = [int(x) for x in fti["cameras_used"]] if n else []
    used_inetx = [p[-166 + 13] for p in packets]  # FTI parameter block v3: the packet's last 166 bytes
    ok(all(u >= max(1, min_cameras) for u in used_csv + used_inetx),
       tag + "no sample with cameras_used below %d (CSV min %s, iNET-X min %s)"
       % (max(1, min_cameras), min(used_csv, default=None), min(used_inetx, default=None)))
    seq0 = struct.unpack_from(">I", groups[0][0], HDR + 2)[0]
    seqs = [int(x) for x in fti["trigger_seq"]] if n else []
    if a.ch10_dump:
        dump = json.loads(subprocess.run([a.ch10_dump, os.path.join(out, "out.ch10")], check=True,
                                         capture_output=True, text=True).stdout)
        rec = dump["samples"]
        ok(dump["fti_block_errors"] == 0 and [r["trigger_seq"] for r in rec] == seqs
           and all(r["cameras_used"] >= max(1, min_cameras) for r in rec),
           tag + "Chapter 10 (independent reader): the CSV's %d samples, none with cameras_used "
           "below %d" % (len(rec), max(1, min_cameras)))
    ok(all(seq0 <= q < seq0 + len(groups) for q in seqs), tag + "every sample is an exposure the rig took")
    valid = int(sum((int(x) & 1) for x in fti["status"])) if n else 0
    print("%s%d samples written, %d valid of %d exposures; aligner: quarantined %d, late %d, "
          "partial %d, too few cameras %d; withheld %s"
          % (tag, n, valid, len(groups), al["dropped_quarantined"], al["dropped_late"],
             al["exposures_partial_timeout"] + al["exposures_partial_overflow"],
             al["exposures_dropped_too_few_cameras"], withheld))
    if a.settings == "gate":
        weak_seqs = {seq0 + k for k in WEAK}
        ok(not weak_seqs & set(seqs), tag + "none of the three weak exposures is a sample")
        ok(al["exposures_dropped_too_few_cameras"] >= 1 and withheld["no_camera_used"] >= 1
           and sum(withheld.values()) >= 2,
           tag + "counted by reason: aligner too few cameras %d, withheld %s"
           % (al["exposures_dropped_too_few_cameras"], withheld))
    return valid


def main():
    sim_dir = os.path.join(a.out, "sim")
    groups = setup(sim_dir)
    if len(groups) != 220 or any(len(g) != 4 for g in groups):
        sys.exit("run_forged.py: expected 220 exposures of 4 cameras from the simulator")
    ok = Checks()
    valid = {}
    for lead in [int(x) for x in a.leads.split(",")]:
        out, rc, packets = run(groups, sim_dir, lead)
        valid[lead] = check_run(ok, out, rc, packets, lead, groups)
    if 0 in valid:
        for lead, v in valid.items():
            if lead:
                ok(valid[0] - v <= a.max_lost,
                   "[%s] lead %d: %d valid samples, %d without the forged datagram (at most %d lost)"
                   % (a.settings, lead, v, valid[0], a.max_lost))
    json.dump(valid, open(os.path.join(a.out, "valid_%s.json" % a.settings), "w"))
    return 1 if ok.failures else 0


if __name__ == "__main__":
    sys.exit(main())
