#!/usr/bin/env python3
"""Checks of guest/e2e.sh (independent of the code under test): the trigger, the camera
emulator, both units, the host's CSV and Chapter 10 outputs, against each other and the truth.

1. Every trigger pulse the emulator sent reached both units (edges CSV: N accepted edges,
   sequence 0..N-1) and the camera emulator (N edges, frame k on edge k).
2. Every edge gave one host sample, or the loss is counted: a sample missing at the host must be
   matched by an edge a unit left unpaired (pairing counters) or an exposure the host's aligner
   dropped; at most --max-loss of the edges may be lost.
3. Trigger sequence numbers line up end to end: the host's trigger_seq k carries the pose of the
   simulator's exposure k (the frame the camera emulator wrote on edge k); the check shows how
   far off a neighbouring exposure's truth would be.
4. The Chapter 10 file reads back with the independent reader (rig_ch10_dump): no header or
   data checksum error, not truncated, the same samples as the CSV.
5. Store pose (T_p_s: x y z yaw pitch roll) and triangulated mark positions (world frame) match
   the truth within k = 3 of their stated standard uncertainties: at most --max-outside of the
   components outside (a normal error is outside 3 u with probability 0.27 %).
"""
import argparse
import csv
import json
import math
import statistics
import sys


def read_csv(path):
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    # host CSV headers carry units in brackets: "x [m]" -> "x"
    header = [h.split(" [")[0].strip() for h in rows[0]]
    return [dict(zip(header, r)) for r in rows[1:] if r]


def wrap(a):
    return (a + math.pi) % (2 * math.pi) - math.pi


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--count", type=int, required=True)
    ap.add_argument("--rate", type=float, required=True)
    ap.add_argument("--trigger-log", required=True)
    ap.add_argument("--camera-log", required=True)
    ap.add_argument("--units", nargs="+", required=True)
    ap.add_argument("--edges", nargs="+", required=True)
    ap.add_argument("--host", required=True)
    ap.add_argument("--fti", required=True)
    ap.add_argument("--marks", required=True)
    ap.add_argument("--ch10", required=True)
    ap.add_argument("--truth-poses", required=True)
    ap.add_argument("--truth-marks", required=True)
    ap.add_argument("--max-loss", type=float, default=0.05, help="fraction of the edges")
    ap.add_argument("--max-outside", type=float, default=0.01,
                    help="fraction of components outside 3 u")
    a = ap.parse_args()
    n = a.count
    err = []
    period_ms = 1e3 / a.rate

    # 1. trigger -> units, camera emulator
    pulses = [r for r in read_csv(a.trigger_log) if r["kind"] != "missing"]
    late = max(int(r["rise_mono_ns"]) - int(r["planned_rise_mono_ns"]) for r in pulses) / 1e6
    print(f"trigger-emu: {len(pulses)} pulses at {a.rate} Hz, max lateness {late:.1f} ms")
    if len(pulses) != n:
        err.append(f"trigger emulator sent {len(pulses)} pulses, want {n}")
    cam = read_csv(a.camera_log)
    reaction = [(int(r["t_queued_mono_ns"]) - int(r["t_edge_mono_ns"])) / 1e6 for r in cam]
    print(f"camera emulator: {len(cam)} edges served; reaction (edge -> frame queued) median "
          f"{statistics.median(reaction):.1f} ms, max {max(reaction):.1f} ms" if cam else
          "camera emulator: no edges")
    if len(cam) != n or any(int(r["frame"]) != i for i, r in enumerate(cam)):
        err.append(f"camera emulator served {len(cam)} edges (want {n}, frame k on edge k)")
    unit_edges = []
    for path in a.edges:
        rows = read_csv(path)
        seqs = [int(r["trigger_seq"]) for r in rows]
        verdicts = {r["verdict"] for r in rows}
        print(f"{path}: {len(rows)} edges, sequence {seqs[:1]}..{seqs[-1:]}, verdicts {verdicts}")
        if seqs != list(range(n)) or verdicts != {"accepted"}:
            err.append(f"{path}: edges are not sequence 0..{n - 1}, all accepted")
        unit_edges.append([int(r["t_mono_ns"]) for r in rows])
    if all(len(e) == n for e in unit_edges) and len(cam) == n:
        skew = max(abs(e[k] - int(cam[k]["t_edge_mono_ns"])) for e in unit_edges for k in range(n))
        print(f"edge k at every consumer (units, camera emulator): max skew {skew / 1e6:.2f} ms")
        if skew > 0.25 * period_ms * 1e6:
            err.append(f"edge times of one pulse differ by {skew / 1e6:.1f} ms between lines")

    # 2. losses, counted
    unit_lost = 0
    for path in a.units:
        u = json.load(open(path))
        p, link = u.get("pairing", {}), (u.get("links") or [{}])[0]
        t = u.get("triggered_only", {})
        v = u.get("v4l2", {})
        lost = n - p.get("frames_paired", 0)
        unit_lost += max(lost, 0)
        print(f"{path}: {u.get('frames_captured')} frames captured ({v.get('dropped')} dropped by "
              f"V4L2), {t.get('skipped_no_marks')} dark, {t.get('skipped_untriggered')} not "
              f"claimed by an edge, {p.get('frames_paired')} paired, "
              f"{link.get('observations_sent')} sent; centroiding "
              f"{u.get('centroid_time_us_mean', 0) / 1e3:.1f} ms/frame; "
              f"{p.get('ambiguous')} ambiguous windows")
        if link.get("observations_sent") != p.get("frames_paired"):
            err.append(f"{path}: sent {link.get('observations_sent')} != paired "
                       f"{p.get('frames_paired')}")
        if p.get("ambiguous", 0):
            err.append(f"{path}: {p['ambiguous']} pairing windows held two edges")
    host = json.load(open(a.host))
    fti = read_csv(a.fti)
    seqs = [int(r["trigger_seq"]) for r in fti]
    missing = sorted(set(range(n)) - set(seqs))
    host_dropped = sum(v for k, v in host.get("aligner", {}).items()
                       if k.startswith("exposures_dropped") or k.startswith("observations_dropped"))
    for c in host.get("can", []):
        r = c.get("reassembly", {})
        print(f"host CAN {c.get('interface')}: {c.get('frames')} frames, {c.get('decoded')} "
              f"messages, reassembly timeouts {r.get('timeouts')}, fragments lost "
              f"{r.get('fragments_lost')}")
    print(f"host: {len(fti)} samples for {n} edges; missing {missing}; aligner "
          f"{json.dumps(host.get('aligner', {}))}")
    if len(set(seqs)) != len(seqs) or any(s < 0 or s >= n for s in seqs):
        err.append("host samples: trigger_seq repeated or outside 0..N-1")
    if len(missing) > unit_lost + host_dropped:
        err.append(f"{len(missing)} edges without a host sample, only {unit_lost} counted as "
                   f"unpaired by the units and {host_dropped} dropped by the host")
    if len(missing) > a.max_loss * n:
        err.append(f"{len(missing)} of {n} edges lost (> {a.max_loss:.0%})")

    # 4. Chapter 10 via the independent reader
    ch = json.load(open(a.ch10))
    print(f"chapter 10: {ch['packets']} packets {ch['packets_by_type']}, header checksum errors "
          f"{ch['header_checksum_errors']}, data checksum errors {ch['data_checksum_errors']}, "
          f"truncated {ch['truncated']}, {len(ch['samples'])} FTI samples")
    if ch["header_checksum_errors"] or ch["data_checksum_errors"] or ch["truncated"] or \
            ch["stop_reason"] or ch["message_decode_errors"] or ch["fti_block_errors"]:
        err.append(f"chapter 10 file not clean: {ch['stop_reason']}")
    if [s["trigger_seq"] for s in ch["samples"]] != seqs:
        err.append("chapter 10 samples are not the CSV's (trigger_seq)")
    else:
        keys = ("x", "y", "z", "yaw", "pitch", "roll")
        worst = max((abs(s["pose"][i] - float(r[k])) / max(1e-9, abs(float(r[k])))
                     for s, r in zip(ch["samples"], fti) for i, k in enumerate(keys)
                     if math.isfinite(float(r[k]))), default=0.0)
        if worst > 1e-6:
            err.append(f"chapter 10 pose differs from the CSV by {worst:.2e} (relative)")

    # 3 + 5. truth
    truth = {int(r["trigger_seq"]): r for r in read_csv(a.truth_poses)}
    keys = [("x", "T_p_s_x_m", "u_x", False), ("y", "T_p_s_y_m", "u_y", False),
            ("z", "T_p_s_z_m", "u_z", False), ("yaw", "T_p_s_yaw_rad", "u_yaw", True),
            ("pitch", "T_p_s_pitch_rad", "u_pitch", True),
            ("roll", "T_p_s_roll_rad", "u_roll", True)]

    def zs(shift):
        out = []
        for r in fti:
            k = int(r["trigger_seq"]) + shift
            if k not in truth or not int(r["status"]) & 1:
                continue
            for est, tru, unc, ang in keys:
                d = float(r[est]) - float(truth[k][tru])
                out.append((wrap(d) if ang else d) / float(r[unc]))
        return out

    valid = sum(1 for r in fti if int(r["status"]) & 1)
    z = zs(0)
    if not z:
        err.append("no valid pose samples to compare with the truth")
    else:
        outside = sum(1 for v in z if abs(v) > 3)
        print(f"pose vs truth: {valid} valid samples, {outside} of {len(z)} components outside "
              f"3 u, max |error|/u {max(abs(v) for v in z):.2f}, RMS {math.sqrt(statistics.mean(v * v for v in z)):.2f}")
        if outside > a.max_outside * len(z):
            err.append(f"pose: {outside} of {len(z)} components outside 3 u")
        for shift in (-1, 1):
            zz = zs(shift)
            if zz:
                o = sum(1 for v in zz if abs(v) > 3)
                print(f"  (against exposure k{shift:+d}'s truth: {o} of {len(zz)} outside 3 u)")
    if valid < len(fti):
        err.append(f"{len(fti) - valid} host samples not valid")

    tm = {}
    for r in read_csv(a.truth_marks):
        tm[(int(r["trigger_seq"]), int(r["mark_id"]))] = r
    # The host's world frame is the one the rig calibration realises (the cameras ride on the
    # vibrating pylon pod): the simulator writes that truth as x_w0_m (older trees: x_w_m only).
    frame = "w0" if tm and "x_w0_m" in next(iter(tm.values())) else "w"
    seen, zm = set(), []
    for r in read_csv(a.marks):
        key = (int(r["trigger_seq"]), int(r["mark_id"]))
        if key in seen or key not in tm or r["excluded"] != "0":
            continue
        seen.add(key)
        for c in ("x", "y", "z"):
            zm.append((float(r[f"{c}_w"]) - float(tm[key][f"{c}_{frame}_m"])) /
                      float(r[f"u_{c}_w"]))
    if not zm:
        err.append("no triangulated marks to compare with the truth")
    else:
        outside = sum(1 for v in zm if abs(v) > 3)
        print(f"marks vs truth ({frame}): {len(seen)} mark positions, {outside} of {len(zm)} components "
              f"outside 3 u, max |error|/u {max(abs(v) for v in zm):.2f}, RMS "
              f"{math.sqrt(statistics.mean(v * v for v in zm)):.2f}")
        if outside > a.max_outside * len(zm):
            err.append(f"marks: {outside} of {len(zm)} components outside 3 u")
    for e in err:
        print("FAIL: " + e)
    return 1 if err else 0


if __name__ == "__main__":
    sys.exit(main())
