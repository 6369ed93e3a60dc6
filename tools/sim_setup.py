#!/usr/bin/env python3
"""What the host needs from a storetrack-sim run (--out SIM_DIR): the one extraction that
tools/testpoint, the integration tests and the VM rig's tests all use.

  sim_setup.py SCENARIO.json SIM_DIR SETUP_DIR
      SETUP_DIR gets rig_calibration.json (the calibrated rig: truth + calibration errors),
      pylon_survey.json and store_survey.json (surveys with survey errors; the pendulum board
      stands in for the store), initial_marks.json, setup.json (exposures, frame rate,
      camera/unit ids) and store_envelope.json (a host.json fragment, below).
  sim_setup.py --initial-marks TRUTH_MARKS.csv OUT.json [SIGMA_M]
      only initial_marks.json.
  sim_setup.py --store-envelope TRUTH_POSES.csv OUT.json [POSES]
      only the store envelope: {"live": {"store_envelope": [...]}}, POSES (default 24) poses
      T_p_s of the scenario's trajectory, evenly spaced over its exposures, first and last
      included, a pose equal to the one before left out (a store at rest); the live page draws where the store's marks fall along them (docs/live-view.md).

initial_marks.json holds the marks at the first exposure plus Gaussian survey noise, SIGMA_M per
axis (default 1 mm, seeded: the same file for the same simulator run), as the installation survey
would give them.
"""
import csv
import json
import os
import random
import shutil
import struct
import sys

SURVEY_SIGMA_M = 1e-3
SURVEY_SEED = 12345
# MarkObservations on the wire (docs/icd.md): a 12-byte UDP frame header, then the message
# (id 0x01; trigger_seq at +2), a CRC-32 last.
UDP_HEADER_BYTES = 12
OBSERVATION_FIXED_BYTES = 30


def read_observation_groups(observations_udp):
    """The simulator's observations.udp (each datagram behind a big-endian u32 length) as one list
    per exposure of its MarkObservations datagrams, in file order, each without its CRC."""
    groups, last = [], None
    data = open(observations_udp, "rb").read()
    i = 0
    while i + 4 <= len(data):
        n = struct.unpack_from(">I", data, i)[0]
        d = data[i + 4:i + 4 + n]
        i += 4 + n
        if len(d) < UDP_HEADER_BYTES + OBSERVATION_FIXED_BYTES or d[3] != 0x01:
            continue
        seq = struct.unpack_from(">I", d, UDP_HEADER_BYTES + 2)[0]
        if seq != last:
            groups.append([])
            last = seq
        groups[-1].append(bytearray(d[:-4]))
    return groups


def initial_marks(truth_marks_csv, sigma_m=SURVEY_SIGMA_M):
    """The marks of the first exposure in truth_marks.csv, each axis + N(0, sigma_m^2)."""
    rng = random.Random(SURVEY_SEED)
    marks, first = [], None
    with open(truth_marks_csv, newline="") as f:
        for row in csv.DictReader(f):
            if first is None:
                first = row["trigger_seq"]
            if row["trigger_seq"] != first:
                break
            marks.append({"id": int(row["mark_id"]),
                          "p_w_m": [float(row[k]) + (rng.gauss(0.0, sigma_m) if sigma_m else 0.0)
                                    for k in ("x_w_m", "y_w_m", "z_w_m")]})
    if not marks:
        sys.exit("sim_setup.py: no marks in " + truth_marks_csv)
    return {"marks": marks}


def write_initial_marks(truth_marks_csv, out_json, sigma_m=SURVEY_SIGMA_M):
    with open(out_json, "w") as f:
        json.dump(initial_marks(truth_marks_csv, sigma_m), f, indent=1)


def store_envelope(truth_poses_csv, poses=24):
    """T_p_s at `poses` exposures of truth_poses.csv spread evenly over the run, as host.json's
    live.store_envelope entries ({t_m, rotvec_rad})."""
    with open(truth_poses_csv, newline="") as f:
        rows = list(csv.DictReader(f))
    if not rows:
        sys.exit("sim_setup.py: no poses in " + truth_poses_csv)
    count = max(1, min(poses, len(rows)))
    picks = sorted({round(k * (len(rows) - 1) / max(1, count - 1)) for k in range(count)})
    envelope = []
    for k in picks:
        pose = {"t_m": [float(rows[k]["T_p_s_" + a]) for a in ("x_m", "y_m", "z_m")],
                "rotvec_rad": [float(rows[k]["T_p_s_" + a]) for a in ("rx_rad", "ry_rad", "rz_rad")]}
        if not envelope or pose != envelope[-1]:  # a store at rest (captive, static) once
            envelope.append(pose)
    return envelope


def write_store_envelope(truth_poses_csv, out_json, poses=24):
    with open(out_json, "w") as f:
        json.dump({"live": {"store_envelope": store_envelope(truth_poses_csv, poses)}}, f, indent=1)


def write_setup(scenario_json, sim, setup):
    scenario = json.load(open(scenario_json))
    os.makedirs(setup, exist_ok=True)
    shutil.copy(os.path.join(sim, "rig_calibrated.json"), os.path.join(setup, "rig_calibration.json"))
    shutil.copy(os.path.join(sim, "survey_pylon.json"), os.path.join(setup, "pylon_survey.json"))
    body = next(n for n in ("store", "pendulum")
                if os.path.exists(os.path.join(sim, f"survey_{n}.json")))
    shutil.copy(os.path.join(sim, f"survey_{body}.json"), os.path.join(setup, "store_survey.json"))
    write_initial_marks(os.path.join(sim, "truth_marks.csv"), os.path.join(setup, "initial_marks.json"))
    write_store_envelope(os.path.join(sim, "truth_poses.csv"), os.path.join(setup, "store_envelope.json"))
    cams = [{"camera_id": c["camera_id"], "unit_id": c["unit_id"]} for c in scenario["cameras"]]
    with open(os.path.join(setup, "setup.json"), "w") as f:
        json.dump({"num_exposures": scenario["timing"]["num_exposures"],
                   "frame_rate_hz": scenario["timing"]["frame_rate_hz"], "cameras": cams}, f, indent=1)


def main(argv):
    if len(argv) in (3, 4) and argv[0] == "--initial-marks":
        write_initial_marks(argv[1], argv[2], float(argv[3]) if len(argv) == 4 else SURVEY_SIGMA_M)
        return 0
    if len(argv) in (3, 4) and argv[0] == "--store-envelope":
        write_store_envelope(argv[1], argv[2], int(argv[3]) if len(argv) == 4 else 24)
        return 0
    if len(argv) == 3 and not argv[0].startswith("-"):
        write_setup(*argv)
        return 0
    print(__doc__.strip(), file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
