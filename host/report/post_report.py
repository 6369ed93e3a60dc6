"""The truth-free parts of the storetrack reports: what storetrack-post --report DIR writes
(docs/post-processing.md), rendered as PNG plots and summary rows. storetrack_post_report.py
renders a report directory alone; storetrack_report.py (the main job's report) calls the same
functions with the simulator's truth added. Debian packages only (python3-matplotlib,
python3-numpy)."""
import json
import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from storetrack_csv import read_csv  # noqa: E402

K = 2.0  # coverage factor of the bands (GUM expanded uncertainty)
AXES_POS = ["x", "y", "z"]
AXES_ATT = ["yaw", "pitch", "roll"]


def savefig(fig, outdir, name, figures):
    fig.savefig(os.path.join(outdir, name), dpi=90, bbox_inches="tight")
    plt.close(fig)
    figures.append(name)


def load_post_dir(d):
    """The tables storetrack-post --report wrote into d (None for those absent)."""
    report_json = os.path.join(d, "report.json")
    if not os.path.exists(report_json):
        raise SystemExit("report: %s: no report.json (not a storetrack-post --report directory)"
                         % d)
    report = json.load(open(report_json))
    files = report.get("files", {})

    def table(key, default_name):
        path = files.get(key) or os.path.join(d, default_name)
        return read_csv(path) if path else None

    return {"report": report, "samples": table("samples", "samples.csv"),
            "smoothed": table("smoothed", "smoothed.csv"),
            "product": table("product", "product.csv"),
            "residuals": read_csv(os.path.join(d, "residuals.csv")),
            "windows": read_csv(os.path.join(d, "residual_windows.csv")),
            "exposures": read_csv(os.path.join(d, "exposures.csv")),
            # Absent when the recorded run had the calibration health test off.
            "health": read_csv(os.path.join(d, "calibration_health.csv"))}


def seconds(t_tai_ns, t0_ns):
    return (np.asarray(t_tai_ns, dtype=float) - t0_ns) * 1e-9


def plot_pose(fti, smoothed, t0_ns, outdir, figures, truth_err=None):
    """Store position and attitude relative to the pylon with k = 2 bands: the real-time samples
    (fti.csv columns) beside the smoothed trajectory (smoothed.csv), the simulator's truth when
    given as the real-time samples' errors (storetrack_report.store_pose_errors)."""
    t = seconds(fti["exposure_mid_tai_ns"], t0_ns)
    valid = (fti["status"].astype(int) & 1) == 1
    ts = seconds(smoothed["exposure_mid_tai_ns"], t0_ns) if smoothed is not None else None
    for axes, name, scale, unit, title in (
            (AXES_POS, "trajectory.png", 1e3, "mm",
             "Store position relative to the pylon (T_p_s) with k = 2 uncertainty bands"),
            (AXES_ATT, "attitude.png", 180 / np.pi, "deg",
             "Store attitude relative to the pylon with k = 2 uncertainty bands")):
        fig, axs = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
        for ax, a in zip(axs, axes):
            v, u = fti[a] * scale, fti["u_" + a] * scale
            ax.fill_between(t[valid], (v - K * u)[valid], (v + K * u)[valid], alpha=0.3,
                            color="tab:blue", label="real-time k = 2")
            ax.plot(t[valid], v[valid], ".", ms=2, color="tab:blue", label="real-time")
            if smoothed is not None:
                col = a + ("_m" if a in AXES_POS else "_rad")
                vs, us = smoothed[col] * scale, smoothed["u_" + col] * scale
                ax.fill_between(ts, vs - K * us, vs + K * us, alpha=0.3, color="tab:green",
                                label="smoothed k = 2")
                ax.plot(ts, vs, "-", lw=0.8, color="tab:green", label="smoothed")
            if truth_err is not None:
                ax.plot(t, v - truth_err[a] * scale, "-", lw=0.8, color="k",
                        label="truth (simulator)")
            ax.set_ylabel("%s [%s]" % (a, unit))
            ax.grid(alpha=0.3)
        axs[0].legend(loc="best", fontsize=8)
        axs[0].set_title(title)
        axs[-1].set_xlabel("time since first exposure [s]")
        savefig(fig, outdir, name, figures)


def plot_rates(smoothed, product, t0_ns, outdir, figures):
    """CG velocity (data product; the smoothed origin's without a CG) and body rates p, q, r
    (data product; the smoothed angular rate without), each with its k = 2 band."""
    if smoothed is None:
        return
    src = product if product is not None else smoothed
    t = seconds(src["exposure_mid_tai_ns"], t0_ns)
    if product is not None:
        rows = [("vx", "vx_ac_m_s", 1.0, "m/s"), ("vy", "vy_ac_m_s", 1.0, "m/s"),
                ("vz", "vz_ac_m_s", 1.0, "m/s"), ("p", "p_rad_s", 180 / np.pi, "deg/s"),
                ("q", "q_rad_s", 180 / np.pi, "deg/s"), ("r", "r_rad_s", 180 / np.pi, "deg/s")]
        what = "CG velocity (aircraft axes) and body rates p, q, r (data product)"
    else:
        rows = [("vx", "vx_m_s", 1.0, "m/s"), ("vy", "vy_m_s", 1.0, "m/s"),
                ("vz", "vz_m_s", 1.0, "m/s"), ("wx", "wx_rad_s", 180 / np.pi, "deg/s"),
                ("wy", "wy_rad_s", 180 / np.pi, "deg/s"), ("wz", "wz_rad_s", 180 / np.pi, "deg/s")]
        what = "velocity and angular rate (smoothed; no CG in the store survey)"
    fig, axs = plt.subplots(3, 2, figsize=(13, 8), sharex=True)
    for ax, (label, col, scale, unit) in zip(axs.T.flat, rows):
        v, u = src[col] * scale, src["u_" + col] * scale
        ax.fill_between(t, v - K * u, v + K * u, alpha=0.35, color="tab:green", label="k = 2")
        ax.plot(t, v, "-", lw=0.8, color="tab:green")
        ax.set_ylabel("%s [%s]" % (label, unit))
        ax.grid(alpha=0.3)
    axs[0][0].legend(fontsize=8)
    for ax in axs[-1]:
        ax.set_xlabel("time since first exposure [s]")
    fig.suptitle("Smoothed " + what)
    savefig(fig, outdir, "rates.png", figures)


def plot_residual_windows(windows, t0_ns, outdir, figures):
    """Per camera: the noise part of its reprojection residuals (differences of consecutive
    exposures normalised by the centroid noise's predicted spread), RMS per window of exposures
    (expected 1), with each window's 0.95 chi-square band."""
    if windows is None or len(windows.get("camera_id", [])) == 0:
        return
    cams = sorted(set(int(c) for c in windows["camera_id"]))
    fig, axs = plt.subplots(len(cams), 1, figsize=(10, 2.2 * len(cams)), sharex=True,
                            squeeze=False)
    for ax, c in zip(axs[:, 0], cams):
        m = windows["camera_id"] == c
        t = seconds((windows["first_t_tai_ns"][m] + windows["last_t_tai_ns"][m]) / 2, t0_ns)
        ax.fill_between(t, windows["band_low"][m], windows["band_high"][m], step="mid",
                        alpha=0.3, color="tab:gray", label="0.95 chi-square band")
        inside = windows["inside"][m] == 1
        ax.plot(t[inside], windows["rms_normalised"][m][inside], "o", ms=3, color="tab:blue",
                label="inside")
        ax.plot(t[~inside], windows["rms_normalised"][m][~inside], "o", ms=3, color="tab:red",
                label="outside")
        ax.axhline(1.0, color="k", lw=0.6)
        ax.set_ylabel("camera %d" % c)
        ax.grid(alpha=0.3)
    axs[0][0].legend(fontsize=8, loc="upper right")
    axs[-1][0].set_xlabel("time since first exposure [s]")
    fig.suptitle("Noise part: RMS of the normalised residual differences per window (expected 1)")
    savefig(fig, outdir, "residual_windows.png", figures)


def plot_rigid_fits(exposures, t0_ns, outdir, figures):
    """The pose fits' chi-square per exposure over its 0.99 quantile (above 1: exceeds)."""
    if exposures is None or len(exposures.get("trigger_seq", [])) == 0:
        return
    t = seconds(exposures["t_tai_ns"], t0_ns)
    fig, ax = plt.subplots(figsize=(10, 3))
    for body, color in (("store", "tab:orange"), ("pylon", "tab:blue")):
        m = np.isfinite(exposures[body + "_chi2_q99"])
        ax.semilogy(t[m], exposures[body + "_chi2"][m] / exposures[body + "_chi2_q99"][m], ".",
                    ms=2, color=color, label=body)
    ax.axhline(1.0, color="tab:red", lw=0.8, label="0.99 quantile")
    ax.set_ylabel("chi2 / its 0.99 quantile")
    ax.set_xlabel("time since first exposure [s]")
    ax.legend(fontsize=8)
    ax.grid(alpha=0.3)
    ax.set_title("Rigid-body pose fits: chi-square against its 0.99 quantile (3 n - 6 dof)")
    savefig(fig, outdir, "rigid_fits.png", figures)


def plot_camera_usage(residuals, t0_ns, outdir, figures):
    """Which camera delivered each exposure (gaps: the aligner closed it without the camera)."""
    if residuals is None or len(residuals.get("camera_id", [])) == 0:
        return
    cams = sorted(set(int(c) for c in residuals["camera_id"]))
    fig, ax = plt.subplots(figsize=(10, 0.5 + 0.5 * len(cams)))
    for i, c in enumerate(cams):
        m = residuals["camera_id"] == c
        t = seconds(residuals["t_tai_ns"][m], t0_ns)
        d = residuals["delivered"][m] == 1
        ax.plot(t[d], np.full(d.sum(), i), "|", ms=8, color="tab:green")
        ax.plot(t[~d], np.full((~d).sum(), i), "|", ms=10, color="tab:red")
    ax.set_yticks(range(len(cams)), ["camera %d" % c for c in cams])
    ax.set_xlabel("time since first exposure [s]")
    ax.set_title("Camera usage: green delivered, red missing")
    savefig(fig, outdir, "camera_usage.png", figures)


def camera_rows(residuals):
    """Per camera: exposures delivered / missing, residuals, the noise part's overall RMS."""
    rows = []
    if residuals is None or len(residuals.get("camera_id", [])) == 0:
        return rows
    for c in sorted(set(int(c) for c in residuals["camera_id"])):
        m = residuals["camera_id"] == c
        d = residuals["delivered"][m] == 1
        dof = residuals["noise_dof"][m].sum()
        rms = np.sqrt(residuals["noise_chi2"][m].sum() / dof) if dof > 0 else float("nan")
        rows.append(("camera %d: exposures delivered / missing, residuals, noise part RMS "
                     "normalised (expected 1)" % c,
                     "%d / %d, %d, %.3f" % (d.sum(), (~d).sum(), residuals["residuals"][m].sum(),
                                            rms)))
    return rows


def calibration_rows(report):
    """The shared (calibration) part: one chi-square per camera for the whole recording, or per
    span of one calibration where correct mode rebuilt the processor on a corrected rig."""
    cal = report.get("calibration_residuals")
    if not cal:
        return []
    rows = []
    spans = len({c.get("span", 0) for c in cal["per_camera"]})
    for c in cal["per_camera"]:
        what = "camera %d" % c["camera_id"]
        if spans > 1:
            what += ", calibration %s (trigger_seq %d .. %d)" % (
                "as recorded" if c["span"] == 0 else "corrected #%d" % c["span"],
                c["first_trigger_seq"], c["last_trigger_seq"])
        verdict = ""
        if c["chi2"] > c["band_high"]:
            verdict = "  ABOVE: calibration off by more than stated"
        elif c["chi2"] < c["band_low"]:
            verdict = "  BELOW: stated calibration uncertainty larger than the residuals show"
        rows.append(("%s: calibration part chi-square (one draw for the %s)"
                     % (what, "span" if spans > 1 else "recording"),
                     "%.1f on %d dof (%.4f band %.1f .. %.1f)%s" % (
                         c["chi2"], c["dof"], cal["band_probability"], c["band_low"], c["band_high"],
                         verdict)))
    return rows


def summary_rows(report):
    """Integrity and statistics rows from report.json."""
    i = report["integrity"]
    rows = []
    for f in i["files"]:
        rows.append(("file %s: packets / bytes (whole packets)" % f["file"],
                     "%d / %d (%d)" % (f["packets"], f["file_bytes"], f["bytes_in_whole_packets"])))
        rows.append(("file %s: header / data checksum errors, sequence-gap packets, raw data / "
                     "format errors, torn" % f["file"],
                     "%d / %d, %d, %d / %d, %s" % (
                         f["header_checksum_errors"], f["data_checksum_errors"],
                         f["sequence_gap_packets"], f["raw_data_errors"], f["raw_format_errors"],
                         ("yes: " + f["stop_reason"]) if f["torn"] else "no")))
    rows.append(("continuation files read", str(i["continuation_files"])))
    rows.append(("raw packets missing between files", "; ".join(i["gaps_between_files"]) or "none"))
    rows.append(("raw records / refused live / undecodable",
                 "%d / %d / %d" % (i["raw_records"], i["refused_live"], i["undecodable"])))
    rows.append(("exposures processed / missing from the trigger sequence",
                 "%d / %d" % (i["exposures_processed"], i["exposures_missing"])))
    rows.append(("host ended normally (final flush recorded)",
                 "yes" if i["host_ended_normally"] else "NO"))
    w = report["residual_windows"]
    if w["windows"]:
        rows.append(("noise-part residual windows (%d exposures) inside their 0.95 band"
                     % w["window_exposures"],
                     "%d of %d (an honest spread: %d .. %d)%s" % (
                         w["inside"], w["windows"], w["inside_band_low"], w["inside_band_high"],
                         "" if w["acceptable"] else "  OUTSIDE")))
    for body in ("store", "pylon"):
        x = report["rigid_" + body]
        if x["fits"]:
            rows.append(("%s pose fits above the chi-square 0.99 quantile" % body,
                         "%d of %d (an honest spread: %d .. %d)%s" % (
                             x["above_quantile"], x["fits"], x["band_low"], x["band_high"],
                             "" if x["inside"] else "  OUTSIDE")))
    return rows


def plot_calibration_health(health, t0_ns, outdir, figures):
    """Per camera: the calibration health test's chi-square(6) statistic per window against its
    alarm threshold (docs/calibration-health.md), the windows after a camera was declared moved
    marked."""
    if health is None or len(health.get("camera_id", [])) == 0:
        return
    cams = sorted(set(int(c) for c in health["camera_id"]))
    fig, axs = plt.subplots(len(cams), 1, figsize=(10, 2.0 * len(cams)), sharex=True,
                            squeeze=False)
    for ax, c in zip(axs[:, 0], cams):
        m = health["camera_id"] == c
        t = seconds(health["t_tai_ns"][m], t0_ns)
        moved = health["moved"][m] == 1
        ax.semilogy(t[~moved], health["statistic"][m][~moved], "o", ms=3, color="tab:blue",
                    label="window statistic")
        ax.semilogy(t[moved], health["statistic"][m][moved], "o", ms=3, color="tab:red",
                    label="camera declared moved")
        ax.plot(t, health["threshold"][m], color="k", lw=0.8, label="alarm threshold")
        ax.set_ylabel("camera %d" % c)
        ax.grid(alpha=0.3)
    axs[0][0].legend(fontsize=8, loc="upper left")
    axs[-1][0].set_xlabel("time since first exposure [s]")
    fig.suptitle("Calibration health: chi-square(6) of each window's camera motion (alarm above "
                 "the threshold)")
    savefig(fig, outdir, "calibration_health.png", figures)


def health_rows(health):
    """Per camera: windows tested, alarms, and whether and when it was declared moved."""
    if health is None or len(health.get("camera_id", [])) == 0:
        return [("calibration health test", "off in the recorded run (no calibration_health.csv)")]
    rows = []
    for c in sorted(set(int(c) for c in health["camera_id"])):
        m = health["camera_id"] == c
        moved = np.nonzero(health["moved"][m] == 1)[0]
        rows.append(("camera %d: calibration health windows / alarms" % c,
                     "%d / %d%s" % (int(m.sum()), int((health["alarm"][m] == 1).sum()),
                                    "; MOVED from trigger_seq %d" % int(health["trigger_seq"][m][moved[0]])
                                    if len(moved) else "")))
    return rows


def render_post(post, outdir, figures, summary, t0_ns, truth_err=None, fti=None):
    """Every truth-free section of a storetrack-post --report directory (load_post_dir): plots
    into outdir (names appended to figures), rows appended to summary. fti: the real-time
    samples to plot (default: the replayed ones the directory holds)."""
    fti = fti if fti is not None else post["samples"]
    plot_pose(fti, post["smoothed"], t0_ns, outdir, figures, truth_err)
    plot_rates(post["smoothed"], post["product"], t0_ns, outdir, figures)
    plot_residual_windows(post["windows"], t0_ns, outdir, figures)
    plot_rigid_fits(post["exposures"], t0_ns, outdir, figures)
    plot_camera_usage(post["residuals"], t0_ns, outdir, figures)
    plot_calibration_health(post["health"], t0_ns, outdir, figures)
    summary.extend(camera_rows(post["residuals"]))
    summary.extend(health_rows(post["health"]))
    summary.extend(calibration_rows(post["report"]))
    summary.extend(summary_rows(post["report"]))
