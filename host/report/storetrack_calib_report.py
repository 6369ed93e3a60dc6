#!/usr/bin/env python3
"""storetrack-calib report: HTML page + PNG plots from a storetrack-calib result (docs/calibration.md).

detect (the JSON of `detect --report-json`): per image used / rejected with the reason, the
rejected corners, the coverage of the image by the points of all views (plot and the fraction of
a 10 x 10 grid of cells holding a point).
intrinsic, rig (the calibration JSON they write, -o): per camera the parameter table with sigma,
per-view RMS bars; with --observations and --residuals (the CSVs of detect and of --residuals)
also the residual vectors over the image and the residual histogram against the normal density
of the fit's residual sigma.
register (its registered JSON): T_w_r with sigma, the marks table and residual bars.
The numbers are the result's own; the RMS recomputed from the residual CSV is printed next to it.
Debian packages only (python3-matplotlib, python3-numpy).

Usage: storetrack_calib_report.py RESULT.json OUT_DIR [--observations CSV ...] [--residuals CSV]
"""
import argparse
import csv
import html
import json
import math
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from report_html import table, write_page  # noqa: E402

NAMES = ["fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"]
UNITS = ["px"] * 5 + [""] * 8
COVERAGE_CELLS = 10


def save(fig, path):
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def coverage_fraction(points, width, height):
    """Fraction of a COVERAGE_CELLS x COVERAGE_CELLS grid over the image holding a point."""
    cells = {(min(int(x / width * COVERAGE_CELLS), COVERAGE_CELLS - 1),
              min(int(y / height * COVERAGE_CELLS), COVERAGE_CELLS - 1))
             for x, y in points if 0 <= x < width and 0 <= y < height}
    return len(cells) / COVERAGE_CELLS ** 2


def detect_page(r, out_dir):
    w, h = r["image_size"] or (1, 1)
    fig, ax = plt.subplots(figsize=(7, 7 * h / w + 0.6))
    frames = sorted({p[0] for p in r["points"]})
    for i, f in enumerate(frames):
        xy = np.array([p[2:4] for p in r["points"] if p[0] == f])
        ax.plot(xy[:, 0], xy[:, 1], ".", ms=3, color=f"C{i % 10}")
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_xlabel("x [px]")
    ax.set_ylabel("y [px]")
    ax.set_title(f"points of all {len(frames)} views (colour = view)")
    save(fig, os.path.join(out_dir, "detect_coverage.png"))
    coverage = coverage_fraction([p[2:4] for p in r["points"]], w, h)
    images = [[i["frame"], i["path"], "used" if i["used"] else "REJECTED", i["points"],
               i["reason"]] for i in r["images"]]
    corners = [[c["frame"], c["point_id"], c["reason"]] for c in r["rejected_corners"]]
    board = ", ".join(f"{k} {v}" for k, v in r["board"].items())
    print(f"detect: {r['images_used']} of {len(r['images'])} images used, "
          f"{len(r['points'])} points, coverage {100 * coverage:.0f} % of the image")
    return f"""<h1>storetrack-calib detect: camera {r['camera']}</h1>
<p>Board: {html.escape(board)}. Image {w} x {h} px. {r['images_used']} of {len(r['images'])}
images used, {len(r['points'])} points, {len(corners)} corners rejected. Observations:
{html.escape(r['observations_csv'])}.</p>
<p>Coverage: {100 * coverage:.0f} % of the {COVERAGE_CELLS} x {COVERAGE_CELLS} cells of the
image hold a point (distortion is determined only where boards were seen: aim for the corners
and edges too).</p>
<p><img src="detect_coverage.png"></p>
<h2>Images</h2>
{table(["frame", "image", "outcome", "points", "reason"], images)}
<h2>Rejected corners</h2>
{table(["frame", "corner id", "reason"], corners) if corners else "<p>None.</p>"}
"""


def read_rows(path):
    with open(path, newline="") as f:
        rows = [line for line in f if not line.startswith("#")]
    return list(csv.DictReader(rows))


def residual_points(camera_id, observations, residuals):
    """(x, y, rx, ry, rejected) per residual of `camera_id`, x/y the observed pixel."""
    pixel = {}
    for path in observations:
        for o in read_rows(path):
            pixel[(int(o["camera"]), int(o["frame"]), int(o["point_id"]))] = (
                float(o["image_x_px"]), float(o["image_y_px"]))
    out = []
    for r in read_rows(residuals):
        key = (int(r["camera"]), int(r["frame"]), int(r["point_id"]))
        if key[0] == camera_id and key in pixel:
            out.append((*pixel[key], float(r["residual_x_px"]), float(r["residual_y_px"]),
                        r["rejected"] == "1"))
    return np.array(out, dtype=float).reshape(-1, 5)


def plot_views(cam, path):
    views = cam["comment"]["views"]
    fig, ax = plt.subplots(figsize=(8, 3.4))
    rms = cam["comment"]["rms_px"]
    ax.bar(range(len(views)), [v["rms_px"] for v in views], color="C0")
    ax.axhline(rms, color="k", lw=0.8, label=f"camera RMS {rms:.4f} px")
    ax.axhline(2 * rms, color="C3", lw=0.8, ls="--", label="2 x RMS (acceptance)")
    ax.set_xticks(range(len(views)), [str(v["frame"]) for v in views], fontsize=7)
    ax.set_xlabel("view (frame)")
    ax.set_ylabel("RMS [px]")
    ax.set_title(f"camera {cam['camera_id']}: per-view RMS reprojection error")
    ax.legend(fontsize=8)
    save(fig, path)


def plot_residuals(cam, pts, sigma, path):
    w, h = cam["image_size"]["width"], cam["image_size"]["height"]
    used = pts[pts[:, 4] == 0]
    scale = 0.05 * w / max(np.percentile(np.hypot(used[:, 2], used[:, 3]), 95), 1e-9)
    fig, axs = plt.subplots(1, 2, figsize=(12, 4.6), gridspec_kw={"width_ratios": [1.4, 1]})
    ax = axs[0]
    ax.quiver(used[:, 0], used[:, 1], used[:, 2] * scale, used[:, 3] * scale, angles="xy",
              scale_units="xy", scale=1, width=0.002, color="C0")
    rej = pts[pts[:, 4] == 1]
    if len(rej):
        ax.plot(rej[:, 0], rej[:, 1], "x", color="C3", label=f"{len(rej)} rejected")
        ax.legend(fontsize=8)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_title(f"camera {cam['camera_id']}: residuals (observed - projected) x {scale:.0f}")
    ax.set_xlabel("x [px]")
    ax.set_ylabel("y [px]")
    ax = axs[1]
    r = np.concatenate([used[:, 2], used[:, 3]])
    lim = max(5 * sigma, np.percentile(np.abs(r), 99.5))
    ax.hist(np.clip(r, -lim, lim), bins=60, range=(-lim, lim), density=True, alpha=0.7, label="x and y residuals")
    x = np.linspace(-lim, lim, 200)
    ax.plot(x, np.exp(-0.5 * (x / sigma) ** 2) / (sigma * math.sqrt(2 * math.pi)), "k",
            label=f"N(0, {sigma:.4f}²): the fit's residual sigma")
    ax.set_xlabel("residual [px]")
    ax.set_ylabel("density")
    ax.legend(fontsize=8)
    save(fig, path)


def parameter_rows(cam):
    i = cam["intrinsics"]
    values = [i["fx"], i["fy"], i["cx"], i["cy"], i.get("skew", 0.0)] + \
        list(i["distortion"]) + [0.0] * (8 - len(i["distortion"]))
    cov = cam["intrinsic_covariance"]
    sd = cov["standard_deviations"] if isinstance(cov, dict) else \
        [math.sqrt(max(cov[k][k], 0.0)) for k in range(13)]
    return [[n, f"{v:.6g}", f"{s:.3g}" if s > 0 else "fixed", u]
            for n, v, s, u in zip(NAMES, values, sd, UNITS)]


def calibration_page(doc, args, out_dir):
    c = doc["comment"]
    step = c["produced_by"].split()[-1]
    parts = [f"<h1>{html.escape(c['produced_by'])}</h1>"]
    if step == "rig":
        parts.append(f"<p>RMS {c['rms_px']:.4f} px over all cameras, residual sigma "
                     f"{c['residual_sigma_px']:.4f} px per axis, {c['points_used']} points used, "
                     f"{c['points_rejected']} rejected, {c['free_parameters']} parameters.</p>")
    for cam in doc["cameras"]:
        cc = cam["comment"]
        cid = cam["camera_id"]
        sigma = cc.get("residual_sigma_px", c.get("residual_sigma_px", 0.0)) if step == "rig" \
            else cc["residual_sigma_px"]
        parts.append(f"<h2>Camera {cid}</h2><p>RMS {cc['rms_px']:.4f} px, residual sigma "
                     f"{sigma:.4f} px per axis, {cc['points_used']} points used, "
                     f"{cc['points_rejected']} rejected, {len(cc['views'])} views.</p>")
        if "baseline_m" in cc and cid != 0:
            parts.append(f"<p>Baseline |T| = {cc['baseline_m'] * 1e3:.3f} ± "
                         f"{cc['baseline_sigma_m'] * 1e3:.3f} mm (1σ); own intrinsic fit RMS "
                         f"{cc['intrinsic_fit_rms_px']:.4f} px.</p>")
        parts.append(table(["parameter", "value", "σ (1 sigma)", "unit"], parameter_rows(cam)))
        plot_views(cam, os.path.join(out_dir, f"camera{cid}_views.png"))
        parts.append(f'<p><img src="camera{cid}_views.png"></p>')
        parts.append(table(["frame", "RMS [px]", "points used", "rejected"],
                           [[v["frame"], f"{v['rms_px']:.4f}", v["points_used"],
                             v["points_rejected"]] for v in cc["views"]]))
        if args.observations and args.residuals:
            pts = residual_points(cid, args.observations, args.residuals)
            used = pts[pts[:, 4] == 0]
            rms = math.sqrt(np.mean(used[:, 2] ** 2 + used[:, 3] ** 2)) if len(used) else 0.0
            print(f"camera {cid}: RMS {cc['rms_px']:.4f} px (result), {rms:.4f} px recomputed "
                  f"from {len(used)} residuals of {args.residuals}")
            plot_residuals(cam, pts, sigma, os.path.join(out_dir, f"camera{cid}_residuals.png"))
            parts.append(f"<p>From {html.escape(args.residuals)}: {len(used)} residuals, RMS "
                         f"{rms:.4f} px.</p><p><img src=\"camera{cid}_residuals.png\"></p>")
        else:
            parts.append("<p>Residual vectors and histogram left out: give --observations and "
                         "--residuals.</p>")
    return "".join(parts)


def register_page(doc, out_dir):
    c = doc["comment"]
    marks = c["marks"]
    fig, ax = plt.subplots(figsize=(9, 3.6))
    for k, axis in enumerate("xyz"):
        ax.bar(np.arange(len(marks)) + 0.25 * (k - 1), [m["residual_r_m"][k] * 1e3 for m in marks],
               width=0.25, label=axis)
    ax.set_xticks(range(len(marks)), [str(m["id"]) for m in marks])
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xlabel("mark id")
    ax.set_ylabel("residual in S_r [mm]")
    ax.set_title("marks: p_r - T_r_w q_w")
    ax.legend()
    save(fig, os.path.join(out_dir, "register_residuals.png"))
    rows = [[m["id"], " ".join(map(str, m["cameras"])),
             " ".join(f"{v * 1e3:.3f}" for v in m["residual_r_m"]),
             f"{np.linalg.norm(m['residual_r_m']) * 1e3:.3f}", f"{m['chi2']:.2f} / {m['dof']}",
             f"{m['p_value']:.3g}",
             "rejected" if not m["used"] else ("OUTLIER, kept" if m["outlier"] else "ok")]
            for m in marks]
    t = c["T_w_r"]
    sd = [math.sqrt(max(c["T_w_r_covariance"][k][k], 0)) for k in range(6)]
    rot = ", ".join(f"{math.degrees(v):.4f} ± {math.degrees(s):.4f}"
                    for v, s in zip(t["rotation_vector_rad"], sd[:3]))
    tra = ", ".join(f"{v * 1e3:.3f} ± {s * 1e3:.3f}"
                    for v, s in zip(t["translation_m"], sd[3:]))
    skipped = [[s["id"], s["reason"]] for s in c["skipped"]]
    print(f"register: {len(marks)} marks, chi-square {c['chi2']:.2f} / {c['dof']}, "
          f"p {c['p_value']:.3g}")
    return f"""<h1>storetrack-calib register</h1>
<p>T_w_r rotation vector [deg]: {rot}; translation [mm]: {tra} (1σ). Fit chi-square
{c['chi2']:.2f} with {c['dof']} dof, p = {c['p_value']:.3g}.</p>
<h2>Marks</h2>
{table(["mark", "cameras", "residual x y z [mm]", "|residual| [mm]", "χ² / dof", "p",
        "outcome"], rows)}
<p><img src="register_residuals.png"></p>
<h2>Skipped marks</h2>
{table(["mark", "reason"], skipped) if skipped else "<p>None.</p>"}
"""


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("result", help="detect --report-json JSON, or the calibration JSON of "
                   "intrinsic, rig or register")
    p.add_argument("out_dir", help="directory for index.html and the PNGs")
    p.add_argument("--observations", nargs="*", default=[], help="observation CSV(s) of the fit")
    p.add_argument("--residuals", help="residual CSV of the fit (--residuals of the command)")
    args = p.parse_args()
    with open(args.result) as f:
        doc = json.load(f)
    os.makedirs(args.out_dir, exist_ok=True)
    fmt = doc.get("format")
    produced_by = doc.get("comment", {}).get("produced_by", "") \
        if isinstance(doc.get("comment"), dict) else ""
    if fmt == "storetrack-calib-detect":
        body = detect_page(doc, args.out_dir)
    elif fmt == "storetrack-rig-calibration" and produced_by == "storetrack-calib register":
        body = register_page(doc, args.out_dir)
    elif fmt == "storetrack-rig-calibration" and produced_by == "storetrack-calib rig":
        body = calibration_page(doc, args, args.out_dir)
    elif fmt == "storetrack-rig-calibration" and \
            doc["cameras"][0].get("comment", {}).get("produced_by") == "storetrack-calib intrinsic":
        doc["comment"] = doc["cameras"][0]["comment"]
        body = calibration_page(doc, args, args.out_dir)
    else:
        sys.exit(f"{args.result}: format: expected a storetrack-calib detect report JSON or a "
                 f"calibration file written by storetrack-calib, got {fmt!r} ({produced_by!r})")
    write_page(args.out_dir, body, title="storetrack-calib")


if __name__ == "__main__":
    main()
