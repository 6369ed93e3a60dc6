#!/usr/bin/python3
"""Checks one run of run_faults.py: what the host counted against what the units sent and the
fault proxy did (its seeded fates), and the store pose against the simulator's truth.

Accounting (per camera c, MarkObservations only; every number from an independent source):
  sent_c      units' own statistics (observations_sent), == proxy in_c (loopback, no loss)
  arrived_c = proxy forwarded_c - corrupted_c   (a duplicate is forwarded twice)
  host aligner cameras[c].received == arrived_c
  corrupted datagrams (any kind) + garbage flood == host udp decode errors (CRC-32 rejects
    every single-bit error); foreign-unit flood == udp.spoofed_source; unknown-camera flood ==
    aligner.dropped_unknown_camera. With the host's kernel filter (udp.kernel_filter_sources >
    0, the default with --udp-source) the foreign-unit flood and the garbage or corruption that
    hits the magic or unit id are refused before the socket: decode errors + kernel drops ==
    corrupted + garbage + foreign unit, spoofed == 0
  duplicated_c == cameras[c].duplicate;  used_c == in_c - lost_c - corrupted_c  (nothing late)
  missing_c <= lost_c + corrupted_c, and missing_c >= that minus the exposures nobody delivered
"""
import json
import math
import os
import sys

import numpy as np

root, out = sys.argv[1], sys.argv[2]
sys.path.insert(0, os.path.join(root, "host", "report"))
from storetrack_report import Checks, read_csv  # noqa: E402

check = Checks()
failures = check.failures


def load(name):
    return json.load(open(os.path.join(out, name)))


stats, proxy, fault = load("stats.json"), load("proxy.json"), load("fault.json")
case, nexp = fault["case"], fault["exposures"]
pc, pcam = proxy["counts"], proxy["by_camera"]
al, udp = stats["aligner"], stats["udp"]
cams = {str(c["camera_id"]): c for c in stats["cameras"]}
fti = read_csv(os.path.join(out, "fti.csv"))
truth = read_csv(os.path.join(out, "sim", "truth_poses.csv"))
n = len(fti["trigger_seq"])
first_seq = int(truth["trigger_seq"][0])


def pget(c, what):
    return pcam.get(str(c), {}).get(what, 0)


# --- units -> proxy -> host: every datagram accounted for -------------------------------------
sent = {}
for f in sorted(os.listdir(out)):
    if f.startswith("unit_cam") and f.endswith(".json"):
        c = f[len("unit_cam"):].split(".")[0].split("_")[0]
        s = json.load(open(os.path.join(out, f)))
        sent[c] = sent.get(c, 0) + sum(l["observations_sent"] for l in s["links"])
for c in sorted(cams):
    if case != "restart" or c != "3":  # the killed process wrote no statistics
        check(sent.get(c, 0) == pget(c, "in"),
              "camera %s: units sent %d observations, proxy received %d" % (c, sent.get(c, 0), pget(c, "in")))
flood_total = sum(v for k, v in pc.items() if k.startswith("flood_"))
forwarded = pc.get("observations_forwarded", 0) + pc.get("health_forwarded", 0)
decode_errors = sum(udp["decode_errors"].values())
corrupted = pc.get("observations_corrupted", 0) + pc.get("health_corrupted", 0)
refused = corrupted + pc.get("flood_garbage", 0) + pc.get("flood_foreign_unit", 0)
kernel = udp.get("kernel_drops", 0)
if udp.get("kernel_filter_sources", 0) > 0:
    # The host's kernel filter refuses every datagram without the magic or from a (unit,
    # address) not configured before the socket: the kernel counts them (kernel_drops; nothing
    # overflows in this slow-motion load), the host sees the rest.
    check(udp["datagrams"] + kernel == forwarded + flood_total,
          "host received %d + kernel refused %d datagrams == proxy forwarded %d + flood %d"
          % (udp["datagrams"], kernel, forwarded, flood_total))
    check(kernel >= pc.get("flood_foreign_unit", 0) and udp.get("spoofed_source", 0) == 0,
          "every foreign-unit datagram (%d) refused in the kernel (%d refused), none spoofed in "
          "the host (%d)" % (pc.get("flood_foreign_unit", 0), kernel, udp.get("spoofed_source", 0)))
    check(decode_errors + kernel == refused,
          "host decode errors %d + kernel refused %d == corrupted %d + garbage %d + foreign unit %d"
          % (decode_errors, kernel, corrupted, pc.get("flood_garbage", 0),
             pc.get("flood_foreign_unit", 0)))
else:
    check(udp["datagrams"] == forwarded + flood_total and kernel == 0,
          "host received %d datagrams == proxy forwarded %d + flood %d, kernel drops %d"
          % (udp["datagrams"], forwarded, flood_total, kernel))
    check(decode_errors == corrupted + pc.get("flood_garbage", 0),
          "host decode errors %d == corrupted %d + garbage flood %d (%s)"
          % (decode_errors, corrupted, pc.get("flood_garbage", 0),
             {k: v for k, v in udp["decode_errors"].items() if v}))
    check(udp.get("spoofed_source", 0) == pc.get("flood_foreign_unit", 0),
          "spoofed source %d == foreign-unit flood %d"
          % (udp.get("spoofed_source", 0), pc.get("flood_foreign_unit", 0)))
check(al["dropped_unknown_camera"] == pc.get("flood_unknown_camera", 0),
      "unknown camera %d == unknown-camera flood %d" % (al["dropped_unknown_camera"], pc.get("flood_unknown_camera", 0)))
dropped = sum(v for k, v in al.items() if k.startswith("dropped_"))
check(al["observations_in"] == al["observations_used"] + dropped,
      "every observation used (%d) or dropped by a counted cause (%d)" % (al["observations_used"], dropped))
for c in sorted(cams):
    arrived = pget(c, "forwarded") - pget(c, "corrupted")
    check(cams[c]["received"] == arrived,
          "camera %s: host received %d == proxy delivered intact %d" % (c, cams[c]["received"], arrived))
    check(cams[c]["duplicate"] == pget(c, "duplicated"),
          "camera %s: duplicates counted %d == injected %d" % (c, cams[c]["duplicate"], pget(c, "duplicated")))

# --- samples ----------------------------------------------------------------------------------
seqs = fti["trigger_seq"].astype(np.int64)
check(np.all(np.diff(seqs) > 0), "samples in trigger order, each exposure once")
released = al["exposures_complete"] + al["exposures_partial_timeout"] + al["exposures_partial_overflow"]
withheld = sum(stats["samples_withheld"].values())
check(released == stats["exposures_processed"] and n == released - withheld
      and n == stats["samples_written"],
      "one sample per released exposure but those too few cameras measured (%d samples, %d "
      "released, %d withheld)" % (n, released, withheld))
status = fti["status"].astype(np.int64)
flagged = (status & 16) != 0  # camera_missing
partial = al["exposures_partial_timeout"] + al["exposures_partial_overflow"]
check(partial - withheld <= int(flagged.sum()) <= partial,
      "samples flagged camera_missing %d == partial exposures %d (less those withheld, %d)"
      % (flagged.sum(), partial, withheld))
cameras_used = fti["cameras_used"].astype(np.int64)
check(np.all(cameras_used[~flagged] == len(cams)) and np.all(cameras_used[flagged] < len(cams)),
      "cameras_used is %d exactly where no camera is flagged missing" % len(cams))
valid = (status & 1) == 1


def expected_missing_bounds(c):
    lost = pget(c, "lost") + pget(c, "corrupted")
    return lost - (nexp - n), lost


if case in ("loss1", "loss10"):
    for c in sorted(cams):
        exp_used = pget(c, "in") - pget(c, "lost") - pget(c, "corrupted")
        check(cams[c]["used"] == exp_used and cams[c]["late"] == 0 and cams[c]["time_mismatch"] == 0,
              "camera %s: used %d == sent %d - lost %d - corrupted %d (late %d, time mismatch %d)"
              % (c, cams[c]["used"], pget(c, "in"), pget(c, "lost"), pget(c, "corrupted"),
                 cams[c]["late"], cams[c]["time_mismatch"]))
        lo, hi = expected_missing_bounds(c)
        check(lo <= cams[c]["missing"] <= hi,
              "camera %s: missing %d in [%d, %d] (lost + corrupted, less exposures nobody delivered)"
              % (c, cams[c]["missing"], lo, hi))
    # An exposure disappears only when every camera's datagram was lost or corrupted: with
    # p = loss + corrupt per datagram that is p^4 per exposure (10 %+2 %: 2e-4, 0.02 of 100).
    check(n >= nexp - 1, "host kept producing samples: %d of %d exposures" % (n, nexp))
    check(pc.get("observations_reordered", 0) > 0 and pc.get("observations_duplicated", 0) > 0,
          "reordering (%d) and duplication (%d) were exercised"
          % (pc.get("observations_reordered", 0), pc.get("observations_duplicated", 0)))

if case == "restart":
    r = fault["restart"]
    missed = nexp - pget(3, "in")  # exposures camera 3 never sent (down, restarting)
    for c in ("0", "1", "2"):
        check(cams[c]["used"] == nexp and cams[c]["missing"] == 0,
              "camera %s unaffected: used %d of %d, missing %d" % (c, cams[c]["used"], nexp, cams[c]["missing"]))
    check(n == nexp, "every exposure produced a sample (%d of %d)" % (n, nexp))
    # Rejoin: of camera 3's observations after the restart at most 3 are not used.
    lost_after = pget(3, "in") - cams["3"]["used"]
    check(0 <= lost_after <= 3,
          "restarted camera 3 rejoined within %d exposures (restart at exposure %d, numbering "
          "from 0; %d sent in all, %d used)" % (lost_after, r["restart_exposure"], pget(3, "in"), cams["3"]["used"]))
    check(cams["3"]["missing"] == missed + lost_after,
          "camera 3 missing %d == never sent %d + not yet rejoined %d" % (cams["3"]["missing"], missed, lost_after))
    check(al.get("sequence_offset_changes", 0) >= 1, "sequence offset re-learned (%d)" % al.get("sequence_offset_changes", 0))

if case == "clock":
    for c, st in fault["clock_steps"].items():
        span = st["to"] - st["from"]
        check(cams[c]["time_mismatch"] == span and cams[c]["used"] == nexp - span,
              "camera %s: TAI step %+d ms for %d exposures: %d dropped as time mismatch, %d used"
              % (c, st["step_ns"] // 1_000_000, span, cams[c]["time_mismatch"], cams[c]["used"]))
    for c in sorted(set(cams) - set(fault["clock_steps"])):
        check(cams[c]["used"] == nexp and cams[c]["time_mismatch"] == 0,
              "camera %s (clock healthy) lost nothing: used %d" % (c, cams[c]["used"]))
    check(n == nexp, "every exposure produced a sample (%d of %d)" % (n, nexp))

if case == "flood":
    for c in sorted(cams):
        check(cams[c]["used"] == nexp, "camera %s: every observation used under the flood (%d)" % (c, cams[c]["used"]))
    nominal = pc.get("observations_in", 0) + pc.get("health_in", 0)
    check(flood_total >= 10 * nominal, "flood %d datagrams = %.1f x the nominal %d"
          % (flood_total, flood_total / max(nominal, 1), nominal))
    lat = stats["latency"]["last_observation_to_inetx_complete_exposures"]
    budget_us = float(os.environ.get("STORETRACK_P99_BUDGET_US", "2000"))
    check(lat["count"] == nexp, "latency measured for every exposure (%d)" % lat["count"])
    # The budget (docs/performance.md: p99 < 2 ms) is for an instrument computer, not for a
    # shared CI machine whose run queue is longer than its cores: there the host is preempted
    # whatever the flood does, so the budget is asserted only when the load allows it.
    load, cores = os.getloadavg()[0], os.cpu_count() or 1
    what = ("p99 latency of valid samples under the flood %.0f us <= budget %.0f us (%d exposures, "
            "max %.0f us; load %.1f on %d cores)" % (lat["p99_us"], budget_us, lat["count"], lat["max_us"], load, cores))
    if load <= cores or os.environ.get("STORETRACK_P99_BUDGET_US"):
        check(lat["p99_us"] <= budget_us, what)
    else:
        print("SKIP " + what + ": not asserted, the machine is overloaded")

# --- store pose: uncertainty grows where cameras are missing, coverage honest ------------------
idx = {int(s): i for i, s in enumerate(truth["trigger_seq"])}
sel = np.array([idx[int(s)] for s in seqs])
e = np.stack([fti[a] - truth["T_p_s_%s_m" % a][sel] for a in ("x", "y", "z")], axis=1)
u = np.stack([fti["u_" + a] for a in ("x", "y", "z")], axis=1)
inside = np.all(np.abs(e) <= 2 * u, axis=1)  # all three position axes within k = 2
full = valid & ~flagged
part = valid & flagged
print("     valid samples %d: %d with every camera, %d with a camera missing" % (valid.sum(), full.sum(), part.sum()))
if part.sum() > 0 and full.sum() > 0:
    # (1) Uncertainty grows: fewer rays means less information, so each position variance of a
    # partial exposure is at least that of its complete neighbours (+-3 exposures; the geometry
    # changes little over 0.3 s at 10 fps before separation). Tolerance 2 % for the motion.
    grew, total = 0, 0
    full_idx = np.flatnonzero(full)
    for i in np.flatnonzero(part):
        near = full_idx[np.abs(seqs[full_idx] - seqs[i]) <= 3]
        if len(near) == 0:
            continue
        total += 1
        ref = np.median(np.linalg.norm(u[near], axis=1))
        grew += np.linalg.norm(u[i]) >= 0.98 * ref
    check(total == 0 or grew == total,
          "position uncertainty grows where a camera is missing: %d of %d partial samples" % (grew, total))
    # (2) Coverage of the partial samples against the complete samples of the SAME run, with p0
    # the complete samples' k = 2 coverage (all three axes): printed with the binomial tail
    # probabilities it WOULD have if the partial samples were independent (they are not, below).
    m, k_in = int(part.sum()), int(inside[part].sum())
    p0 = float(inside[full].mean())

    def binom_cdf(k, m, p):
        return sum(math.comb(m, j) * p ** j * (1 - p) ** (m - j) for j in range(0, k + 1))

    p_low = binom_cdf(k_in, m, p0)
    p_high = 1.0 - binom_cdf(k_in - 1, m, p0) if k_in > 0 else 1.0
    # Printed, not asserted: the partial samples are not Binomial(m, p0). All samples of a run
    # share ONE calibration draw, and a camera subset weighs that draw's errors differently from
    # the full rig, so an honest partial uncertainty can cover 56 % in one run and 100 % in
    # another (seen: 18/32 against 88.9 % complete, then 21/30 against 85 %, same code). The
    # coverage with a camera missing is asserted over pooled calibration draws, one sample per
    # draw, by tests/host/uncertainty/test_uncertainty_missing_camera (docs/reliability.md).
    print("     one calibration draw (not a test, see test_uncertainty_missing_camera): k=2 coverage "
          "with a camera missing %d/%d = %.1f %% vs complete %.1f %% (n=%d); binomial P(X<=k)=%.3g, "
          "P(X>=k)=%.3g would apply only to independent draws"
          % (k_in, m, 100.0 * k_in / m, 100 * p0, int(full.sum()), p_low, p_high))
z = np.abs(e[valid]) / u[valid]
check(np.mean(z <= 4) >= 0.99, "position errors within 4 u for %.1f %% of valid samples" % (100 * np.mean(z <= 4)))
print("     position k=2 coverage (all axes): complete %.1f %%, partial %s"
      % (100 * inside[full].mean() if full.any() else float("nan"),
         "%.1f %%" % (100 * inside[part].mean()) if part.any() else "-"))
summary = {"case": case, "samples": n, "valid": int(valid.sum()), "partial": int(flagged.sum()),
           "proxy": pc, "host_drops": {k: v for k, v in al.items() if k.startswith("dropped_") and v},
           "decode_errors": {k: v for k, v in udp["decode_errors"].items() if v},
           "spoofed_source": udp.get("spoofed_source", 0), "budget_exhausted": udp.get("budget_exhausted", 0),
           "latency_complete": stats["latency"]["last_observation_to_inetx_complete_exposures"],
           "failures": failures}
json.dump(summary, open(os.path.join(out, "summary.json"), "w"), indent=1)
sys.exit(1 if failures else 0)
