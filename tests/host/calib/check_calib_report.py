#!/usr/bin/env python3
"""The storetrack-calib reports on a real case (OpenCV's 9x6 stereo chessboard set, tests/data):
detect (both cameras, --report-json), intrinsic (left) and rig (left + right) as documented in
docs/calibration.md, then host/report/storetrack_calib_report.py on each. Checks that every page
and PNG is written and that the report's numbers are the result's: images used and points of
detect's JSON and CSV, the parameters with sigma of the calibration JSON in the page, and the
RMS and per-view RMS of the JSON against the ones recomputed from the residual CSV (an
independent sum over the points). Usage: check_calib_report.py STORETRACK_CALIB REPO OUT_DIR"""
import csv
from html import escape as html_escape
import json
import math
import os
import shutil
import subprocess
import sys

calib, repo, out = sys.argv[1:4]
shutil.rmtree(out, ignore_errors=True)
os.makedirs(out)
images = os.path.join(repo, "tests/data/opencv_stereo_chessboard_9x6/images")
report = os.path.join(repo, "host/report/storetrack_calib_report.py")
frames = ["01", "02", "03", "04", "05", "06", "07", "08", "09", "11", "12", "13", "14"]
failures = []


def check(cond, what):
    print(("ok   " if cond else "FAIL ") + what)
    if not cond:
        failures.append(what)


def run(*args):
    r = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"{' '.join(map(str, args))}: exit {r.returncode}\n{r.stderr}")
    return r.stdout


def o(name):
    return os.path.join(out, name)


def rows(path):
    with open(path) as f:
        return list(csv.DictReader(line for line in f if not line.startswith("#")))


for cam, side in ((0, "left"), (1, "right")):
    run(calib, "detect", "--board", "chessboard", "--cols", 9, "--rows", 6, "--square", 0.025,
        "--camera", cam, *[os.path.join(images, f"{side}{i}.jpg") for i in frames],
        "-o", o(f"{side}.csv"), "--report-json", o(f"{side}_detect.json"))
run(calib, "intrinsic", o("left.csv"), "--camera", 0, "--fix-aspect-ratio",
    "--no-outlier-rejection", "-o", o("left.json"), "--residuals", o("left_res.csv"))
run(calib, "rig", o("left.csv"), o("right.csv"), "--no-outlier-rejection", "-o", o("rig.json"),
    "--residuals", o("rig_res.csv"))
run("/usr/bin/python3", report, o("left_detect.json"), o("detect_report"))
run("/usr/bin/python3", report, o("left.json"), o("intrinsic_report"), "--observations",
    o("left.csv"), "--residuals", o("left_res.csv"))
run("/usr/bin/python3", report, o("rig.json"), o("rig_report"), "--observations", o("left.csv"),
    o("right.csv"), "--residuals", o("rig_res.csv"))

expected = {"detect_report": ["index.html", "detect_coverage.png"],
            "intrinsic_report": ["index.html", "camera0_views.png", "camera0_residuals.png",
                                 "camera0_model_error.png"],
            "rig_report": ["index.html", "camera0_views.png", "camera0_residuals.png",
                           "camera1_views.png", "camera1_residuals.png", "camera0_model_error.png",
                           "camera1_model_error.png"]}
for d, files in expected.items():
    for f in files:
        p = o(os.path.join(d, f))
        check(os.path.isfile(p) and os.path.getsize(p) > 1000 if f.endswith(".png")
              else os.path.isfile(p) and os.path.getsize(p) > 0, f"{d}/{f} written")

det = json.load(open(o("left_detect.json")))
page = open(o("detect_report/index.html")).read()
check(det["images_used"] == 13 and page.count("<td>used</td>") == 13,
      f"detect: 13 images used in the JSON ({det['images_used']}) and the page "
      f"({page.count('<td>used</td>')})")
check(len(det["points"]) == len(rows(o("left.csv"))) == 702,
      f"detect: points of the JSON ({len(det['points'])}) = rows of the CSV "
      f"({len(rows(o('left.csv')))}) = 13 x 54")


def check_fit(doc, residual_csv, page_path, label):
    page = open(page_path).read()
    for cam in doc["cameras"]:
        c, cid = cam["comment"], cam["camera_id"]
        res = [r for r in rows(residual_csv) if int(r["camera"]) == cid and r["rejected"] == "0"]
        sq = [float(r["residual_x_px"]) ** 2 + float(r["residual_y_px"]) ** 2 for r in res]
        rms = math.sqrt(sum(sq) / len(sq))
        check(abs(rms - c["rms_px"]) < 1e-4,
              f"{label} camera {cid}: RMS {c['rms_px']:.5f} px (JSON) = {rms:.5f} px (from the "
              f"{len(sq)} residuals)")
        check(f"RMS {c['rms_px']:.4f} px" in page, f"{label} camera {cid}: page shows that RMS")
        worst = 0.0
        for v in c["views"]:
            s = [float(r["residual_x_px"]) ** 2 + float(r["residual_y_px"]) ** 2
                 for r in res if int(r["frame"]) == v["frame"]]
            worst = max(worst, abs(math.sqrt(sum(s) / len(s)) - v["rms_px"]))
            check(f"<td>{v['frame']}</td><td>{v['rms_px']:.4f}</td>" in page,
                  f"{label} camera {cid} view {v['frame']}: page shows RMS {v['rms_px']:.4f}")
        check(worst < 1e-4, f"{label} camera {cid}: per-view RMS of the JSON = recomputed "
              f"(largest difference {worst:.1e} px)")
        me = cam.get("model_error")
        check(me is not None and html_escape(me["verdict"]) in page,
              f"{label} camera {cid}: the model error verdict of the JSON (run by default) is in "
              f"the page")
        fx = cam["intrinsics"]["fx"]
        sd = cam["intrinsic_covariance"]
        sd_fx = sd["standard_deviations"][0] if isinstance(sd, dict) else math.sqrt(sd[0][0])
        check(f"<td>fx</td><td>{fx:.6g}</td><td>{sd_fx:.3g}</td>" in page,
              f"{label} camera {cid}: page shows fx = {fx:.6g} ± {sd_fx:.3g} px of the JSON")


check_fit(json.load(open(o("left.json"))), o("left_res.csv"),
          o("intrinsic_report/index.html"), "intrinsic")
check_fit(json.load(open(o("rig.json"))), o("rig_res.csv"), o("rig_report/index.html"), "rig")
print(f"{len(failures)} failed" if failures else "all passed")
sys.exit(1 if failures else 0)
