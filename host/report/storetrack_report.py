#!/usr/bin/env python3
"""storetrack test-point report: HTML page + PNG plots + a printed summary table.

Reads a test-point run directory (tools/testpoint): fti.csv (samples), marks.csv (per-mark
observations and residuals), rigid.csv (rigid-body pair tests), stats.json (host counters),
storetrack.ch10 (Chapter 10 file, re-read here with a small independent parser) and the
simulator's truth (truth_poses.csv, truth_marks.csv). Plots: store trajectory and attitude with
k = 2 uncertainty bands, error against truth with the k = 2 band, mark position errors, rigid-body
residuals, per-camera residual maps, the uncertainty budget. Debian packages only
(python3-matplotlib, python3-numpy).
"""
import argparse
import csv
import html
import json
import math
import os
import re
import struct
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

# The FTI sample's u_budget_extrinsic: extrinsic calibration, world registration AND the pylon
# and store mark surveys (schema fti_sample.yaml).
EXTRINSIC_LABEL = "extrinsic / registration / body survey"

from post_report import (AXES_ATT, AXES_POS, K, load_post_dir, plot_pose, render_post,  # noqa: E402
                         savefig)
from storetrack_csv import read_csv  # noqa: E402
from clearance_report import clearance_section, pooled_clearance_row  # noqa: E402


class Checks:
    """The verdicts of a test script against truth: check(cond, what) prints "ok" or "FAIL" and
    what was checked, and keeps the failed ones (the script exits non-zero when there are any)."""

    def __init__(self):
        self.failures = []

    def __call__(self, cond, what):
        print(("ok   " if cond else "FAIL ") + what)
        if not cond:
            self.failures.append(what)
        return bool(cond)


def read_ch10(path):
    """Minimal independent Chapter 10 pass: packet count by data type, checksums, messages of
    the sample channel, the raw channel's observations (RawObservation records, the channel TMATS
    names RAWOBS) and the recorded inputs (RecordedInput records in Computer-Generated F0
    packets, chunks joined), decoded from docs/icd.md's tables."""
    out = {"packets": 0, "by_type": {}, "messages": 0, "header_checksum_errors": 0,
           "truncated_bytes": 0, "first_type": None, "raw_channel": None,
           "raw_observations": [], "inputs": []}
    if not os.path.exists(path):
        return None
    data = open(path, "rb").read()
    at = 0
    while at + 24 <= len(data):
        sync, chan, plen, dlen, ver, seq, flags, dtype = struct.unpack_from("<HHIIBBBB", data, at)
        if sync != 0xEB25 or plen < 24 or at + plen > len(data):
            break
        words = struct.unpack_from("<11H", data, at)
        if (sum(words) & 0xFFFF) != struct.unpack_from("<H", data, at + 22)[0]:
            out["header_checksum_errors"] += 1
        if out["first_type"] is None:
            out["first_type"] = dtype
        out["packets"] += 1
        out["by_type"][dtype] = out["by_type"].get(dtype, 0) + 1
        body = data[at + 24:at + 24 + dlen]
        if dtype == 0x01 and out["raw_channel"] is None:
            tmats = body[4:].decode("ascii", "replace")
            m = re.search(r"R-1\\DSI-(\d+):RAWOBS;", tmats)
            t = m and re.search(r"R-1\\TK1-%s:(\d+);" % m.group(1), tmats)
            out["raw_channel"] = int(t.group(1)) if t else -1
        if dtype == 0x30 and chan == out["raw_channel"]:
            count = struct.unpack_from("<I", body, 0)[0] & 0xFFFF
            p = 4
            for _ in range(count):
                rtc = struct.unpack_from("<Q", body, p)[0] & 0xFFFFFFFFFFFF
                iph = struct.unpack_from("<I", body, p + 8)[0]
                n = iph & 0xFFFF
                rec = body[p + 12:p + 12 + n]
                if rec[0] != 2:  # version 2 (docs/icd.md); version 1 had no host_mono_ns
                    raise ValueError("%s: raw observation version %d at offset %d: this reader "
                                     "decodes version 2 only" % (path, rec[0], at))
                (version, kind, arrival, address, port, unit, camera, rflags, error, received,
                 host_mono, length) = struct.unpack_from(">BBqIHBBBBIqH", rec, 0)
                out["raw_observations"].append({
                    "rtc": rtc, "version": version, "source_kind": kind, "arrival_tai_ns": arrival,
                    "source_address": address, "source_port": port, "unit_id": unit,
                    "camera_id": camera, "flags": rflags, "decode_error": error,
                    "received_bytes": received, "host_mono_ns": host_mono,
                    "bytes": rec[34:34 + length],
                    "data_error": bool(iph >> 31)})
                p += 12 + n + (n & 1)
        elif dtype == 0x30:
            out["messages"] += struct.unpack_from("<I", body, 0)[0] & 0xFFFF
        elif dtype == 0x00 and len(body) >= 52:
            rec = body[4:]
            version, kind = rec[0], rec[1]
            sha = rec[2:34].hex()
            total, offset, chunk, name_bytes = struct.unpack_from(">IIIH", rec, 34)
            name = rec[48:48 + name_bytes].decode("utf-8", "replace")
            content = rec[48 + name_bytes:48 + name_bytes + chunk]
            if offset == 0:
                out["inputs"].append({"version": version, "kind": kind, "name": name,
                                      "sha256": sha, "total_bytes": total, "bytes": b""})
            if out["inputs"] and out["inputs"][-1]["sha256"] == sha:
                out["inputs"][-1]["bytes"] += content
        at += plen
    out["truncated_bytes"] = len(data) - at
    return out


def store_pose_errors(fti, truth):
    """Store pose error against the simulator's T_p_s per sample (NaN where no truth or the
    sample is invalid): dict axis -> array (m for x/y/z, rad for yaw/pitch/roll), or None when
    the truth has no moving tracked body."""
    if truth is None or "T_p_s_x_m" not in truth:
        return None
    seq = fti["trigger_seq"].astype(np.int64)
    valid = (fti["status"].astype(int) & 1) == 1
    idx = {s: i for i, s in enumerate(truth["trigger_seq"].astype(np.int64))}
    sel = np.array([idx.get(s, -1) for s in seq])
    ok = (sel >= 0) & valid
    moving = np.any(truth["T_p_s_x_m"] != 0) or np.any(truth["T_p_s_z_m"] != 0)
    if not ok.any() or not moving:
        return None
    err = {}
    for a in AXES_POS:
        tv = np.full(len(seq), np.nan)
        tv[ok] = truth["T_p_s_%s_m" % a][sel[ok]]
        err[a] = fti[a] - tv
    for a in AXES_ATT:
        tv = np.full(len(seq), np.nan)
        tv[ok] = truth["T_p_s_%s_rad" % a][sel[ok]]
        e = fti[a] - tv
        err[a] = (e + np.pi) % (2 * np.pi) - np.pi
    return err


def mark_errors(marks, truth_marks):
    """Triangulated mark position errors against truth, one per mark and exposure (marks.csv
    has one row per observation; excluded marks are skipped): lists ex, ey, ez, ux, uy, uz [m].
    The cameras ride on the pylon pod, so the host measures in the world frame as the rig
    realises it (w0: pod vibration cancels); scored against that truth when the simulator gives
    it (x_w0_m...)."""
    out = [[] for _ in range(6)]
    if marks is None or truth_marks is None or len(marks.get("trigger_seq", [])) == 0:
        return out
    w0 = "%s_w0_m" if "x_w0_m" in truth_marks else "%s_w_m"
    key = {}
    for i in range(len(truth_marks["trigger_seq"])):
        key[(int(truth_marks["trigger_seq"][i]), int(truth_marks["mark_id"][i]))] = i
    seen = set()
    for i in range(len(marks["trigger_seq"])):
        k = (int(marks["trigger_seq"][i]), int(marks["mark_id"][i]))
        if k in seen or k not in key or int(marks["excluded"][i]) == 1:
            continue
        seen.add(k)
        j = key[k]
        for a, axis in enumerate("xyz"):
            out[a].append(marks[axis + "_w"][i] - truth_marks[w0 % axis][j])
            out[3 + a].append(marks["u_%s_w" % axis][i])
    return out


def binomial_acceptance(n, p=0.954499736, alpha_per_side=0.025):
    """Acceptance interval [low, high] / n of a count X ~ Binomial(n, p): the largest low and
    smallest high with P(X < low) <= alpha and P(X > high) <= alpha (the host's
    uncertainty::binomial_interval, here for the report)."""
    pmf = [math.exp(math.lgamma(n + 1) - math.lgamma(k + 1) - math.lgamma(n - k + 1) +
                    k * math.log(p) + (n - k) * math.log1p(-p)) for k in range(n + 1)]
    low, acc = 0, 0.0
    while low <= n and acc + pmf[low] <= alpha_per_side:
        acc += pmf[low]
        low += 1
    high, acc = n, 0.0
    while high >= 0 and acc + pmf[high] <= alpha_per_side:
        acc += pmf[high]
        high -= 1
    return low / n, high / n


def cluster_bootstrap_interval(inside, draw, resamples=2000, seed=1):
    """95 % percentile interval of the pooled coverage, resampling whole draws with replacement:
    the samples of one draw share its calibration errors, so the draws, not the samples, are
    the independent units."""
    draws = np.unique(draw)
    per_draw = [inside[draw == d] for d in draws]
    sums = np.array([x.sum() for x in per_draw], dtype=float)
    counts = np.array([len(x) for x in per_draw], dtype=float)
    rng = np.random.default_rng(seed)
    pick = rng.integers(0, len(draws), size=(resamples, len(draws)))
    cov = sums[pick].sum(axis=1) / counts[pick].sum(axis=1)
    return np.percentile(cov, 2.5), np.percentile(cov, 97.5)


def pooled_coverage(run_dirs):
    """Coverage of the k = 2 intervals pooled over runs with different simulator seeds, i.e.
    different draws of the calibration and survey errors. Within one run those errors are ONE
    draw shared by every sample, so one run's coverage is one sample of it; only the pool over
    draws checks the stated uncertainty (JCGM 101 style). Each row carries the 95 % bootstrap
    interval of its pooled coverage over draws, and the interval an honest instrument's pooled
    coverage falls in with 95 % probability when each draw contributes one sample (binomial,
    n = draws: the widest the within-draw correlation allows). Returns (rows, draws used)."""
    pose = {a: ([], [], []) for a in AXES_POS + AXES_ATT}
    no_pose = 0  # samples the host wrote without a valid store pose: counted, not scored
    mk = [[] for _ in range(9)]
    used = 0
    for d in run_dirs:
        fti = read_csv(os.path.join(d, "fti.csv"))
        truth = read_csv(os.path.join(d, "sim", "truth_poses.csv"))
        if fti is None or truth is None or len(fti.get("trigger_seq", [])) == 0:
            print("report: %s: no samples or no truth, left out of the pool" % d, file=sys.stderr)
            continue
        err = store_pose_errors(fti, truth)
        if err is not None:
            no_pose += int((~np.isfinite(err["x"])).sum())
            for a in AXES_POS + AXES_ATT:
                m = np.isfinite(err[a])
                pose[a][0].extend(err[a][m])
                pose[a][1].extend(fti["u_" + a][m])
                pose[a][2].extend([used] * int(m.sum()))
        me = mark_errors(read_csv(os.path.join(d, "marks.csv")),
                         read_csv(os.path.join(d, "sim", "truth_marks.csv")))
        for i in range(6):
            mk[i].extend(me[i])
        for i in range(3):
            mk[6 + i].extend([used] * len(me[i]))
        used += 1
    rows = []
    series = [("store " + a, "mm" if a in AXES_POS else "deg", pose[a][0], pose[a][1], pose[a][2])
              for a in AXES_POS + AXES_ATT]
    series += [("mark %s_w" % a, "mm", mk[i], mk[3 + i], mk[6 + i]) for i, a in enumerate("xyz")]
    honest = binomial_acceptance(used) if used > 0 else (float("nan"), float("nan"))
    for name, unit, e, u, draw in series:
        if not e:
            continue
        e, u, draw = np.array(e), np.array(u), np.array(draw)
        scale = 1e3 if unit == "mm" else 180 / math.pi
        z = e / u
        inside = np.abs(z) <= K
        lo, hi = cluster_bootstrap_interval(inside, draw)
        missing = no_pose if name.startswith("store") else 0
        rows.append((name, unit, len(e), missing if name.startswith("store") else "-",
                     "%.4f" % np.sqrt(np.mean((e * scale) ** 2)),
                     "%.4f" % np.mean(u * scale), "%.1f" % (100.0 * np.mean(inside)),
                     "%.1f" % (100.0 * inside.sum() / (len(e) + missing)),
                     "%.1f .. %.1f" % (100.0 * lo, 100.0 * hi),
                     "%.1f .. %.1f" % (100.0 * honest[0], 100.0 * honest[1]),
                     "%.2f" % np.sqrt(np.mean(z * z))))
    return rows, used


def calibration_stage(stage_dir, budget_share, image_size, outdir, figures):
    """The calibration stage of tools/testpoint (tools/calib_stage.py: storetrack-calib detect,
    rig, register): its residuals and its share of the store-position budget. Returns (summary
    rows, per-camera table rows, registration table rows, printed note) or None without it."""
    path = os.path.join(stage_dir, "calibration_summary.json")
    if not os.path.exists(path):
        return None
    s = json.load(open(path))
    rows = [("calibration: board images / rig RMS / residual sigma",
             "%d / %.3f px / %.3f px" % (s["images"], s["rig"]["rms_px"], s["rig"]["residual_sigma_px"])),
            ("calibration: board points used / rejected",
             "%d / %d" % (s["rig"]["points_used"], s["rig"]["points_rejected"]))]
    cams = [(c["camera_id"], c["views"], c["points_used"], c["points_rejected"],
             "%.3f" % c["rms_px"], "%.3f" % c["intrinsic_fit_rms_px"],
             "-" if c["camera_id"] == 0 else "%.2f +/- %.3f" % (c["baseline_m"] * 1e3, c["baseline_sigma_m"] * 1e3))
            for c in s["cameras"]]
    r = s["registration"]
    marks = [(m["id"], ",".join(str(c) for c in m["cameras"]),
              "%.3f" % (1e3 * math.sqrt(sum(x * x for x in m["residual_r_m"]))),
              "%.2f / %d" % (m["chi2"], m["dof"]), "%.3f" % m["p_value"],
              "yes" if m["used"] else "no", "OUTLIER" if m["outlier"] else "")
             for m in r["marks"]]
    sig = r["T_r_w_sigma"]
    rows.append(("registration: chi2 / dof (p)", "%.2f / %d (%.3f)" % (r["chi2"], r["dof"], r["p_value"])))
    rows.append(("registration: u(T_r_w) rms per axis: total, centroid, calibration, survey",
                 ", ".join("%.1f mdeg %.2f mm" % (sig[k][0] * 180e3 / math.pi, sig[k][1] * 1e3)
                           for k in ("total", "centroid", "calibration", "survey"))))
    rows.append(("calibration stage time [s]",
                 ", ".join("%s %.1f" % kv for kv in s["seconds"].items())))
    # The sample's extrinsic field also carries the pylon and store mark surveys (they register
    # the body frames): the calibration alone is a part of it. test_calib_round_trip splits it
    # (store separation: survey 99.0 %, camera calibration 0.2 %, docs/calibration.md).
    ext = budget_share.get(EXTRINSIC_LABEL, 0)
    cal_share = budget_share.get("intrinsic", 0) + ext
    rows.append(("calibration + body-mark survey share of the store-position variance "
                 "(intrinsic + extrinsic/registration/survey; the sample does not split them)",
                 "%.1f %% (%.1f + %.1f)" % (cal_share, budget_share.get("intrinsic", 0), ext)))
    # Residual map of the rig fit: every board point where it was seen, coloured by |residual|.
    res = read_csv(os.path.join(stage_dir, "rig_residuals.csv"))
    if res is not None and len(res.get("camera", [])) > 0:
        at = {}  # (camera, frame, point) -> detected pixel, from the observation CSVs
        for c in s["cameras"]:
            p = os.path.join(stage_dir, "cam%d.csv" % c["camera_id"])
            if not os.path.exists(p):
                continue
            with open(p, newline="") as f:  # '#' comment lines come before the header
                rd = csv.reader(line for line in f if not line.startswith("#"))
                next(rd)
                for row in rd:
                    at[(int(row[0]), int(row[1]), int(row[2]))] = (float(row[6]), float(row[7]))
        cam_ids = [c["camera_id"] for c in s["cameras"]]
        ncol = min(2, len(cam_ids))
        fig, axs = plt.subplots((len(cam_ids) + ncol - 1) // ncol, ncol, figsize=(7 * ncol, 3.6 * ((len(cam_ids) + 1) // 2)), squeeze=False)
        for ax in axs.flat[len(cam_ids):]:
            ax.set_visible(False)
        for ax, cid in zip(axs.flat, cam_ids):
            m = res["camera"] == cid
            xy = [at.get((cid, int(f), int(q)), (np.nan, np.nan)) for f, q in zip(res["frame"][m], res["point_id"][m])]
            xy = np.array(xy).reshape(-1, 2)
            mag = np.hypot(res["residual_x_px"][m], res["residual_y_px"][m])
            sc = ax.scatter(xy[:, 0], xy[:, 1], c=mag, s=2, cmap="viridis", vmin=0,
                            vmax=np.percentile(mag, 99) if len(mag) else 1)
            ax.set_xlim(-0.5, image_size[0] - 0.5); ax.set_ylim(image_size[1] - 0.5, -0.5)
            ax.set_aspect("equal")
            ax.set_title("camera %d: %d board points, RMS %.3f px" % (
                cid, int(m.sum()), math.sqrt(np.mean(mag ** 2)) if len(mag) else float("nan")), fontsize=9)
            fig.colorbar(sc, ax=ax, label="|residual| [px]", shrink=0.7)
        fig.suptitle("Calibration (storetrack-calib rig): board points over each image, coloured by residual")
        savefig(fig, outdir, "calibration_residuals.png", figures)
    note = ("The host flew with storetrack-calib's calibration of this run (board images rendered "
            "by the simulator, detect, rig, register from the simulated total-station survey), not "
            "the simulator's calibration file; its stated covariance and the body-mark surveys are "
            "%.0f %% of the store-position variance (the sample does not split them; "
            "test_calib_round_trip does: the surveys ~99 %%)." % cal_share)
    return rows, cams, marks, note


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", required=True, help="test-point run directory")
    ap.add_argument("--truth-poses", help="simulator truth_poses.csv")
    ap.add_argument("--truth-marks", help="simulator truth_marks.csv (default next to poses)")
    ap.add_argument("--calibration", help="rig calibration JSON (image size)")
    ap.add_argument("--out", required=True, help="output directory for index.html and PNGs")
    ap.add_argument("--calibration-stage", metavar="DIR",
                    help="tools/testpoint's calibration stage directory (calibration_summary.json, "
                         "rig_residuals.csv, cam<id>.csv): its residuals and budget share")
    ap.add_argument("--post", metavar="DIR",
                    help="storetrack-post --report directory of this run: the smoothed "
                         "trajectory beside the real-time one, rates, per-camera residual "
                         "diagnostics, camera usage and the recording's integrity")
    ap.add_argument("--pool-runs", nargs="+", default=[], metavar="DIR",
                    help="run directories of the same test point with other seeds (other "
                         "calibration draws, each with sim/truth_*.csv): adds the k = 2 coverage "
                         "pooled over them and --run")
    ap.add_argument("--clearance-geometry", metavar="JSON",
                    help="the clearance geometry the host flew with: adds the clearance section "
                         "(live with its k = 2 band against the clearance at the true pose)")
    ap.add_argument("--clearance-tool", metavar="EXE",
                    help="storetrack-clearance-at-poses (evaluates the true poses)")
    ap.add_argument("--clearance-threshold", type=float, metavar="M",
                    help="the host's clearance.alarm_threshold_m (drawn on the plot)")
    args = ap.parse_args()
    os.makedirs(args.out, exist_ok=True)

    fti = read_csv(os.path.join(args.run, "fti.csv"))
    if fti is None or len(fti.get("trigger_seq", [])) == 0:
        print("report: no samples in %s/fti.csv" % args.run, file=sys.stderr)
        return 2
    marks = read_csv(os.path.join(args.run, "marks.csv"))
    rigid = read_csv(os.path.join(args.run, "rigid.csv"))
    stats = json.load(open(os.path.join(args.run, "stats.json")))
    truth = read_csv(args.truth_poses) if args.truth_poses else None
    truth_marks_path = args.truth_marks or (
        os.path.join(os.path.dirname(args.truth_poses), "truth_marks.csv") if args.truth_poses else None)
    truth_marks = read_csv(truth_marks_path) if truth_marks_path else None
    ch10 = read_ch10(os.path.join(args.run, "storetrack.ch10"))
    width, height = 1920, 1024
    if args.calibration and os.path.exists(args.calibration):
        try:
            cal = json.load(open(args.calibration))
            cam0 = cal["cameras"][0]
            intr = cam0.get("intrinsics", cam0)
            width, height = int(intr.get("width", width)), int(intr.get("height", height))
        except (KeyError, ValueError, IndexError, TypeError):
            pass

    seq = fti["trigger_seq"].astype(np.int64)
    t_tai = fti["exposure_mid_tai_ns"]
    t = (t_tai - t_tai[0]) * 1e-9
    valid = (fti["status"].astype(int) & 1) == 1
    figures = []
    summary = []  # (name, value)
    summary.append(("samples (valid / total)", "%d / %d" % (valid.sum(), len(valid))))

    axes_pos, axes_att = AXES_POS, AXES_ATT

    # --- truth alignment by trigger sequence ---------------------------------------------------
    err = store_pose_errors(fti, truth)
    has_store_truth = err is not None

    # --- trajectory and attitude with k=2 bands (real-time beside smoothed), and with
    # storetrack-post's report directory its truth-free sections (host/report/post_report.py)
    post = load_post_dir(args.post) if args.post else None
    if post is not None:
        render_post(post, args.out, figures, summary, t_tai[0], err if has_store_truth else None,
                    fti=fti)
    else:
        plot_pose(fti, read_csv(os.path.join(args.run, "smoothed.csv")), t_tai[0], args.out,
                  figures, err if has_store_truth else None)

    # --- error against truth -------------------------------------------------------------------
    coverage_rows = []
    if has_store_truth:
        fig, axs = plt.subplots(2, 3, figsize=(13, 6), sharex=True)
        for i, a in enumerate(axes_pos + axes_att):
            ax = axs[i // 3][i % 3]
            scale, unit = (1e3, "mm") if a in axes_pos else (180 / math.pi, "deg")
            e, u = err[a], fti["u_" + a]
            m = np.isfinite(e) & valid
            ax.fill_between(t[m], -K * u[m] * scale, K * u[m] * scale, alpha=0.3, color="tab:green",
                            label="±k u (k = 2)")
            ax.plot(t[m], e[m] * scale, ".", ms=2, color="tab:red", label="error")
            ax.set_title("%s error [%s]" % (a, unit), fontsize=10)
            ax.grid(alpha=0.3)
            inside = np.abs(e[m]) <= K * u[m]
            coverage_rows.append((a, unit, np.sqrt(np.mean((e[m] * scale) ** 2)),
                                  np.max(np.abs(e[m] * scale)), np.mean(u[m] * scale),
                                  100.0 * inside.mean() if m.any() else float("nan")))
        axs[0][0].legend(fontsize=8)
        for ax in axs[1]:
            ax.set_xlabel("time [s]")
        fig.suptitle("Store pose error against the simulator's truth, with the k = 2 band")
        savefig(fig, args.out, "error.png", figures)

    # --- store-to-aircraft clearance against the clearance at the true pose ----------------------
    clearance = None
    if has_store_truth and args.clearance_geometry and args.clearance_tool:
        clearance = clearance_section(fti, truth, args.run, args.clearance_tool,
                                      args.clearance_geometry, args.clearance_threshold, args.out,
                                      figures, binomial_acceptance)

    # --- mark position error against truth (every scenario) ------------------------------------
    mark_rows = []
    if marks is not None and truth_marks is not None and len(marks.get("trigger_seq", [])) > 0:
        ex, ey, ez, ux, uy, uz = mark_errors(marks, truth_marks)
        if ex:
            E = np.array([ex, ey, ez]) * 1e3
            U = np.array([ux, uy, uz]) * 1e3
            fig, axs = plt.subplots(1, 3, figsize=(13, 3.5))
            for i, a in enumerate(["x_w", "y_w", "z_w"]):
                z = E[i] / U[i]
                axs[i].hist(z, bins=60, range=(-5, 5), density=True, alpha=0.7, color="tab:purple")
                g = np.linspace(-5, 5, 200)
                axs[i].plot(g, np.exp(-g * g / 2) / np.sqrt(2 * np.pi), "k-", lw=1, label="N(0,1)")
                axs[i].set_title("mark %s: error / u (ideal: N(0,1))" % a, fontsize=10)
                inside = 100.0 * np.mean(np.abs(z) <= K)
                mark_rows.append((a, np.sqrt(np.mean(E[i] ** 2)), np.mean(U[i]), inside))
            axs[0].legend(fontsize=8)
            fig.suptitle("Triangulated mark positions against truth (%d mark samples)" % len(ex))
            savefig(fig, args.out, "mark_errors.png", figures)

    # --- rigid-body residuals -------------------------------------------------------------------
    if rigid is not None and len(rigid.get("trigger_seq", [])) > 0:
        fig, axs = plt.subplots(1, 2, figsize=(13, 4))
        for b, name, color in (("p", "pylon", "tab:blue"), ("s", "store", "tab:orange")):
            m = rigid["body"] == b
            if not m.any():
                continue
            d = (rigid["distance"][m] - rigid["surveyed"][m]) * 1e3
            z = d / (rigid["sigma"][m] * 1e3)
            axs[0].hist(d, bins=80, alpha=0.6, color=color, label="%s (%d pair tests)" % (name, m.sum()))
            axs[1].hist(z, bins=80, range=(-6, 6), alpha=0.6, density=True, color=color, label=name)
            summary.append(("rigid-body %s: RMS distance residual" % name, "%.3f mm" % np.sqrt(np.mean(d ** 2))))
        g = np.linspace(-6, 6, 200)
        axs[1].plot(g, np.exp(-g * g / 2) / np.sqrt(2 * np.pi), "k-", lw=1, label="N(0,1)")
        axs[0].set_xlabel("distance - surveyed distance [mm]")
        axs[1].set_xlabel("(distance - surveyed) / predicted sigma")
        axs[0].legend(fontsize=8); axs[1].legend(fontsize=8)
        fig.suptitle("Rigid-body distance checks (every mark pair of each body, every exposure)")
        savefig(fig, args.out, "rigid_residuals.png", figures)

    # --- per-camera residual maps ---------------------------------------------------------------
    if marks is not None and len(marks.get("camera_id", [])) > 0:
        cams = sorted(set(int(c) for c in marks["camera_id"]))
        ncol = min(2, len(cams))
        nrow = (len(cams) + ncol - 1) // ncol
        fig, axs = plt.subplots(nrow, ncol, figsize=(7 * ncol, 4 * nrow), squeeze=False)
        for ax in axs.flat[len(cams):]:
            ax.set_visible(False)
        for ax, c in zip(axs.flat, cams):
            m = (marks["camera_id"] == c) & np.isfinite(marks["u_obs"])
            u, v = marks["u_obs"][m], marks["v_obs"][m]
            du, dv = marks["residual_u"][m], marks["residual_v"][m]
            mag = np.hypot(du, dv)
            sc = ax.scatter(u, v, c=mag, s=3, cmap="viridis", vmin=0, vmax=np.percentile(mag, 99) if len(mag) else 1)
            step = max(1, len(u) // 400)
            ax.quiver(u[::step], v[::step], du[::step], -dv[::step], angles="xy", scale_units="xy",
                      scale=0.01, width=0.002, color="tab:red", alpha=0.6)
            ax.set_xlim(-0.5, width - 0.5); ax.set_ylim(height - 0.5, -0.5)
            ax.set_aspect("equal")
            rms = np.sqrt(np.mean(du ** 2 + dv ** 2) / 2) if len(du) else float("nan")
            ax.set_title("camera %d: RMS residual %.3f px/axis (%d obs)" % (c, rms, len(du)), fontsize=9)
            summary.append(("camera %d reprojection residual RMS" % c, "%.3f px per axis" % rms))
            fig.colorbar(sc, ax=ax, label="|residual| [px]", shrink=0.7)
        fig.suptitle("Per-camera reprojection residual maps (arrows x100)")
        savefig(fig, args.out, "camera_residuals.png", figures)

    # --- uncertainty budget ---------------------------------------------------------------------
    comps = [("centroid", "u_budget_centroid"), ("intrinsic", "u_budget_intrinsic"),
             (EXTRINSIC_LABEL, "u_budget_extrinsic"), ("time sync", "u_budget_sync"),
             ("process noise (extrapolated)", "u_budget_process")]
    # A CSV from before FtiSample v2 has no process column: plot the four it has.
    comps = [(n, c) for n, c in comps if c in fti]
    fig, axs = plt.subplots(1, 2, figsize=(13, 4), gridspec_kw={"width_ratios": [3, 1]})
    var = np.array([fti[c][valid] ** 2 for _, c in comps]) * 1e6  # mm^2
    axs[0].stackplot(t[valid], var, labels=[n for n, _ in comps], alpha=0.8)
    axs[0].set_ylabel("position variance [mm^2]")
    axs[0].set_xlabel("time [s]")
    axs[0].legend(loc="upper left", fontsize=8)
    axs[0].set_title("Uncertainty budget of the store position (variances add)")
    share = var.mean(axis=1)
    share = share / share.sum() * 100 if share.sum() > 0 else share
    axs[1].barh([n for n, _ in comps], share, color=["C%d" % i for i in range(len(comps))])
    axs[1].set_xlabel("share of the variance [%]")
    for i, s in enumerate(share):
        axs[1].text(s, i, " %.1f %%" % s, va="center", fontsize=8)
        summary.append(("budget share: %s" % comps[i][0], "%.1f %%" % s))
    savefig(fig, args.out, "budget.png", figures)
    calib = (calibration_stage(args.calibration_stage, {n: v for (n, _), v in zip(comps, share)},
                               (width, height), args.out, figures)
             if args.calibration_stage else None)
    if calib:
        summary.extend(calib[0])
    if len(comps) == 5 and valid.any():
        # The five parts are independent sources: their variances add up to u_x^2 + u_y^2 + u_z^2
        # (to the CSV's 9 digits), extrapolated samples included.
        total = sum(fti[c][valid] ** 2 for c in ("u_x", "u_y", "u_z")) * 1e6
        closure = np.max(np.abs(var.sum(axis=0) / total - 1))
        summary.append(("budget closure: max |sum of parts / total - 1|", "%.1e" % closure))

    # --- cameras / marks used -------------------------------------------------------------------
    fig, ax = plt.subplots(figsize=(10, 2.8))
    ax.plot(t, fti["marks_used"], ".", ms=2, label="store marks used")
    ax.plot(t, fti["pylon_marks_used"], ".", ms=2, label="pylon marks used")
    ax.plot(t, fti["cameras_used"], ".", ms=2, label="cameras used")
    ax.set_xlabel("time [s]"); ax.legend(fontsize=8); ax.grid(alpha=0.3)
    ax.set_title("Marks and cameras contributing per exposure")
    savefig(fig, args.out, "usage.png", figures)

    # --- summary --------------------------------------------------------------------------------
    lat = stats.get("latency", {}).get("last_observation_to_inetx_complete_exposures", {})
    al = stats.get("aligner", {})
    summary.append(("exposures complete / partial", "%s / %s" % (al.get("exposures_complete"), al.get("exposures_partial_timeout"))))
    summary.append(("observations dropped (dup/late/time/unknown)", "%s/%s/%s/%s" % (
        al.get("dropped_duplicate"), al.get("dropped_late"), al.get("dropped_time_mismatch"), al.get("dropped_unknown_camera"))))
    ident = stats.get("identifier", {})
    summary.append(("marks identified / observed", "%s / %s (ambiguous %s)" % (
        ident.get("identified"), ident.get("observations"), ident.get("ambiguous"))))
    summary.append(("latency last observation -> iNET-X p50 / p99", "%.0f / %.0f us" % (lat.get("p50_us", float("nan")), lat.get("p99_us", float("nan")))))
    out = stats.get("outputs", {})
    summary.append(("iNET-X packets sent", str(out.get("inetx_sent"))))
    if ch10 is not None:
        summary.append(("Chapter 10: packets / messages / TMATS first",
                        "%d / %d / %s" % (ch10["packets"], ch10["messages"], "yes" if ch10["first_type"] == 1 else "NO")))
        summary.append(("Chapter 10: header checksum errors / trailing bytes",
                        "%d / %d" % (ch10["header_checksum_errors"], ch10["truncated_bytes"])))

    def fmt_table(rows, headers):
        widths = [max(len(str(h)), *(len(str(r[i])) for r in rows)) for i, h in enumerate(headers)]
        line = "  ".join(str(h).ljust(w) for h, w in zip(headers, widths))
        sep = "  ".join("-" * w for w in widths)
        return "\n".join([line, sep] + ["  ".join(str(c).ljust(w) for c, w in zip(r, widths)) for r in rows])

    print("\nTest point summary")
    print(fmt_table(summary, ["quantity", "value"]))
    cov_table = [(a, unit, "%.4f" % rms, "%.4f" % mx, "%.4f" % mu, "%.1f" % cov)
                 for a, unit, rms, mx, mu, cov in coverage_rows]
    if cov_table:
        print("\nStore pose against truth (coverage of the k = 2 interval should be about 95 %)")
        print(fmt_table(cov_table, ["axis", "unit", "RMS error", "max |error|", "mean u", "inside k=2 [%]"]))
    mark_table = [(a, "%.4f" % rms, "%.4f" % mu, "%.1f" % c) for a, rms, mu, c in mark_rows]
    if mark_table:
        print("\nTriangulated marks against truth [mm]")
        print(fmt_table(mark_table, ["axis", "RMS error", "mean u", "inside k=2 [%]"]))
    one_draw_note = (
        "One run is ONE draw of the calibration and survey errors, shared by all its samples "
        "(calibration and body-mark surveys are %.0f %% of the store-position variance here), so "
        "its coverage is one "
        "sample: single runs range from about 70 to 100 %%. The stated uncertainty is checked "
        "over many draws: tools/testpoint --draws N pools N seeds; tests/host/uncertainty runs "
        "1500." % (100.0 - share[0] - share[3] if share.sum() > 0 else float("nan")))
    if cov_table or mark_table:
        print("(" + one_draw_note + ")")
    if clearance:
        print("\nStore-to-aircraft clearance against the clearance at the true pose")
        print(fmt_table(clearance["rows"], ["quantity", "value"]))
        print("(" + clearance["note"] + ")")
    calib_headers = (["camera", "views", "points used", "rejected", "RMS [px]",
                      "own intrinsic fit RMS [px]", "baseline [mm] +/- u"],
                     ["mark", "cameras", "|residual| [mm]", "chi2 / dof", "p", "used", "outlier"])
    if calib:
        print("\nCalibration stage (storetrack-calib rig, per camera)")
        print(fmt_table(calib[1], calib_headers[0]))
        print("\nWorld registration (storetrack-calib register, per mark; residual in S_r)")
        print(fmt_table(calib[2], calib_headers[1]))
        print("(" + calib[3] + ")")
    pool_headers = ["quantity", "unit", "samples", "no pose (not scored)", "RMS error", "mean u",
                    "inside k=2 [%]", "inside k=2, no pose as outside [%]",
                    "95 % CI [%] (bootstrap over draws)", "honest range [%] (binomial, n = draws)",
                    "RMS error/u"]
    pool_table, pool_draws = [], 0
    if args.pool_runs:
        pool_table, pool_draws = pooled_coverage([args.run] + args.pool_runs)
        if clearance:
            row = pooled_clearance_row([args.run] + args.pool_runs, args.clearance_tool,
                                       args.clearance_geometry, binomial_acceptance,
                                       cluster_bootstrap_interval, read_csv)
            if row:
                pool_table.append(row)
        print("\nPooled over %d calibration draws (seeds): coverage should be about 95 %%, "
              "RMS error/u about 1. 95 %% CI: percentile interval of the pooled coverage over 2000 "
              "resamples of whole draws; honest range: where an honest instrument's pooled "
              "coverage falls with 95 %% probability (Binomial(draws, 95.45 %%)); samples the host "
              "wrote without a store pose are counted (no pose), and scored as outside in the "
              "column after the coverage" % pool_draws)
        print(fmt_table(pool_table, pool_headers))

    with open(os.path.join(args.out, "index.html"), "w") as f:
        f.write("<!doctype html><html><head><meta charset='utf-8'><title>storetrack test point</title>"
                "<style>body{font-family:sans-serif;max-width:1200px;margin:auto}table{border-collapse:collapse}"
                "td,th{border:1px solid #ccc;padding:3px 8px;text-align:left}img{max-width:100%}</style></head><body>")
        f.write("<h1>storetrack test point: %s</h1>" % html.escape(os.path.basename(os.path.abspath(args.run))))
        f.write("<p>Store pose relative to the pylon with GUM standard uncertainties; bands are k = 2 "
                "expanded uncertainties. Truth from the scene simulator.</p><h2>Summary</h2><table>")
        for k_, v in summary:
            f.write("<tr><td>%s</td><td>%s</td></tr>" % (html.escape(k_), html.escape(str(v))))
        f.write("</table>")
        if cov_table or mark_table:
            f.write("<p><i>%s</i></p>" % html.escape(one_draw_note))
        if clearance:
            f.write("<h2>Store-to-aircraft clearance against truth</h2><table>")
            for k_, v in clearance["rows"]:
                f.write("<tr><td>%s</td><td>%s</td></tr>" % (html.escape(k_), html.escape(v)))
            f.write("</table><p><i>%s</i></p>" % html.escape(clearance["note"]))
        if calib:
            f.write("<h2>Calibration stage (storetrack-calib)</h2><p>%s</p>" % html.escape(calib[3]))
            for table, headers in ((calib[1], calib_headers[0]), (calib[2], calib_headers[1])):
                f.write("<table><tr>%s</tr>" % "".join("<th>%s</th>" % h for h in headers))
                for r in table:
                    f.write("<tr>%s</tr>" % "".join("<td>%s</td>" % html.escape(str(c)) for c in r))
                f.write("</table><br>")
        if pool_table:
            f.write("<h2>Pooled over %d calibration draws</h2><p>Coverage should be about 95 %%, "
                    "RMS error/u about 1.</p><table><tr>%s</tr>" % (
                        pool_draws, "".join("<th>%s</th>" % h for h in pool_headers)))
            for r in pool_table:
                f.write("<tr>%s</tr>" % "".join("<td>%s</td>" % html.escape(str(c)) for c in r))
            f.write("</table>")
        for title, table, headers in (("Store pose error against truth", cov_table,
                                       ["axis", "unit", "RMS error", "max |error|", "mean u", "inside k=2 [%]"]),
                                      ("Triangulated marks against truth [mm]", mark_table,
                                       ["axis", "RMS error", "mean u", "inside k=2 [%]"])):
            if table:
                f.write("<h2>%s</h2><table><tr>%s</tr>" % (title, "".join("<th>%s</th>" % h for h in headers)))
                for r in table:
                    f.write("<tr>%s</tr>" % "".join("<td>%s</td>" % html.escape(str(c)) for c in r))
                f.write("</table>")
        for name in figures:
            f.write("<h2>%s</h2><img src='%s'>" % (html.escape(name[:-4].replace("_", " ")), name))
        f.write("<h2>Host counters</h2><pre>%s</pre></body></html>" % html.escape(json.dumps(stats, indent=1)))
    if clearance:
        st = clearance["stats"]
        with open(os.path.join(args.out, "clearance.json"), "w") as f:
            json.dump({"n": st["n"], "inside_k2": st["inside"], "coverage": st["coverage"],
                       "acceptance_band": list(st["band"]), "bound_held": st["held"],
                       "bound_held_band_low": st["held_band_low"],
                       "alarm_episodes": len(st["episodes"]), "parts": clearance["names"],
                       "min_live_m": st["min_live"][0] if st["min_live"] else None,
                       "min_true_m": st["min_true"][0] if st["min_true"] else None}, f, indent=1)
    print("\nreport: %s" % os.path.join(args.out, "index.html"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
