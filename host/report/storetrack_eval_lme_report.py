"""storetrack-eval lme report section (imported by storetrack_eval_report.py).

VDI/VDE 2634-1 length measuring error (docs/evaluation.md): the table laid out as seed 001's
(Leizea et al., Sensors 2023, Tables 4 and 5: LME max, mean, sigma, k = 1) per bar, overall and
per repetition, and two plots: the bars' positions in the measuring volume (3-D, world frame)
and LME per bar and measurement with the predicted +-2u and the MPE.
"""
import html
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

MM = 1e3


def plot_positions(r, path):
    fig = plt.figure(figsize=(6.5, 5.5))
    ax = fig.add_subplot(projection="3d")
    for i, b in enumerate(r["bars"]):
        a, e = b["p_a_w_m"], b["p_b_w_m"]
        ax.plot([a[0], e[0]], [a[1], e[1]], [a[2], e[2]], "-o", color=f"C{i % 10}", lw=2.5,
                label=f"{b['id']} ({b['length_m']:.3f} m)")
    ax.set_xlabel("x_w [m]")
    ax.set_ylabel("y_w [m]")
    ax.set_zlabel("z_w [m]")
    ax.set_title("scale-bar positions in the measuring volume")
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def plot_errors(r, path):
    fig, ax = plt.subplots(figsize=(10, 4))
    for i, b in enumerate(r["bars"]):
        ms = b["measurements"]
        n = len(ms)
        xs = [i + (j - (n - 1) / 2) * 0.6 / max(n, 1) for j in range(n)]
        ax.plot(xs, [m["error_m"] * MM for m in ms], ".", color=f"C{i % 10}", ms=3)
        u = b["statistics"]["u_rms_m"] * MM
        ax.plot([i - 0.35, i + 0.35], [2 * u, 2 * u], color="0.4", lw=1)
        ax.plot([i - 0.35, i + 0.35], [-2 * u, -2 * u], color="0.4", lw=1)
        if r["mpe"] is not None:
            ax.plot([i - 0.4, i + 0.4], [b["mpe_m"] * MM] * 2, color="C3", lw=1.5)
            ax.plot([i - 0.4, i + 0.4], [-b["mpe_m"] * MM] * 2, color="C3", lw=1.5)
    ax.axhline(0, color="k", lw=0.8)
    ax.set_xticks(range(len(r["bars"])), [b["id"] for b in r["bars"]], rotation=20)
    ax.set_ylabel("LME [mm]")
    ax.set_title("LME per bar and measurement; grey ±2u (RMS predicted u)"
                 + ("; red ±MPE" if r["mpe"] is not None else ""))
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _table(header, rows):
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>"
                   for row in rows)
    return f"<table border=1 cellpadding=4><tr>{head}</tr>{body}</table>"


def _stats_row(s):
    lo, hi = s["z_rms_interval"]
    return [s["n"], f"{s['max_abs_m'] * MM:.4f}", f"{s['mean_m'] * MM:.4f}",
            f"{s['sd_m'] * MM:.4f}", f"{s['u_rms_m'] * MM:.4f}",
            f"{s['z_rms']:.2f} [{lo:.2f}, {hi:.2f}]"]


def lme_page(r, out_dir):
    """Writes the PNGs to out_dir and returns the HTML body."""

    plot_positions(r, os.path.join(out_dir, "lme_positions.png"))
    plot_errors(r, os.path.join(out_dir, "lme_errors.png"))
    mpe = r["mpe"]
    mpe_text = ("not assessed" if mpe is None else
                (f"MPE = {mpe['a_m'] * MM:.3f} mm + L / {mpe['k']:g}" if mpe["k"] > 0
                 else f"MPE = {mpe['a_m'] * MM:.3f} mm"))
    stats_head = ["n", "LME max", "LME μ", "LME σ", "u (RMS)", "RMS(LME/u) [interval]"]
    bars = [[b["id"], f"{b['length_m']:.4f}"] + _stats_row(b["statistics"])
            + [("-" if mpe is None else f"{b['mpe_m'] * MM:.4f}"),
               ("-" if mpe is None else ("pass" if b["statistics"]["exceeding_mpe"] == 0
                                         else f"FAIL ({b['statistics']['exceeding_mpe']})"))]
            for b in r["bars"]]
    bars.append(["all", ""] + _stats_row(r["overall"]) + ["", r["verdict"]])
    reps = [[i + 1, html.escape(os.path.basename(rep["path"]))] + _stats_row(rep["statistics"])[:4]
            for i, rep in enumerate(r["repetitions"])]
    cov = ("the marks' full stated covariance" if r["full_covariance"] else
           "the marks' per-axis u only (the marks CSV has no cov_*_w columns: off-diagonal "
           "covariance taken as zero)")
    return f"""<h1>storetrack-eval: VDI/VDE 2634-1 length measuring error</h1>
<p>{html.escape(r['method'])}. {len(r['bars'])} bars, {len(r['repetitions'])} repetitions,
{r['overall']['n']} length measurements; u (k = 1) from {cov} and the bar's calibration u,
treating the two marks' errors as independent (calibration errors shared by both ends make it
an upper estimate). {html.escape(mpe_text)}; verdict: <b>{html.escape(r['verdict'])}</b>.</p>
<h2>LME per bar (seed 001's table, k = 1), mm</h2>
{_table(["bar", "L cal [m]"] + stats_head + ["MPE", "verdict"], bars)}
<h2>LME per repetition (seed 001's Table 5), mm</h2>
{_table(["repetition", "file", "n", "LME max", "LME μ", "LME σ"], reps)}
<h2>Plots</h2>
<p><img src="lme_positions.png"></p>
<p><img src="lme_errors.png"></p>
<p>Inputs: {html.escape(', '.join(r['inputs']['marks_csv']))}; bars
{html.escape(r['inputs']['bars'])}.</p>
"""
