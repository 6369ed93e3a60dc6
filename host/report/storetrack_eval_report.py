#!/usr/bin/env python3
"""storetrack-eval report: HTML page + PNG plots from a storetrack-eval result JSON.

type-a (docs/evaluation.md): the per-axis table laid out as SisTrO's static table (mean error,
1-sigma experimental standard deviation, the instrument's stated u), the per-mark table (mean
error +- U with k, s, u = s/sqrt(N), s/u_stated in its chi-square interval), and two plots:
mean error +- U per mark and axis, s/u_stated per mark and axis with its interval.
lme: VDI/VDE 2634-1 length measuring error as seed 001's table (storetrack_eval_lme_report.py).
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


def table(header, rows):
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>"
                   for row in rows)
    return f"<table border=1 cellpadding=4><tr>{head}</tr>{body}</table>"


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


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("result", help="storetrack-eval result JSON")
    p.add_argument("out_dir", help="directory for index.html and the PNGs")
    args = p.parse_args()
    with open(args.result) as f:
        r = json.load(f)
    if r.get("format") not in ("storetrack-eval-type-a", "storetrack-eval-lme"):
        sys.exit(f"{args.result}: format: expected storetrack-eval-type-a or storetrack-eval-lme, "
                 f"got {r.get('format')!r}")
    os.makedirs(args.out_dir, exist_ok=True)
    if r["format"] == "storetrack-eval-lme":
        sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
        from storetrack_eval_lme_report import lme_page
        write_page(args.out_dir, lme_page(r, args.out_dir))
        return
    plot_errors(r, os.path.join(args.out_dir, "type_a_errors.png"))
    plot_ratio(r, os.path.join(args.out_dir, "type_a_ratio.png"))
    write_page(args.out_dir, type_a_page(r))


def write_page(out_dir, body):
    with open(os.path.join(out_dir, "index.html"), "w") as f:
        f.write("<!doctype html><html><head><meta charset='utf-8'><title>storetrack-eval"
                "</title></head><body>" + body + "</body></html>\n")
    print(f"report: {os.path.join(out_dir, 'index.html')}")


if __name__ == "__main__":
    main()
