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
compare (docs/calibration.md, "Compare"): the verdict, the per-camera projection difference
(rigid motion fitted out) as maps over the image (largest over the working distances) and
histograms, the triangulated difference against both predicted uncertainties (chi-square per
grid point, |difference| against the combined standard uncertainty), the scale bars.
uncertainty-map: the predicted 3-D standard uncertainty sqrt(trace C) of a triangulated mark in
three slices through the centre of the working volume; points seen by fewer than 2 cameras are
grey.
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
import warnings

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from report_html import table, write_page  # noqa: E402

NAMES = ["fx", "fy", "cx", "cy", "skew", "k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6"]
UNITS = ["px"] * 5 + [""] * 8
COVERAGE_CELLS = 10


MM = 1e3


def nan_array(rows):
    return np.array([[np.nan if v is None else v for v in row] for row in rows], dtype=float)


def inside_differences(c):
    """difference_px (distances x pixels) with the pixels outside the observed region blanked:
    there the models are extrapolated (docs/calibration.md, "Inside the observed region")."""
    d = nan_array(c["difference_px"])
    if "inside_observed_region" in c:
        d[:, ~np.array(c["inside_observed_region"], dtype=bool)] = np.nan
    return d


def plot_projection_maps(r, path):
    cams = r["cameras"]
    fig, axs = plt.subplots(1, len(cams), figsize=(4.2 * len(cams), 3.2), squeeze=False)
    for ax, c in zip(axs[0], cams):
        d = inside_differences(c)  # distances x pixels; outside the observed region blank
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: outside
            worst = np.nanmax(d, axis=0).reshape(c["rows"], c["columns"])
        px = np.array(c["pixels"])
        extent = [px[:, 0].min(), px[:, 0].max(), px[:, 1].max(), px[:, 1].min()]
        im = ax.imshow(worst, extent=extent, aspect="auto", cmap="viridis")
        fig.colorbar(im, ax=ax, label="px")
        ax.set_title(f"camera {c['camera_id']}: max over distances")
        ax.set_xlabel("u [px]")
        ax.set_ylabel("v [px]")
    fig.suptitle("projection difference a -> b, rigid motion fitted out (blank: outside the "
                 "observed region)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_histograms(r, path):
    fig, axs = plt.subplots(1, 2, figsize=(11, 3.8))
    for c in r["cameras"]:
        d = inside_differences(c).ravel()
        axs[0].hist(d[np.isfinite(d)], bins=40, histtype="step", label=f"camera {c['camera_id']}")
    axs[0].set_xlabel("projection difference [px]")
    axs[0].set_ylabel("grid samples")
    axs[0].legend(fontsize=8)
    chi2 = [float(p["chi2"]) for p in r["volume_points"] if p["valid"]]
    chi2 = np.minimum(np.array(chi2), 50)
    axs[1].hist(chi2, bins=50, density=True, label="grid points (clipped at 50)")
    x = np.linspace(0.01, 50, 400)
    axs[1].plot(x, np.sqrt(x / (2 * np.pi)) * np.exp(-x / 2), "k", lw=1, label="chi-square(3)")
    axs[1].axvline(r["triangulated"]["chi2_threshold"], color="C3", label="point threshold")
    axs[1].set_xlabel("d^T (S_a + S_b)^-1 d")
    axs[1].legend(fontsize=8)
    axs[1].set_title("triangulated difference against both uncertainties")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_volume(r, path):
    pts = [p for p in r["volume_points"] if p["valid"]]
    d = np.array([np.linalg.norm(p["difference_m"]) for p in pts]) * MM
    u = np.array([np.hypot(p["u_a_m"], p["u_b_m"]) for p in pts]) * MM
    bad = np.array([p["inconsistent"] for p in pts], dtype=bool)
    fig, ax = plt.subplots(figsize=(6, 4.5))
    ax.plot(u[~bad], d[~bad], ".", ms=3, label="consistent")
    ax.plot(u[bad], d[bad], ".", ms=3, color="C3", label="inconsistent")
    lim = max(u.max(initial=1e-3), d.max(initial=1e-3)) * 1.05
    ax.plot([0, lim], [0, lim], "k", lw=0.8, label="|d| = u")
    ax.set_xlabel("sqrt(u_a^2 + u_b^2) [mm] (u = sqrt(trace S))")
    ax.set_ylabel("|p_b - p_a| [mm]")
    ax.set_title("triangulated difference over the working volume")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def stats_row(name, s, scale=1.0):
    return [name] + [f"{s[k] * scale:.4f}" for k in ("rms", "p50", "p95", "p99", "max")]


def compare_page(r, out):
    plot_projection_maps(r, os.path.join(out, "compare_projection_maps.png"))
    plot_histograms(r, os.path.join(out, "compare_histograms.png"))
    plot_volume(r, os.path.join(out, "compare_volume.png"))
    t = r["triangulated"]
    v = r["verdict"]
    rows = [stats_row(f"camera {c['camera_id']} fitted [px]", c["fitted_px"]) for c in r["cameras"]]
    rows += [stats_row(f"camera {c['camera_id']} unfitted [px]", c["unfitted_px"])
             for c in r["cameras"]]
    rows += [stats_row("|p_b - p_a| [mm]", t["difference_m"], MM),
             stats_row("u_a [mm]", t["u_a_m"], MM), stats_row("u_b [mm]", t["u_b_m"], MM)]
    bars = [[b["id"], f"{b['length_m'] * MM:.2f}",
             f"{b['error_a_m'] * MM:.4f} ± {b['u_a_m'] * MM:.4f}" if b["valid"] else b["reason"],
             f"{b['error_b_m'] * MM:.4f} ± {b['u_b_m'] * MM:.4f}" if b["valid"] else ""]
            for b in r["bars"]]
    colour = "#060" if v["consistent"] else "#a00"
    return f"""<h1>storetrack-calib compare</h1>
<p>a = {html.escape(r['a'])}, b = {html.escape(r['b'])}; working distances
{', '.join(f'{d:.3f}' for d in r['distances_m'])} m; centroid sigma {r['sigma_px']} px</p>
<p style="color:{colour}"><b>{html.escape(v['text'])}</b></p>
<p>Joint test over the volume: chi2 {t['joint_chi2']:.1f} for {t['joint_dof']} dof
(p = {t['joint_p_value']:.3g}, refused below {t['false_alarm']}); {t['valid_points']} grid
points seen by &ge; 2 cameras, {t['unseen_points']} not; {100 * t['inconsistent_fraction']:.1f} %
of them outside their own {100 * (1 - t['point_false_alarm']):.0f} % ellipsoid.</p>
{table(['quantity', 'rms', 'p50', 'p95', 'p99', 'max'], rows)}
{table(['bar', 'length [mm]', 'error a ± u [mm]', 'error b ± u [mm]'], bars) if bars else ''}
<img src="compare_projection_maps.png"><br><img src="compare_histograms.png"><br>
<img src="compare_volume.png">"""


def plot_slices(r, path):
    n = r["volume"]["points"]
    pts = r["points"]
    u = np.array([p["u_m"] * MM if p["valid"] else np.nan for p in pts]).reshape(n[2], n[1], n[0])
    lo, hi = r["volume"]["min_w_m"], r["volume"]["max_w_m"]
    mid = [k // 2 for k in n]
    slices = [("z", u[mid[2], :, :], (0, 1)), ("y", u[:, mid[1], :], (0, 2)),
              ("x", u[:, :, mid[0]], (1, 2))]
    vmax = np.nanmax(u) if np.isfinite(u).any() else 1
    fig, axs = plt.subplots(1, 3, figsize=(15, 4.4))
    names = "xyz"
    for ax, (fixed, s, (i, j)) in zip(axs, slices):
        ax.set_facecolor("0.8")
        im = ax.imshow(s, origin="lower", extent=[lo[i], hi[i], lo[j], hi[j]], aspect="auto",
                       vmin=0, vmax=vmax, cmap="viridis")
        k = "xyz".index(fixed)
        centre = lo[k] + (hi[k] - lo[k]) * (mid[k] / max(n[k] - 1, 1))
        ax.set_title(f"{fixed}_w = {centre:.3f} m (grey: < 2 cameras)")
        ax.set_xlabel(f"{names[i]}_w [m]")
        ax.set_ylabel(f"{names[j]}_w [m]")
        fig.colorbar(im, ax=ax, label="sqrt(trace C) [mm]")
    fig.suptitle("predicted 3-D standard uncertainty of a triangulated mark")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def map_page(r, out):
    plot_slices(r, os.path.join(out, "uncertainty_slices.png"))
    s = r["u_m"]
    return f"""<h1>storetrack-calib uncertainty-map</h1>
<p>{html.escape(r['rig'])}; centroid sigma {r['sigma_px']} px; calibration covariance:
{html.escape(r['covariance_source'])}</p>
{table(['quantity', 'rms', 'p50', 'p95', 'p99', 'max'],
       [stats_row('sqrt(trace C) [mm]', s, MM)])}
<img src="uncertainty_slices.png">"""


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


def plot_model_error(cam, path):
    """The model error check's two maps (the file's model_error section): the residual map's mean
    residual per cell over its sigma, the cross-validation difference per cell over its sigma;
    flagged cells outlined in red, untested cells grey."""
    me = cam["model_error"]
    cols, rows = me["columns"], me["rows"]
    fig, axs = plt.subplots(1, 2, figsize=(13, 3.6))
    for ax, key, title in ((axs[0], "residual_map", "residual map: |mean residual| / σ_mean"),
                           (axs[1], "cross_validation", "cross-validation: |half b − half a| / σ")):
        z = np.full((rows, cols), np.nan)
        for c in me[key]["comment"]["cells"]:
            if c["tested"]:
                z[c["row"], c["column"]] = math.sqrt(max(c["chi2"], 0.0))
        im = ax.imshow(z, cmap="viridis", vmin=0, vmax=max(4.0, np.nanmax(z) if np.isfinite(z).any() else 4.0))
        for c in me[key]["comment"]["cells"]:
            if c["flagged"]:
                ax.add_patch(plt.Rectangle((c["column"] - 0.5, c["row"] - 0.5), 1, 1, fill=False,
                                           edgecolor="red", linewidth=2))
        ax.set_title(f"camera {cam['camera_id']}: {title}", fontsize=9)
        ax.set_xlabel("cell column")
        ax.set_ylabel("cell row")
        fig.colorbar(im, ax=ax, fraction=0.025)
    save(fig, path)


def model_error_html(cam, out_dir):
    if "model_error" not in cam:
        return "<p>No model error check in this file (--no-model-check, or an older file).</p>"
    me = cam["model_error"]
    cid = cam["camera_id"]
    plot_model_error(cam, os.path.join(out_dir, f"camera{cid}_model_error.png"))
    if me["verdict"].startswith("model error not checked"):
        return f"<h3>Model error check</h3><p>{html.escape(me['verdict'])}</p>"
    head = ("<p><b style=\"color:#b00\">Model error dominates here</b>: the stated parameter "
            "uncertainty does not cover the lens model's error in the cells outlined in red.</p>"
            if me["model_error_dominates"] else "<p>Noise dominates: the stated uncertainty "
            "covers the differences and residual structure found.</p>")
    return (f"<h3>Model error check</h3>{head}<p>{html.escape(me['verdict'])}</p>"
            f"<p><img src=\"camera{cid}_model_error.png\"></p>")


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
        parts.append(model_error_html(cam, out_dir))
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
    p.add_argument("result", help="detect --report-json JSON, the calibration JSON of "
                   "intrinsic, rig or register, or the result of compare or uncertainty-map")
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
    kind = doc.get("kind")
    if kind == "storetrack-calib-compare":
        body = compare_page(doc, args.out_dir)
    elif kind == "storetrack-calib-uncertainty-map":
        body = map_page(doc, args.out_dir)
    elif fmt == "storetrack-calib-detect":
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
                 f"calibration file written by storetrack-calib, or a compare / uncertainty-map result, "
                 f"got format {fmt!r}, kind {kind!r} ({produced_by!r})")
    write_page(args.out_dir, body, title="storetrack-calib")


if __name__ == "__main__":
    main()
