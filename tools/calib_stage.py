#!/usr/bin/env python3
"""The main job's calibration stage (tools/testpoint; docs/calibration.md, "The main job's
calibration stage"): the hangar procedure on the simulator, so the host flies the test point
with a calibration storetrack-calib made, not the simulator's.

  calib_stage.py --sim SIM --calib CALIB --scenario SCENARIO.json --seed S \\
                 --sim-dir SIM_DIR --out OUT [--board-common-views N] [--board-single-views N]

  1. storetrack-sim --mode boards: chessboard images of every camera with known truth (fresh
     image noise per seed) -> OUT/boards/cam<id>/*.png, OUT/boards/truth.json
  2. storetrack-calib detect, per camera, on EVERY image of the camera (the board's size and
     square from the board's certificate, here truth.json) -> OUT/cam<id>.csv; detect refuses
     the images without a whole board itself, each with its reason. Afterwards, and only to
     score detect, truth.json: accepted vs truly whole images, lost whole images, corner ids
     (the stage fails on a wrong id or an accepted board not in the image)
  3. storetrack-calib rig (bundle adjustment, camera 0 = S_r) -> OUT/rig.json
  4. storetrack-calib register: S_r -> S_w from the total-station survey of the pylon marks in
     S_w and their hangar observations (SIM_DIR/survey_aircraft.json, registration_marks.csv,
     written by the storetrack-sim run of the same scenario and seed) -> OUT/registered.json
  5. OUT/rig_calibration.json: registered.json with each camera's unit id (the installation,
     scenario.json) and trigger-latency calibration (exposure_offset_ns and its sigma, from the
     simulator's rig_calibrated.json: a bench measurement storetrack-calib does not make).
  6. OUT/calibration_summary.json: per-camera RMS, registration residuals, detection score,
     timings; printed.

Exit 0 ok, 1 a step failed (its log in OUT/logs), 2 bad arguments.
"""
import argparse
import concurrent.futures
import json
import math
import os
import subprocess
import sys
import time


def run(step, cmd, log):
    """Runs one program, its output to log; returns seconds, raises on failure."""
    t0 = time.monotonic()
    with open(log, "w") as f:
        rc = subprocess.call(cmd, stdout=f, stderr=subprocess.STDOUT)
    if rc != 0:
        tail = open(log).read().splitlines()[-15:]
        sys.exit("calib_stage: %s failed (exit %d, log %s):\n  %s\n  %s" % (
            step, rc, log, " ".join(cmd), "\n  ".join(tail)))
    return time.monotonic() - t0


def board_spec(truth):
    """(cols, rows, square_m) of the board from the board set's truth file."""
    b = truth["board"]
    return int(b["cols"]), int(b["rows"]), float(b["square_m"])


def frame_of(path):
    """The board set's frame number of an image, from its file name (frame_NNNN.ext)."""
    return int(os.path.basename(path).split("_", 1)[1].split(".", 1)[0])


def camera_images(out):
    """camera id -> every board image of that camera (sorted by name, so by frame)."""
    boards = os.path.join(out, "boards")
    cams = {}
    for d in sorted(os.listdir(boards)):
        if d.startswith("cam") and os.path.isdir(os.path.join(boards, d)):
            cams[int(d[3:])] = [os.path.join(boards, d, f)
                                for f in sorted(os.listdir(os.path.join(boards, d)))
                                if f.startswith("frame_")]
    return cams


def renumber_frames(csv_path, frames):
    """detect numbers frames by position in its image list; the rig step needs the board set's
    frame numbers (one board pose = one frame across cameras): position i -> frames[i], in the
    rows and in the '# frame,' comment lines."""
    lines = open(csv_path).read().splitlines()
    out, header_seen = [], False
    for line in lines:
        if line.startswith("# frame,"):
            _, pos, src = line.split(",", 2)
            line = "# frame,%d,%s" % (frames[int(pos)], src)
        elif line.startswith("#") or not line.strip():
            pass
        elif not header_seen:
            header_seen = True
        else:
            cells = line.split(",")
            cells[1] = str(frames[int(cells[1])])
            line = ",".join(cells)
        out.append(line)
    with open(csv_path, "w") as f:
        f.write("\n".join(out) + "\n")


def score_detection(truth, detections):
    """detect's result against truth.json, AFTER detection (nothing here feeds the calibration).
    detections: (camera id, detect's --report-json, board-set frame of each image position).
    A corner id is right when the detected corner is nearer its own true projection than any
    other's; an accepted view is 'not whole' when truth's planning limits (the board's white
    border >= 12 px inside, squares >= 14 px, <= 60 deg) do not count it, 'not in the image'
    when a true inner corner lies outside the image."""
    views = {(c["camera_id"], f["frame"]): c for f in truth["frames"] for c in f["cameras"]}
    s = {"images": 0, "accepted": 0, "truly_whole": 0, "rejected": 0, "lost": [],
         "accepted_not_whole": [], "accepted_not_in_image": [], "wrong_ids": [],
         "rejections_by_reason": {}, "max_corner_error_px": 0.0}
    for cid, report, frames in detections:
        r = json.load(open(report))
        points = {}
        for pos, pid, x, y in r["points"]:
            points.setdefault(pos, []).append((pid, x, y))
        for img in r["images"]:
            frame = frames[img["frame"]]
            view, name = views[(cid, frame)], "camera %d frame %d" % (cid, frame)
            whole = view["board_whole_in_view"]
            s["images"] += 1
            s["truly_whole"] += int(whole)
            if not img["used"]:
                s["rejected"] += 1
                kind = img["reason"].split(" (", 1)[0]
                s["rejections_by_reason"][kind] = s["rejections_by_reason"].get(kind, 0) + 1
                if whole:
                    s["lost"].append("%s: %s" % (name, img["reason"]))
                continue
            s["accepted"] += 1
            true_px = view["corners_px"]
            w, h = r["image_size"]
            if not all(p is not None and 0 <= p[0] <= w - 1 and 0 <= p[1] <= h - 1
                       for p in true_px):
                s["accepted_not_in_image"].append(name)
            wrong = 0
            for pid, x, y in points.get(img["frame"], []):
                d = [math.hypot(x - p[0], y - p[1]) if p is not None else math.inf
                     for p in true_px]
                if min(range(len(d)), key=d.__getitem__) != pid:
                    wrong += 1
                else:
                    s["max_corner_error_px"] = max(s["max_corner_error_px"], d[pid])
            if wrong:
                s["wrong_ids"].append("%s: %d of %d corner ids wrong" % (
                    name, wrong, len(points.get(img["frame"], []))))
            if not whole:
                inside = min(min(p[0], p[1], w - 1 - p[0], h - 1 - p[1]) for p in true_px)
                s["accepted_not_whole"].append(
                    "%s: incidence %.1f deg, inner corners >= %.0f px inside the image" % (
                        name, view["incidence_deg"], inside))
    return s


def print_detection(s):
    reasons = ", ".join("%s %d" % kv for kv in sorted(s["rejections_by_reason"].items()))
    print("  detect: %d images, %d accepted, %d truly whole (truth.json), %d rejected (%s); "
          "%d whole lost, %d accepted not whole by truth's planning limits, %d with wrong ids, "
          "largest corner error %.3f px" % (
              s["images"], s["accepted"], s["truly_whole"], s["rejected"], reasons,
              len(s["lost"]), len(s["accepted_not_whole"]), len(s["wrong_ids"]),
              s["max_corner_error_px"]))
    for kind in ("lost", "accepted_not_whole", "accepted_not_in_image", "wrong_ids"):
        for line in s[kind]:
            print("    %s: %s" % (kind.replace("_", " "), line))


def merge_installation(registered, scenario, sim_rig, out):
    """registered.json + unit ids (scenario) + latency calibration (simulator's file)."""
    doc = json.load(open(registered))
    units = {c["camera_id"]: c["unit_id"] for c in json.load(open(scenario))["cameras"]}
    timing = {c["camera_id"]: c for c in json.load(open(sim_rig))["cameras"]}
    for cam in doc["cameras"]:
        cid = cam["camera_id"]
        cam["unit_id"] = units[cid]
        cam["exposure_offset_ns"] = timing[cid].get("exposure_offset_ns", 0)
        cam["exposure_offset_sigma_ns"] = timing[cid].get("exposure_offset_sigma_ns", 0)
    doc.setdefault("comment", {})["installation"] = (
        "unit_id from the scenario (installation); exposure_offset_ns and its sigma from the "
        "trigger-latency calibration (the simulator's rig_calibrated.json): tools/calib_stage.py")
    with open(out, "w") as f:
        json.dump(doc, f, indent=1)


def summary_of(out, timings, images):
    """The fit summaries storetrack-calib wrote into the registered file's comments."""
    doc = json.load(open(os.path.join(out, "registered.json")))
    rig = json.load(open(os.path.join(out, "rig.json")))
    cams = []
    for c in doc["cameras"]:
        k = c.get("comment", {})
        cams.append({"camera_id": c["camera_id"], "rms_px": k.get("rms_px"),
                     "intrinsic_fit_rms_px": k.get("intrinsic_fit_rms_px"),
                     "views": len(k.get("views", [])), "points_used": k.get("points_used"),
                     "points_rejected": k.get("points_rejected"),
                     "baseline_m": k.get("baseline_m"), "baseline_sigma_m": k.get("baseline_sigma_m")})
    reg = doc["comment"]
    cov = reg["T_r_w_covariance"]

    def rms_sd(m):  # rms standard uncertainty per axis: rotation [rad], translation [m]
        d = [max(0.0, m[i][i]) for i in range(6)]
        return [(sum(d[:3]) / 3) ** 0.5, (sum(d[3:]) / 3) ** 0.5]

    return {"images": images, "seconds": timings,
            "rig": {"rms_px": rig["comment"]["rms_px"],
                    "residual_sigma_px": rig["comment"]["residual_sigma_px"],
                    "points_used": rig["comment"]["points_used"],
                    "points_rejected": rig["comment"]["points_rejected"],
                    "frames": rig["comment"]["frames"]},
            "cameras": cams,
            "registration": {"chi2": reg["chi2"], "dof": reg["dof"], "p_value": reg["p_value"],
                             "marks": reg["marks"], "skipped": reg["skipped"],
                             "T_r_w_sigma": {s: rms_sd(cov[s]) for s in
                                             ("total", "centroid", "calibration", "survey")}}}


def print_summary(s):
    print("  %d board images; rig RMS %.3f px (residual sigma %.3f px), %d points, %d rejected"
          % (s["images"], s["rig"]["rms_px"], s["rig"]["residual_sigma_px"],
             s["rig"]["points_used"], s["rig"]["points_rejected"]))
    for c in s["cameras"]:
        base = "" if c["camera_id"] == 0 else ", baseline %.1f +/- %.3f mm" % (
            c["baseline_m"] * 1e3, c["baseline_sigma_m"] * 1e3)
        print("  camera %d: %d views, RMS %.3f px (own intrinsic fit %.3f px), %d rejected%s"
              % (c["camera_id"], c["views"], c["rms_px"], c["intrinsic_fit_rms_px"],
                 c["points_rejected"], base))
    r = s["registration"]
    used = [m for m in r["marks"] if m["used"]]
    res = max((sum(x * x for x in m["residual_r_m"]) ** 0.5 for m in used), default=float("nan"))
    t = r["T_r_w_sigma"]["total"]
    print("  registration: %d marks, largest residual %.3f mm, chi2 %.2f / %d dof (p %.3f), "
          "u(T_r_w) %.1f mdeg / %.3f mm rms per axis" % (
              len(used), res * 1e3, r["chi2"], r["dof"], r["p_value"],
              t[0] * 180e3 / 3.141592653589793, t[1] * 1e3))
    print("  seconds: " + ", ".join("%s %.1f" % kv for kv in s["seconds"].items()))


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sim", required=True, help="storetrack-sim")
    ap.add_argument("--calib", required=True, help="storetrack-calib")
    ap.add_argument("--scenario", required=True, help="scenario JSON as run")
    ap.add_argument("--seed", required=True, type=int)
    ap.add_argument("--sim-dir", required=True, help="storetrack-sim --out of the same seed")
    ap.add_argument("--out", required=True)
    ap.add_argument("--board-common-views", type=int, help="storetrack-sim's default if absent")
    ap.add_argument("--board-single-views", type=int, help="storetrack-sim's default if absent")
    a = ap.parse_args()
    os.makedirs(os.path.join(a.out, "logs"), exist_ok=True)
    logs = os.path.join(a.out, "logs")
    timings = {}

    cmd = [a.sim, "--scenario", a.scenario, "--seed", str(a.seed), "--mode", "boards",
           "--out", a.out]
    if a.board_common_views is not None:
        cmd += ["--board-common-views", str(a.board_common_views)]
    if a.board_single_views is not None:
        cmd += ["--board-single-views", str(a.board_single_views)]
    timings["render"] = run("storetrack-sim --mode boards", cmd, os.path.join(logs, "boards.log"))
    truth = json.load(open(os.path.join(a.out, "boards", "truth.json")))
    cols, rows, square = board_spec(truth)

    # One detect per camera, as many at once as there are cores (each is single-threaded), on
    # every image the camera took: detect refuses an image without a whole board itself, with
    # its reason, in ~0.1 s (docs/calibration.md, "Fast rejection"). truth.json is not read
    # until detect has finished, and then only to score it.
    t0, jobs = time.monotonic(), []
    for cid, files in sorted(camera_images(a.out).items()):
        csv = os.path.join(a.out, "cam%d.csv" % cid)
        report = os.path.join(a.out, "detect_cam%d.json" % cid)
        jobs.append(("detect camera %d" % cid,
                     [a.calib, "detect", "--board", "chessboard", "--cols", str(cols), "--rows",
                      str(rows), "--square", repr(square), "--camera", str(cid)] + files +
                     ["-o", csv, "--report-json", report],
                     os.path.join(logs, "detect_cam%d.log" % cid), csv,
                     [frame_of(f) for f in files], cid, report))
    with concurrent.futures.ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        for f in [pool.submit(run, step, cmd, log) for step, cmd, log, *_ in jobs]:
            f.result()
    for _, _, _, csv, frames, _, _ in jobs:
        renumber_frames(csv, frames)
    obs = [csv for _, _, _, csv, *_ in jobs]
    timings["detect"] = time.monotonic() - t0
    detection = score_detection(truth, [(cid, report, frames) for *_, frames, cid, report in jobs])
    with open(os.path.join(a.out, "detection_score.json"), "w") as f:
        json.dump(detection, f, indent=1)
    print_detection(detection)
    if detection["wrong_ids"] or detection["accepted_not_in_image"]:
        sys.exit("calib_stage: detect accepted %d view(s) with wrong corner ids and %d with the "
                 "board not in the image (truth.json; %s)" % (
                     len(detection["wrong_ids"]), len(detection["accepted_not_in_image"]),
                     os.path.join(a.out, "detection_score.json")))

    timings["rig"] = run("rig", [a.calib, "rig"] + obs + [
        "-o", os.path.join(a.out, "rig.json"), "--residuals", os.path.join(a.out, "rig_residuals.csv")],
        os.path.join(logs, "rig.log"))
    timings["register"] = run("register", [
        a.calib, "register", os.path.join(a.out, "rig.json"),
        "--survey", os.path.join(a.sim_dir, "survey_aircraft.json"),
        "--observations", os.path.join(a.sim_dir, "registration_marks.csv"),
        "-o", os.path.join(a.out, "registered.json"),
        "--residuals", os.path.join(a.out, "registration_residuals.csv")],
        os.path.join(logs, "register.log"))
    merge_installation(os.path.join(a.out, "registered.json"), a.scenario,
                       os.path.join(a.sim_dir, "rig_calibrated.json"),
                       os.path.join(a.out, "rig_calibration.json"))
    s = summary_of(a.out, timings, detection["accepted"])
    s["detection"] = {k: detection[k] for k in (
        "images", "accepted", "truly_whole", "rejected", "lost", "accepted_not_whole",
        "wrong_ids", "rejections_by_reason", "max_corner_error_px")}
    with open(os.path.join(a.out, "calibration_summary.json"), "w") as f:
        json.dump(s, f, indent=1)
    print_summary(s)
    return 0


if __name__ == "__main__":
    sys.exit(main())
