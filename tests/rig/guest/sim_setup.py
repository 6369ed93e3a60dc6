#!/usr/bin/env python3
"""What the host needs from a storetrack-sim run (--out SIM_DIR), as tools/testpoint makes it.

  sim_setup.py SCENARIO.json SIM_DIR SETUP_DIR

SETUP_DIR gets rig_calibration.json (the calibrated rig: truth + calibration errors),
pylon_survey.json and store_survey.json (surveys with survey errors; the pendulum board stands in
for the store), initial_marks.json (the marks at the first exposure + 1 mm survey noise, as an
installation survey would give them) and setup.json (exposures, frame rate, camera/unit ids).
Same extraction as tools/testpoint step 3, so rig tests and test points set the host up alike.
"""
import csv
import json
import os
import random
import shutil
import sys


def main():
    if len(sys.argv) != 4:
        print(__doc__.strip().splitlines()[2].strip(), file=sys.stderr)
        return 2
    scenario = json.load(open(sys.argv[1]))
    sim, setup = sys.argv[2], sys.argv[3]
    os.makedirs(setup, exist_ok=True)
    shutil.copy(os.path.join(sim, "rig_calibrated.json"), os.path.join(setup, "rig_calibration.json"))
    shutil.copy(os.path.join(sim, "survey_pylon.json"), os.path.join(setup, "pylon_survey.json"))
    body = next(n for n in ("store", "pendulum")
                if os.path.exists(os.path.join(sim, f"survey_{n}.json")))
    shutil.copy(os.path.join(sim, f"survey_{body}.json"), os.path.join(setup, "store_survey.json"))
    rng = random.Random(12345)
    marks, first = [], None
    with open(os.path.join(sim, "truth_marks.csv"), newline="") as f:
        for row in csv.DictReader(f):
            if first is None:
                first = row["trigger_seq"]
            if row["trigger_seq"] != first:
                break
            marks.append({"id": int(row["mark_id"]),
                          "p_w_m": [float(row[k]) + rng.gauss(0.0, 1e-3)
                                    for k in ("x_w_m", "y_w_m", "z_w_m")]})
    json.dump({"marks": marks}, open(os.path.join(setup, "initial_marks.json"), "w"), indent=1)
    cams = [{"camera_id": c["camera_id"], "unit_id": c["unit_id"]} for c in scenario["cameras"]]
    json.dump({"num_exposures": scenario["timing"]["num_exposures"],
               "frame_rate_hz": scenario["timing"]["frame_rate_hz"], "cameras": cams},
              open(os.path.join(setup, "setup.json"), "w"), indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
