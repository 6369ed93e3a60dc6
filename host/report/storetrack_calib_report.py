#!/usr/bin/env python3
"""storetrack-calib report: HTML page + PNG plots from a compare or uncertainty-map result JSON.

compare (docs/calibration.md, "Compare"): the verdict, the per-camera projection difference
(rigid motion fitted out) as maps over the image (largest over the working distances) and
histograms, the triangulated difference against both predicted uncertainties (chi-square per
grid point, |difference| against the combined standard uncertainty), the scale bars.
uncertainty-map: the predicted 3-D standard uncertainty sqrt(trace C) of a triangulated mark in
three slices through the centre of the working volume; points seen by fewer than 2 cameras are
grey.
Debian packages only (python3-matplotlib, python3-numpy); the table helper is
storetrack_eval_report's.

Usage: storetrack_calib_report.py RESULT.json OUT_DIR
"""
import argparse
import html
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from storetrack_eval_report import table  # noqa: E402

MM = 1e3


def nan_array(rows):
    return np.array([[np.nan if v is None else v for v in row] for row in rows], dtype=float)


def plot_projection_maps(r, path):
    cams = r["cameras"]
    fig, axs = plt.subplots(1, len(cams), figsize=(4.2 * len(cams), 3.2), squeeze=False)
    for ax, c in zip(axs[0], cams):
        d = nan_array(c["difference_px"])  # distances x pixels
        worst = np.nanmax(d, axis=0).reshape(c["rows"], c["columns"])
        px = np.array(c["pixels"])
        extent = [px[:, 0].min(), px[:, 0].max(), px[:, 1].max(), px[:, 1].min()]
        im = ax.imshow(worst, extent=extent, aspect="auto", cmap="viridis")
        fig.colorbar(im, ax=ax, label="px")
        ax.set_title(f"camera {c['camera_id']}: max over distances")
        ax.set_xlabel("u [px]")
        ax.set_ylabel("v [px]")
    fig.suptitle("projection difference a -> b, rigid motion fitted out")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_histograms(r, path):
    fig, axs = plt.subplots(1, 2, figsize=(11, 3.8))
    for c in r["cameras"]:
        d = nan_array(c["difference_px"]).ravel()
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


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("result")
    ap.add_argument("out_dir")
    a = ap.parse_args()
    with open(a.result) as f:
        r = json.load(f)
    os.makedirs(a.out_dir, exist_ok=True)
    kind = r.get("kind")
    if kind == "storetrack-calib-compare":
        body = compare_page(r, a.out_dir)
    elif kind == "storetrack-calib-uncertainty-map":
        body = map_page(r, a.out_dir)
    else:
        sys.exit(f"{a.result}: kind: expected a storetrack-calib compare or uncertainty-map "
                 f"result, got {kind!r}")
    with open(os.path.join(a.out_dir, "index.html"), "w") as f:
        f.write(f"<!doctype html><html><head><meta charset='utf-8'><title>{kind}</title>"
                f"</head><body>{body}</body></html>\n")
    print(f"wrote {os.path.join(a.out_dir, 'index.html')}")


if __name__ == "__main__":
    main()
