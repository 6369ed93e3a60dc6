"""The report's clearance section (docs/clearance.md, "In the main job"): the host's live
store-to-aircraft clearance with its k = 2 band beside the clearance at the simulator's TRUE store
pose with the same meshes (storetrack-clearance-at-poses), the k = 2 coverage over the samples
with its two-sided binomial acceptance band, the minimum clearance and when, the alarm episodes,
and a plot against time since release. Debian packages only (python3-numpy, matplotlib)."""
import json
import math
import os
import subprocess

import numpy as np

from post_report import K, savefig

ALARM_BIT = 1 << 8  # FtiSample status bit 8: clearance_alarm
P_INSIDE = math.erf(2 / math.sqrt(2))  # P(|d - d_true| <= 2u) = 95.45 %
P_BOUND_HELD = 0.5 * (1 + math.erf(2 / math.sqrt(2)))  # P(d_true >= d - 2u) = 97.72 %


def truth_clearance(tool, geometry, fti, truth):
    """Per sample (row of fti) and aircraft part, the minimum distance at the simulator's TRUE
    T_p_s (NaN where the truth has no such trigger_seq), and the parts' names."""
    idx = {int(s): i for i, s in enumerate(truth["trigger_seq"])}
    cols = ["T_p_s_%s" % c for c in ("x_m", "y_m", "z_m", "rx_rad", "ry_rad", "rz_rad")]
    lines = []
    for seq in fti["trigger_seq"].astype(np.int64):
        j = idx.get(int(seq))
        if j is not None:
            lines.append("%d %s" % (seq, " ".join("%.12g" % truth[c][j] for c in cols)))
    run = subprocess.run([tool, geometry], input="\n".join(lines) + "\n", capture_output=True,
                         text=True, check=False)
    if run.returncode != 0:
        raise RuntimeError("%s %s: exit %d: %s" % (tool, geometry, run.returncode, run.stderr.strip()))
    rows = [r.split(",") for r in run.stdout.strip().splitlines()[1:]]
    names = {}
    by_seq = {}
    for key, part, name, dist, _pen in rows:
        names[int(part)] = name
        by_seq.setdefault(int(key), {})[int(part)] = float(dist)
    d_true = np.full((len(fti["trigger_seq"]), len(names)), np.nan)
    for i, seq in enumerate(fti["trigger_seq"].astype(np.int64)):
        for p, d in by_seq.get(int(seq), {}).items():
            d_true[i, p] = d
    return d_true, [names[p] for p in range(len(names))]


def release_time_ns(run_dir, fallback_ns):
    """The scenario's release (simulator truth: timing.start_tai_ns + separation.release_time_s),
    or the first exposure when the run has no scenario.json with a separation."""
    try:
        s = json.load(open(os.path.join(run_dir, "scenario.json")))
        return s["timing"]["start_tai_ns"] + s["separation"]["release_time_s"] * 1e9, True
    except (OSError, KeyError, ValueError):
        return fallback_ns, False


def alarm_episodes(fti, t):
    """Runs of consecutive samples with the clearance_alarm bit: (first seq, last seq, t first,
    t last, samples, lowest lower bound)."""
    alarm = (fti["status"].astype(np.int64) & ALARM_BIT) != 0
    out, start = [], None
    for i in range(len(alarm) + 1):
        on = i < len(alarm) and alarm[i]
        if on and start is None:
            start = i
        elif not on and start is not None:
            sl = slice(start, i)
            lb = fti["clearance_lower_bound"][sl]
            out.append((int(fti["trigger_seq"][start]), int(fti["trigger_seq"][i - 1]), t[start],
                        t[i - 1], i - start, np.nanmin(lb) if np.isfinite(lb).any() else np.nan))
            start = None
    return out


def clearance_statistics(fti, d_true, t, binomial_acceptance):
    """The live clearance (the nearest part the host picked) against the truth at that part."""
    d, u, lb = fti["clearance"], fti["u_clearance"], fti["clearance_lower_bound"]
    part = np.where(np.isfinite(d), fti["clearance_part"], 0).astype(int)
    dt = d_true[np.arange(len(d)), np.clip(part, 0, d_true.shape[1] - 1)]
    m = np.isfinite(d) & np.isfinite(u) & np.isfinite(dt)
    n = int(m.sum())
    inside = int(np.sum(np.abs(d[m] - dt[m]) <= K * u[m]))
    held = int(np.sum(dt[m] >= lb[m]))
    low, high = binomial_acceptance(n, P_INSIDE, 0.025) if n else (float("nan"),) * 2
    held_low, _ = binomial_acceptance(n, P_BOUND_HELD, 0.025) if n else (float("nan"),) * 2
    nearest_true = np.nanmin(d_true, axis=1)
    i_live = int(np.nanargmin(np.where(m, d, np.nan))) if n else None
    i_lb = int(np.nanargmin(np.where(m, lb, np.nan))) if n else None
    i_true = int(np.nanargmin(nearest_true)) if np.isfinite(nearest_true).any() else None
    return {"n": n, "inside": inside, "coverage": inside / n if n else float("nan"),
            "band": (low, high), "held": held, "held_band_low": held_low,
            "error": d - dt, "d_true_part": dt, "mask": m, "nearest_true": nearest_true,
            "min_live": (d[i_live], u[i_live], t[i_live], int(fti["trigger_seq"][i_live]))
            if i_live is not None else None,
            "min_bound": (lb[i_lb], t[i_lb]) if i_lb is not None else None,
            "min_true": (nearest_true[i_true], t[i_true]) if i_true is not None else None,
            "episodes": alarm_episodes(fti, t)}


def plot_clearance(fti, st, t, t_label, names, d_true, threshold, outdir, figures):
    import matplotlib.pyplot as plt
    m = st["mask"]
    d, u, lb = fti["clearance"], fti["u_clearance"], fti["clearance_lower_bound"]
    fig, axs = plt.subplots(2, 1, figsize=(11, 7), sharex=True)
    ax = axs[0]
    for p, name in enumerate(names):
        ax.plot(t, d_true[:, p], "-", lw=0.8, alpha=0.5, label="truth: %s" % name)
    ax.fill_between(t[m], (d - K * u)[m], (d + K * u)[m], color="tab:green", alpha=0.4,
                    label="live ± k u (k = 2), nearest part")
    ax.plot(t[m], d[m], ".", ms=2, color="tab:blue", label="live clearance")
    ax.plot(t[m], lb[m], "-", lw=0.8, color="tab:red", label="live lower bound")
    if threshold is not None and np.isfinite(threshold):
        ax.axhline(threshold, ls="--", color="k", lw=0.8, label="alarm threshold")
    ax.set_ylabel("clearance [m]")
    ax.set_yscale("log")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7)
    ax = axs[1]
    ax.fill_between(t[m], -K * u[m] * 1e3, K * u[m] * 1e3, color="tab:green", alpha=0.3,
                    label="± k u (k = 2)")
    ax.plot(t[m], st["error"][m] * 1e3, ".", ms=2, color="tab:red",
            label="live - truth (same part)")
    ax.set_ylabel("error [mm]")
    ax.set_xlabel(t_label)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.suptitle("Store-to-aircraft clearance: live (host) against the simulator's true pose")
    savefig(fig, outdir, "clearance.png", figures)


def write_clearance_csv(path, fti, st, t, names, d_true):
    """Per sample: the live clearance of the nearest part with u, the k = 2 band and bound, the
    truth at that part, whether it is inside the band, and the truth for every part."""
    with open(path, "w") as f:
        f.write("trigger_seq,t_since_release_s,part,clearance_m,u_clearance_m,band_low_m,band_high_m,"
                "lower_bound_m,alarm,true_clearance_part_m,inside_k2,%s\n"
                % ",".join("true_%s_m" % n.replace(" ", "_") for n in names))
        for i in range(len(t)):
            d, u = fti["clearance"][i], fti["u_clearance"][i]
            f.write("%d,%.6f,%s,%.6f,%.6f,%.6f,%.6f,%.6f,%d,%.6f,%s,%s\n" % (
                fti["trigger_seq"][i], t[i],
                int(fti["clearance_part"][i]) if np.isfinite(d) else "", d, u, d - K * u, d + K * u,
                fti["clearance_lower_bound"][i], (int(fti["status"][i]) & ALARM_BIT) != 0,
                st["d_true_part"][i], int(abs(d - st["d_true_part"][i]) <= K * u) if st["mask"][i] else "",
                ",".join("%.6f" % x for x in d_true[i])))


def clearance_section(fti, truth, run_dir, tool, geometry, threshold, outdir, figures,
                      binomial_acceptance):
    """The section's table rows and note; None without clearance in the samples."""
    if "clearance" not in fti or not np.isfinite(fti["clearance"]).any():
        return None
    d_true, names = truth_clearance(tool, geometry, fti, truth)
    t_ns = fti["exposure_mid_tai_ns"]
    t0, is_release = release_time_ns(run_dir, t_ns[0])
    t = (t_ns - t0) * 1e-9
    t_label = "time since release [s]" if is_release else "time since the first exposure [s]"
    st = clearance_statistics(fti, d_true, t, binomial_acceptance)
    plot_clearance(fti, st, t, t_label, names, d_true, threshold, outdir, figures)
    write_clearance_csv(os.path.join(outdir, "clearance.csv"), fti, st, t, names, d_true)
    lo, hi = st["band"]
    rows = [("samples with a clearance and a truth (n)", "%d" % st["n"]),
            ("|live - truth| <= 2u (k = 2 coverage)", "%d of %d = %.1f %%" % (
                st["inside"], st["n"], 100 * st["coverage"])),
            ("  acceptance band (Binomial(n, 95.45 %), 2.5 % per side)", "%.1f .. %.1f %%: %s" % (
                100 * lo, 100 * hi,
                "inside" if lo <= st["coverage"] <= hi else
                ("BELOW (u too small?)" if st["coverage"] < lo else
                 "above (one shared draw: see the note)"))),
            ("truth >= lower bound", "%d of %d = %.1f %% (>= 97.7 %% by the rule; band low %.1f %%)"
             % (st["held"], st["n"], 100 * st["held"] / max(st["n"], 1), 100 * st["held_band_low"]))]
    if st["min_live"]:
        d, u, tm, seq = st["min_live"]
        rows.append(("minimum live clearance", "%.4f m (u %.2f mm) at %.3f s (trigger_seq %d)" % (
            d, u * 1e3, tm, seq)))
        rows.append(("minimum lower bound", "%.4f m at %.3f s" % st["min_bound"]))
    if st["min_true"]:
        rows.append(("minimum true clearance (any part)", "%.4f m at %.3f s" % st["min_true"]))
    rms = np.sqrt(np.mean(st["error"][st["mask"]] ** 2)) if st["n"] else float("nan")
    rows.append(("RMS live - truth / mean u", "%.3f mm / %.3f mm" % (
        rms * 1e3, np.mean(fti["u_clearance"][st["mask"]]) * 1e3 if st["n"] else float("nan"))))
    for p, name in enumerate(names):
        col = d_true[:, p]
        if np.isfinite(col).any():
            rows.append(("true clearance to %s: min / max" % name, "%.4f / %.4f m" % (
                np.nanmin(col), np.nanmax(col))))
    if threshold is not None:
        rows.append(("alarm threshold (k = 2 lower bound)", "%.3f m" % threshold))
    rows.append(("alarm episodes", "%d" % len(st["episodes"])))
    for k, (s0, s1, ta, tb, count, lbmin) in enumerate(st["episodes"]):
        rows.append(("  episode %d" % (k + 1), "trigger_seq %d..%d (%.3f .. %.3f s), %d samples, "
                     "lowest bound %.4f m" % (s0, s1, ta, tb, count, lbmin)))
    note = ("Per sample: clearance.csv. Live: the host's nearest part (lowest k = 2 lower bound) per sample. Truth: the same "
            "meshes evaluated at the simulator's true store pose (storetrack-clearance-at-poses). "
            "The samples of one run share one calibration and survey draw, so their errors are "
            "correlated and the binomial band (which assumes independent samples) is a check of "
            "this run, not a calibration of the stated uncertainty over draws.")
    return {"rows": rows, "note": note, "stats": st, "names": names}


def pooled_clearance_row(run_dirs, tool, geometry, binomial_acceptance, bootstrap_interval,
                         read_csv):
    """The clearance's row of the report's pooled table (tools/testpoint --draws N): |d - d_true|
    <= 2u pooled over runs with different seeds (calibration and survey draws), its 95 %
    bootstrap interval over whole draws, and the range an honest instrument's pooled coverage
    falls in when each draw counts as one sample (Binomial(draws, 0.9545)); None without
    clearance samples."""
    errors, us, draws, used = [], [], [], 0
    for d in run_dirs:
        fti = read_csv(os.path.join(d, "fti.csv"))
        truth = read_csv(os.path.join(d, "sim", "truth_poses.csv"))
        if fti is None or truth is None or "clearance" not in fti:
            continue
        d_true, _ = truth_clearance(tool, geometry, fti, truth)
        st = clearance_statistics(fti, d_true, np.zeros(len(d_true)), binomial_acceptance)
        m = st["mask"]
        errors.extend(st["error"][m])
        us.extend(fti["u_clearance"][m])
        draws.extend([used] * int(m.sum()))
        used += 1
    if not errors:
        return None
    e, u, draw = np.array(errors), np.array(us), np.array(draws)
    z = e / u
    inside = np.abs(z) <= K
    lo, hi = bootstrap_interval(inside, draw)
    honest = binomial_acceptance(used, P_INSIDE, 0.025)
    return ("clearance (nearest part)", "mm", len(e), "-", "%.4f" % np.sqrt(np.mean((e * 1e3) ** 2)),
            "%.4f" % np.mean(u * 1e3), "%.1f" % (100.0 * np.mean(inside)),
            "%.1f" % (100.0 * np.mean(inside)), "%.1f .. %.1f" % (100.0 * lo, 100.0 * hi),
            "%.1f .. %.1f" % (100.0 * honest[0], 100.0 * honest[1]), "%.2f" % np.sqrt(np.mean(z * z)))
