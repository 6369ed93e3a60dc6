#!/usr/bin/env python3
"""storetrack-eval report: HTML page + PNG plots from a storetrack-eval result JSON.

type-a (docs/evaluation.md): the per-axis table laid out as SisTrO's static table (mean error,
1-sigma experimental standard deviation, the instrument's stated u), the per-mark table (mean
error +- U with k, s, u = s/sqrt(N), s/u_stated in its chi-square interval), and two plots:
mean error +- U per mark and axis, s/u_stated per mark and axis with its interval.
lme: VDI/VDE 2634-1 length measuring error as seed 001's table (storetrack_eval_lme_report.py).
noise-floor (docs/evaluation.md): seed 002's noise-floor table (variance error mu_T temporal and
mu_S spatial, bias error, per world axis and per rig axis in-plane 1, in-plane 2, out-of-plane),
the image-coordinate error per camera, the stereo angles (seed 002 Table 3), the reconstruction
error of the surveyed distances in % (Table 4), and two plots: temporal sd and bias per mark
and axis, distance error per pair.
pendulum: storetrack_eval_pendulum.py (SisTrO's dynamic table, parameters, error growth plots).
Debian packages only (python3-matplotlib, python3-numpy).

Usage: storetrack_eval_report.py RESULT.json OUT_DIR
"""
import argparse
import html
import json
import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from report_html import table, write_page  # noqa: E402

AXES = ["x", "y", "z"]
MM = 1e3


def plot_errors(r, path):
    k = r["coverage_factor"]
    fig, axs = plt.subplots(1, 3, figsize=(12, 3.6), sharey=True)
    for ax, a in zip(axs, AXES):
        ids = [m["mark_id"] for m in r["marks"]]
        err = [m[a]["mean_error_m"] * MM for m in r["marks"]]
        U = [m[a]["expanded_m"] * MM for m in r["marks"]]
        ax.errorbar(range(len(ids)), err, yerr=U, fmt="o", capsize=4)
        ax.axhline(0, color="k", lw=0.8)
        ax.set_xticks(range(len(ids)), [str(i) for i in ids])
        ax.set_title(f"{a}: mean error ± U (k = {k:g})")
        ax.set_xlabel("mark id")
        ax.grid(alpha=0.3)
    axs[0].set_ylabel("mm")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_ratio(r, path):
    fig, axs = plt.subplots(1, 3, figsize=(12, 3.6), sharey=True)
    for ax, a in zip(axs, AXES):
        ids = [m["mark_id"] for m in r["marks"]]
        for i, m in enumerate(r["marks"]):
            lo, hi = m["ratio_interval"]
            ax.plot([i, i], [lo, hi], color="0.6", lw=6, solid_capstyle="butt")
            ratio = m[a]["ratio"]
            ax.plot(i, ratio, "o", color="C0" if m[a]["agrees"] else "C3")
        ax.axhline(1, color="k", lw=0.8)
        ax.set_xticks(range(len(ids)), [str(i) for i in ids])
        ax.set_title(f"{a}: s / u_stated ({100 * r['agreement_level']:g} % interval)")
        ax.set_xlabel("mark id")
        ax.grid(alpha=0.3)
    axs[0].set_ylabel("ratio")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def type_a_page(r):
    k = r["coverage_factor"]
    n_marks = len(r["marks"])
    summary = [[a, f"{s['mean_error_m'] * MM:.3f}", f"{s['sd_rms_m'] * MM:.3f}",
                f"{s['sd_max_m'] * MM:.3f}", f"{s['u_stated_rms_m'] * MM:.3f}",
                f"{s['agreeing_marks']}/{n_marks}"]
               for a, s in ((a, r["summary"][a]) for a in AXES)]
    per_mark = []
    for m in r["marks"]:
        lo, hi = m["ratio_interval"]
        for a in AXES:
            x = m[a]
            per_mark.append([m["mark_id"], a, m["repetitions"],
                             f"{x['mean_error_m'] * MM:.3f} ± {x['expanded_m'] * MM:.3f}",
                             f"{x['sd_m'] * MM:.3f}", f"{x['u_mean_m'] * MM:.3f}",
                             f"{x['u_stated_m'] * MM:.3f}", f"{x['u_survey_m'] * MM:.3f}",
                             f"{x['ratio']:.2f} [{lo:.2f}, {hi:.2f}]",
                             "agrees" if x["agrees"] else "DISAGREES"])
    return f"""<h1>storetrack-eval: static Type A</h1>
<p>{html.escape(r['method'])}. {r['repetitions']} repetitions, {n_marks} marks of body
'{html.escape(r['body'])}'; coverage factor k = {k:g}; agreement of the instrument's stated
per-sample u: s/u_stated inside its {100 * r['agreement_level']:g} % chi-square interval
(N-1 degrees of freedom).</p>
<h2>Per axis (SisTrO static table), mm</h2>
{table(["axis", "mean error", "s (1σ, RMS over marks)", "s (max)", "u_stated (RMS)",
        "marks agreeing"], summary)}
<h2>Per mark and axis, mm</h2>
{table(["mark", "axis", "N", f"mean error ± U (k = {k:g})", "s", "u = s/√N", "u_stated",
        "u_survey", "s/u_stated [interval]", "verdict"], per_mark)}
<h2>Plots</h2>
<p><img src="type_a_errors.png"></p>
<p><img src="type_a_ratio.png"></p>
<p>Inputs: {html.escape(', '.join(r['inputs']['marks_csv']))}; survey
{html.escape(r['inputs']['survey'])}.</p>
"""


NF_WORLD = ["x", "y", "z"]
NF_RIG = ["in_plane_1", "in_plane_2", "out_of_plane"]


def plot_noise_marks(r, path):
    axes = NF_RIG if r["has_rig"] else NF_WORLD
    fig, axs = plt.subplots(1, 2, figsize=(12, 3.8))
    ids = [m["mark_id"] for m in r["marks"]]
    x = range(len(ids))
    for j, a in enumerate(axes):
        axs[0].plot(x, [m[a]["temporal_sd_m"] * MM for m in r["marks"]], "o-", label=a)
        axs[1].errorbar([i + 0.1 * (j - 1) for i in x], [m[a]["bias_m"] * MM for m in r["marks"]],
                        yerr=[r["coverage_factor"] * m[a]["u_bias_m"] * MM for m in r["marks"]],
                        fmt="o", capsize=3, label=a)
    axs[0].set_title("variance error: sd over time per mark")
    axs[1].set_title(f"bias error per mark ± U (k = {r['coverage_factor']:g})")
    axs[1].axhline(0, color="k", lw=0.8)
    for ax in axs:
        ax.set_xticks(list(x), [str(i) for i in ids])
        ax.set_xlabel("mark id")
        ax.set_ylabel("mm")
        ax.grid(alpha=0.3)
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_noise_distances(r, path):
    fig, ax = plt.subplots(figsize=(12, 3.6))
    d = r["distances"]
    ax.errorbar(range(len(d)), [p["error_percent"] for p in d],
                yerr=[r["coverage_factor"] * p["u_error_percent"] for p in d], fmt="o", capsize=3)
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xticks(range(len(d)), [f"{p['id_a']}-{p['id_b']}" for p in d], rotation=90,
                  fontsize=7)
    ax.set_ylabel("E [%]")
    ax.set_title("reconstruction error of the surveyed distances (seed 002 eq. 4)")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def noise_axis_table(summary, axes):
    rows = [["variance error, temporal μ_T (sd)"] +
            [f"{summary[a]['temporal_sd_mean_m'] * MM:.4f}" for a in axes],
            ["variance error, spatial μ_S (sd)"] +
            [f"{summary[a]['spatial_sd_mean_m'] * MM:.4f}" for a in axes],
            ["bias error (mean over marks)"] +
            [f"{summary[a]['bias_mean_m'] * MM:.4f}" for a in axes],
            ["bias error (RMS over marks)"] +
            [f"{summary[a]['bias_rms_m'] * MM:.4f}" for a in axes],
            ["stated centroid u (RMS)"] +
            [f"{summary[a]['u_centroid_rms_m'] * MM:.4f}" for a in axes],
            ["μ_T / stated centroid u, pooled [interval]"] +
            [f"{summary[a]['pooled_ratio']:.3f} [{summary[a]['pooled_interval'][0]:.3f}, "
             f"{summary[a]['pooled_interval'][1]:.3f}]" for a in axes]]
    return table(["mm"] + axes, rows)


def noise_floor_page(r):
    k = r["coverage_factor"]
    rig = noise_axis_table(r["summary"]["rig"], NF_RIG) if r["has_rig"] else \
        "<p>No rig calibration given: in-plane / out-of-plane axes left out.</p>"
    cams = [[c["camera_id"], c["marks"], f"{c['u']['residual_rms_px']:.4f}",
             f"{c['v']['residual_rms_px']:.4f}", f"{c['u']['temporal_sd_mean_px']:.4f}",
             f"{c['v']['temporal_sd_mean_px']:.4f}", f"{c['u']['sigma_rms_px']:.4f}",
             f"{c['u']['pooled_ratio']:.3f} / {c['v']['pooled_ratio']:.3f} "
             f"[{c['u']['pooled_interval'][0]:.3f}, {c['u']['pooled_interval'][1]:.3f}]"]
            for c in r["cameras"]]
    image = table(["camera", "marks", "residual RMS u", "residual RMS v", "sd over time u",
                   "sd over time v", "stated σ", "sd/σ u / v [interval]"], cams) \
        if cams else f"<p>{html.escape(r['image_coordinates_note'])}</p>"
    stereo = [[s["mark_id"], f"{s['camera_a']}-{s['camera_b']}",
               f"{s['stereo_angle_rad'] * 57.29577951308232:.2f}",
               f"{s['error_rad'] * 57.29577951308232:.2f}"] for s in r["stereo_angles"]]
    dist = [[f"{d['id_a']}–{d['id_b']}", f"{d['reference_m'] * MM:.3f}",
             f"{d['measured_m'] * MM:.3f}", f"{d['error_percent']:.4f} ± "
             f"{k * d['u_error_percent']:.4f}"] for d in r["distances"]]
    return f"""<h1>storetrack-eval: noise floor</h1>
<p>{html.escape(r['method'])}. {r['exposures']} exposures over {r['duration_s']:.3f} s,
{len(r['marks'])} marks of body '{html.escape(r['bodies'])}'; k = {k:g}; s/u inside its
{100 * r['agreement_level']:g} % chi-square interval.</p>
<h2>Noise floor per axis (seed 002, Figs. 5–7), rig axes, mm</h2>
{rig}
<h2>Noise floor per world axis, mm</h2>
{noise_axis_table(r["summary"]["world"], NF_WORLD)}
<h2>Image-coordinate error per camera, px</h2>
{image}
<h2>Stereo angle per mark and camera pair (seed 002 Table 3), degrees</h2>
{table(["mark", "cameras", "stereo angle", "e_θ = θ_a − θ_b"], stereo) if stereo else
 "<p>Left out (needs --rig and the observation columns).</p>"}
<h2>Reconstruction error of surveyed distances (seed 002 Table 4)</h2>
{table(["pair", "D [mm]", "measured [mm]", f"E ± U (k = {k:g}) [%]"], dist)}
<h2>Plots</h2>
<p><img src="noise_floor_marks.png"></p>
<p><img src="noise_floor_distances.png"></p>
<p>Inputs: {html.escape(r['inputs']['marks_csv'])}; survey {html.escape(r['inputs']['survey'])};
rig {html.escape(r['inputs']['rig'] or '(none)')}.</p>
"""


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("result", help="storetrack-eval result JSON")
    p.add_argument("out_dir", help="directory for index.html and the PNGs")
    args = p.parse_args()
    with open(args.result) as f:
        r = json.load(f)
    if r.get("format") == "storetrack-eval-pendulum":
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        from storetrack_eval_pendulum import write_pendulum_report
        print(f"report: {write_pendulum_report(r, args.out_dir)}")
        return
    formats = ("storetrack-eval-type-a", "storetrack-eval-lme", "storetrack-eval-noise-floor")
    if r.get("format") not in formats:
        sys.exit(f"{args.result}: format: expected one of {', '.join(formats)}, "
                 f"got {r.get('format')!r}")
    os.makedirs(args.out_dir, exist_ok=True)
    if r["format"] == "storetrack-eval-lme":
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        from storetrack_eval_lme_report import lme_page
        write_page(args.out_dir, lme_page(r, args.out_dir))
    elif r["format"] == "storetrack-eval-noise-floor":
        plot_noise_marks(r, os.path.join(args.out_dir, "noise_floor_marks.png"))
        plot_noise_distances(r, os.path.join(args.out_dir, "noise_floor_distances.png"))
        write_page(args.out_dir, noise_floor_page(r))
    else:
        plot_errors(r, os.path.join(args.out_dir, "type_a_errors.png"))
        plot_ratio(r, os.path.join(args.out_dir, "type_a_ratio.png"))
        write_page(args.out_dir, type_a_page(r))


if __name__ == "__main__":
    main()
