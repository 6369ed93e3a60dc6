#!/usr/bin/env python3
"""Scale-bar recordings through the real storetrack-host, for storetrack-eval lme
(docs/evaluation.md, VDI/VDE 2634-1).

  scale_bar_recordings.py SIM_BIN HOST_BIN ROOT OUT [--repetitions N] [--seed S]

For repetition r (seed S + r - 1, its own calibration and bar-survey draw): storetrack-sim
--scenario scale_bars (fast-mode observations) -> its observations.udp replayed over loopback
UDP at the scenario's frame rate -> storetrack-host (calibrated rig, pylon survey, the initial
mark positions of every mark, bars included, as an installation survey gives them; the matcher
identifies the bars' marks from them) --marks-csv OUT/repNN.csv. The host identifies marks of
surveyed bodies only, so its store survey is the frame holding the bars: the bars' 14 marks as
one rigid body, surveyed in the pylon frame (0.2 mm). OUT/bars.json: the bar set as calibrated
(repetition 1's storetrack-sim scale_bars.json).
Then: storetrack-eval lme OUT/rep*.csv --bars OUT/bars.json -o OUT/lme.json
"""
import argparse
import csv
import json
import os
import shutil
import socket
import struct
import subprocess
import sys
import time

HDR = 12  # link header of a datagram (common/msg)


def read_datagrams(path):
    """observations.udp: each datagram prefixed by its big-endian u32 length."""
    data, out, i = open(path, "rb").read(), [], 0
    while i + 4 <= len(data):
        n = struct.unpack_from(">I", data, i)[0]
        out.append(data[i + 4:i + 4 + n])
        i += 4 + n
    return out


def exposure_count(datagrams):
    seqs = {struct.unpack_from(">I", d, HDR + 2)[0] for d in datagrams
            if len(d) >= HDR + 34 and d[3] == 0x01}
    return len(seqs)


def bar_frame_survey(scenario, truth_marks_csv, path, sigma_m=0.0002):
    """The bars' marks as one rigid body (the frame holding the bars, surveyed in the pylon frame
    at exposure 0, sigma_m per axis): the host identifies marks of surveyed bodies only."""
    t_w_p = scenario["T_w_p"]
    if any(abs(a) > 0 for a in t_w_p["ypr_deg"]):
        sys.exit("scale_bar_recordings.py: T_w_p with a rotation is not supported")
    marks, first = [], None
    with open(truth_marks_csv, newline="") as f:
        for row in csv.DictReader(f):
            first = first or row["trigger_seq"]
            if row["trigger_seq"] != first:
                break
            if 300 <= int(row["mark_id"]) < 400:
                p = [float(row[k]) - t for k, t in zip(("x_w0_m", "y_w0_m", "z_w0_m"),
                                                     t_w_p["translation_m"])]
                marks.append({"id": int(row["mark_id"]), "p_body_m": p, "sigma_m": sigma_m})
    json.dump({"format": "storetrack-survey", "version": 1, "name": "scale-bar frame",
               "frame": "s", "mark_diameter_m": 0.015, "marks": marks}, open(path, "w"), indent=1)


def one_repetition(a, sim_setup, r, port):
    seed = a.seed + r - 1
    sim_dir = os.path.join(a.out, "sim%02d" % r)
    scenario_path = os.path.join(a.root, "common/sim/scenarios/scale_bars.json")
    subprocess.run([a.sim, "--scenario", scenario_path,
                    "--seed", str(seed), "--out", sim_dir, "--mode", "observations"],
                   check=True, stdout=subprocess.DEVNULL)
    sim_setup.write_initial_marks(os.path.join(sim_dir, "truth_marks.csv"),
                                  os.path.join(sim_dir, "initial_marks.json"))
    scenario = json.load(open(scenario_path))
    bar_frame_survey(scenario, os.path.join(sim_dir, "truth_marks.csv"),
                     os.path.join(sim_dir, "store_stand_in.json"))
    if r == 1:
        shutil.copy(os.path.join(sim_dir, "scale_bars.json"), os.path.join(a.out, "bars.json"))
    datagrams = read_datagrams(os.path.join(sim_dir, "observations.udp"))
    marks_csv = os.path.join(a.out, "rep%02d.csv" % r)
    if os.path.exists(marks_csv):
        os.remove(marks_csv)  # the host never overwrites: it would number a new file
    host = subprocess.Popen(
        [a.host, "--calibration", os.path.join(sim_dir, "rig_calibrated.json"),
         "--pylon-survey", os.path.join(sim_dir, "survey_pylon.json"),
         "--store-survey", os.path.join(sim_dir, "store_stand_in.json"),
         "--initial-marks", os.path.join(sim_dir, "initial_marks.json"),
         "--udp-port", str(port), "--udp-bind", "127.0.0.1", "--marks-csv", marks_csv,
         "--max-wait-ms", "500", "--idle-exit-s", "1",
         "--expect-exposures", str(exposure_count(datagrams)), "--log-level", "warn"],
        stdout=open(os.path.join(sim_dir, "host.log"), "w"), stderr=subprocess.STDOUT)
    time.sleep(0.5)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for d in datagrams:
        tx.sendto(d, ("127.0.0.1", port))
        time.sleep(0.0005)
    if host.wait(timeout=60) != 0:
        sys.exit("scale_bar_recordings.py: storetrack-host failed, see " +
                 os.path.join(sim_dir, "host.log"))
    print("repetition %d (seed %d): %s" % (r, seed, marks_csv))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sim")
    ap.add_argument("host")
    ap.add_argument("root")
    ap.add_argument("out")
    ap.add_argument("--repetitions", type=int, default=10)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    sys.path.insert(0, os.path.join(a.root, "tools"))
    import sim_setup  # noqa: E402
    os.makedirs(a.out, exist_ok=True)
    port = 21000 + os.getpid() % 900 * 2
    for r in range(1, a.repetitions + 1):
        one_repetition(a, sim_setup, r, port)
    print("storetrack-eval lme %s/rep*.csv --bars %s/bars.json -o %s/lme.json"
          % (a.out, a.out, a.out))


if __name__ == "__main__":
    main()
