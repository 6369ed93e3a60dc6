"""storetrack-eval pendulum report section (imported by storetrack_eval_report.py).

SisTrO's dynamic calibration (docs/evaluation.md): the identified model parameters with their
1-sigma uncertainties, the per-axis dynamic table as SisTrO lays it out (dynamic error mean ±
sd, model error clockwise vs counter-clockwise, dynamic uncertainty 1 sigma, the reference's own
u and the instrument's stated u), and two plots: the RMS dynamic error per axis against the
distance from the reference camera's optical axis and against the mark speed.
"""
import html
import math
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

AXES = ["x", "y", "z"]
MM = 1e3


def _table(header, rows):
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in row) + "</tr>"
                   for row in rows)
    return f"<table border=1 cellpadding=4><tr>{head}</tr>{body}</table>"


def _plot_bins(bins, xlabel, title, path):
    fig, ax = plt.subplots(figsize=(7, 3.8))
    centres = [(b["low"] + b["high"]) / 2 for b in bins]
    for i, a in enumerate(AXES):
        ax.plot(centres, [b["rms_m"][i] * MM for b in bins], "o-", label=a)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("RMS dynamic error [mm]")
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _mm(v):
    return "—" if v is None else f"{v * MM:.3f}"


def _page(r, plots):
    p = r["parameters"]
    d = r["dynamic"]
    dyn = []
    for a in AXES:
        x, me = d["all"][a], d["model_error"][a]
        model = "one direction only" if me["mean_m"] is None else \
            f"{_mm(me['mean_m'])} ± {_mm(me['sd_m'])}"
        dyn.append([a, f"{_mm(x['mean_m'])} ± {_mm(x['sd_m'])}", model, _mm(x["sd_m"]),
                    f"{x['u_reference_m'] * MM:.4f}", _mm(x["u_stated_m"])])
    params = [["L = l2²/l1 [m]", f"{p['equivalent_length_m']:.6f}",
               f"{p['equivalent_length_sigma_m']:.2e}"],
              ["β/(m l2²) [1/s]", f"{p['damping_per_inertia_1_s']:.6f}",
               f"{p['damping_per_inertia_sigma_1_s']:.2e}"]]
    if "l2_m" in p:
        params += [["l1 (given) [m]", f"{p['l1_m']:.6f}", f"{p['l1_sigma_m']:.2e}"],
                   ["l2 [m]", f"{p['l2_m']:.6f}", f"{p['l2_sigma_m']:.2e}"],
                   ["β/m [m²/s]", f"{p['beta_per_mass_m2_s']:.3e}",
                    f"{p['beta_per_mass_sigma_m2_s']:.1e}"]]
    params += [[f"pivot {a} (w) [m]", f"{p['pivot_w_m'][i]:.5f}", f"{p['pivot_sigma_m'][i]:.2e}"]
               for i, a in enumerate(AXES)]
    params.append(["plane normal (w)", " ".join(f"{v:.5f}" for v in p["normal_w"]),
                   f"{p['normal_sigma_rad']:.2e} rad"])
    for run in r["runs"]:
        params.append([f"θ0 [deg], {run['direction']} ({os.path.basename(run['marks_csv'])})",
                       f"{math.degrees(run['theta0_rad']):.4f}",
                       f"{math.degrees(run['theta0_sigma_rad']):.4f}"])
        params.append([f"release [s after first exposure] ({os.path.basename(run['marks_csv'])})",
                       f"{run['release_s']:.6f}", f"{run['release_sigma_s']:.1e}"])
    marks = [[m["mark_id"], f"{m['radius_m']:.5f} ± {m['radius_sigma_m'] * MM:.4f} mm",
              f"{math.degrees(m['angle_rad']):.4f} ± {math.degrees(m['angle_sigma_rad']):.4f}",
              f"{m['offset_m'] * MM:.4f} ± {m['offset_sigma_m'] * MM:.4f}"] for m in r["marks"]]
    fit = r["fit"]
    imgs = "".join(f'<p><img src="{name}"></p>' for name in plots)
    return f"""<h1>storetrack-eval: pendulum dynamic calibration</h1>
<p>{html.escape(r['method'])}. g = {r['g_m_s2']:.7f} m/s²; {len(r['runs'])} runs
({d['samples_clockwise']} clockwise, {d['samples_counter_clockwise']} counter-clockwise samples);
{fit['residuals']} residuals, {fit['parameters']} parameters, reduced χ² {fit['reduced_chi_square']:.4f};
covariance scaled by {html.escape(r['covariance_scale'])}.</p>
<h2>Per axis (SisTrO dynamic table), mm, 1σ</h2>
{_table(["axis", "total dynamic error (mean ± sd)", "model error (cw − ccw)",
         "dynamic uncertainty (1σ)", "u of the reference", "u_stated (RMS)"], dyn)}
<h2>Identified parameters (± 1σ)</h2>
{_table(["parameter", "value", "1σ"], params)}
<h2>Marks on the board</h2>
{_table(["mark", "radius [m]", "angle from the centre-of-mass line [deg]", "offset along n [mm]"],
        marks)}
<h2>Growth of the dynamic error</h2>
{imgs}
<p>Inputs: {html.escape(', '.join(r['inputs']['marks_csv']))}.</p>
"""


def write_pendulum_report(r, out_dir):
    """Writes index.html and the PNGs of a storetrack-eval-pendulum result into out_dir."""
    os.makedirs(out_dir, exist_ok=True)
    plots = []
    bins = r["dynamic"]["by_axis_distance_m"]
    if bins:
        _plot_bins(bins, "distance from the reference camera's optical axis [m]",
                   "dynamic error vs distance from the optical axis",
                   os.path.join(out_dir, "pendulum_by_distance.png"))
        plots.append("pendulum_by_distance.png")
    _plot_bins(r["dynamic"]["by_speed_m_s"], "mark speed [m/s]", "dynamic error vs mark speed",
               os.path.join(out_dir, "pendulum_by_speed.png"))
    plots.append("pendulum_by_speed.png")
    with open(os.path.join(out_dir, "index.html"), "w") as f:
        f.write("<!doctype html><html><head><meta charset='utf-8'><title>storetrack-eval"
                "</title></head><body>" + _page(r, plots) + "</body></html>\n")
    return os.path.join(out_dir, "index.html")
