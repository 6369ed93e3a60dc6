#!/usr/bin/env python3
"""Edge analysis for the in-VM GPIO tests (independent of the code under test).

  gpio_edges.py poll PATH SECONDS > edges.txt       poll a gpio-sim sim_gpioN/value (outputs)
  gpio_edges.py check --edges F --format gpiomon|poll --rate HZ [--log emu.csv] [...]

check: rising edges -> intervals; classifies every edge by the nominal period alone (an edge
closer than period/2 to the previous one is EXTRA; a gap of k > 1.5 periods means k-1 MISSING)
and compares with --expect-missing/--expect-extra; with --log (storetrack-trigger-emu CSV) every
sent pulse must have its rising edge within [planned - tol, rise_mono + tol] (CLOCK_MONOTONIC).
"""
import argparse
import csv
import statistics
import sys
import time


def poll(path, seconds):
    end = time.monotonic_ns() + int(seconds * 1e9)
    last = None
    with open(path, "rb", buffering=0) as f:
        while time.monotonic_ns() < end:
            f.seek(0)
            v = f.read(8).strip()
            t = time.monotonic_ns()
            if v != last:
                print(t, v.decode(), flush=True)
                last = v
            time.sleep(0.0002)


def rising_edges(path, fmt):
    out = []
    with open(path) as f:
        for line in f:
            p = line.split()
            if not p:
                continue
            if fmt == "gpiomon":  # '%e %s %n': event (1 rising), seconds, nanoseconds
                if p[0] == "1":
                    out.append(int(p[1]) * 1_000_000_000 + int(p[2]))
            elif fmt == "unitcsv":  # storetrack-unit --edges-csv: line_count,t_mono_ns,...
                if p[0].startswith("line_count"):
                    continue
                out.append(int(line.split(",")[1]))
            else:  # poll: 't_ns level', first line is the initial level
                out.append((int(p[0]), p[1]))
    if fmt == "poll":
        rises = [t for i, (t, v) in enumerate(out) if i > 0 and v == "1"]
        return rises
    return out


def main():
    ap = argparse.ArgumentParser()
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("poll")
    p.add_argument("path")
    p.add_argument("seconds", type=float)
    c = sub.add_parser("check")
    c.add_argument("--edges", required=True)
    c.add_argument("--format", choices=["gpiomon", "poll", "unitcsv"], default="gpiomon")
    c.add_argument("--rate", type=float, required=True)
    c.add_argument("--rate-tol", type=float, default=0.02, help="relative, median interval")
    c.add_argument("--expect-count", type=int)
    c.add_argument("--expect-missing", type=int, default=0)
    c.add_argument("--expect-extra", type=int, default=0)
    c.add_argument("--log", help="storetrack-trigger-emu CSV log")
    c.add_argument("--source-late-ns", type=int,
                   help="the lateness the pulse source reported itself (storetrack-unit's "
                        "trigger_line.max_late_ns in master mode)")
    # gpio-sim time-stamps an edge in its irq thread: under TCG on a loaded host that runs tens of
    # ms after the write, so VM tests pass a generous window; edges are matched one-to-one in order.
    c.add_argument("--tol-ms", type=float, default=3.0)
    a = ap.parse_args()
    if a.cmd == "poll":
        poll(a.path, a.seconds)
        return 0

    rises = rising_edges(a.edges, a.format)
    period = 1e9 / a.rate
    errors = []
    intervals = [b - x for x, b in zip(rises, rises[1:])]
    nominal = [d for d in intervals if 0.5 * period <= d <= 1.5 * period]
    # Classify against the nominal grid (anchored on the edges themselves): an edge within a
    # quarter period of a grid slot is that slot's pulse, any further edge is EXTRA, and empty
    # slots between the first and last edge are MISSING.
    t0 = rises[0] if rises else 0
    for _ in range(2):
        res = [(t - t0) / period - round((t - t0) / period) for t in rises]
        near = [r for r in res if abs(r) < 0.25]
        if near:
            t0 += statistics.median(near) * period
    slots = set()
    extra = 0
    for t in rises:
        ph = (t - t0) / period
        k = round(ph)
        if abs(ph - k) < 0.25 and k not in slots:
            slots.add(k)
        else:
            extra += 1
    missing = (max(slots) - min(slots) + 1 - len(slots)) if slots else 0
    print(f"rising edges {len(rises)}, extra {extra}, missing {missing}")
    if nominal:
        med = statistics.median(nominal)
        print(f"median nominal interval {med / 1e6:.3f} ms -> {1e9 / med:.3f} Hz "
              f"(want {a.rate} Hz), max dev {max(abs(d - period) for d in nominal) / 1e6:.3f} ms")
        # Rate over the whole run: the first and last edges are nominal pulses (faults sit
        # inside), so span / whole periods; per-edge latency jitter (gpio-sim's irq thread on a
        # starved vCPU) then only enters through two edges instead of every interval.
        span = rises[-1] - rises[0]
        periods = round(span / period)
        rate = periods / (span / 1e9) if span > 0 else 0.0
        print(f"rate over {periods} periods: {rate:.3f} Hz")
        if abs(rate - a.rate) > a.rate_tol * a.rate:
            errors.append(f"rate {rate:.3f} Hz off {a.rate} Hz by > {a.rate_tol:.0%}")
    else:
        errors.append("no nominal intervals")
    if a.expect_count is not None and len(rises) != a.expect_count:
        errors.append(f"{len(rises)} rising edges, want {a.expect_count}")
    timing_ok = True
    if a.log:
        with open(a.log) as f:
            rows = list(csv.DictReader(f))
        sent = [r for r in rows if r["kind"] != "missing"]
        log_missing = sum(1 for r in rows if r["kind"] == "missing")
        log_extra = sum(1 for r in rows if r["kind"] in ("double", "burst"))
        late = max(int(r["rise_mono_ns"]) - int(r["planned_rise_mono_ns"]) for r in sent)
        print(f"emulator log: {len(sent)} sent, {log_missing} withheld, {log_extra} extra, "
              f"max lateness {late / 1e6:.3f} ms")
        if log_missing != a.expect_missing or log_extra != a.expect_extra:
            errors.append(f"emulator logged {log_missing} missing / {log_extra} extra, want "
                          f"{a.expect_missing} / {a.expect_extra}")
        # A pulse played later than a quarter period (a starved TCG vCPU on a loaded host)
        # really is off-rate on the wire: then the edge classification cannot be held to the
        # script, only to the log (every edge must still match its logged pulse, below).
        timing_ok = late < 0.25 * period
        if not timing_ok:
            print("NOTE: emulator ran late by > period/4 (loaded host); fault classification "
                  "of the edges is reported, not asserted")
    # The same for a source that reports its own lateness (the unit as trigger master): its
    # report is the evidence, and the count and the edges' times are still held to it.
    if a.source_late_ns is not None and a.source_late_ns >= 0.25 * period:
        timing_ok = False
        print(f"NOTE: the source reported a pulse {a.source_late_ns / 1e6:.3f} ms late "
              f"(> period/4: loaded host); fault classification of the edges is reported, "
              f"not asserted")
    if timing_ok and extra != a.expect_extra:
        errors.append(f"{extra} extra edges detected, want {a.expect_extra}")
    if timing_ok and missing != a.expect_missing:
        errors.append(f"{missing} missing edges detected, want {a.expect_missing}")
    if a.log:
        if len(sent) != len(rises):
            errors.append(f"emulator logged {len(sent)} pulses, line saw {len(rises)} rising edges")
        tol = int(a.tol_ms * 1e6)
        worst = 0
        for r, t in zip(sent, rises):
            lo, hi = int(r["planned_rise_mono_ns"]) - tol, int(r["rise_mono_ns"]) + tol
            worst = max(worst, abs(t - int(r["rise_mono_ns"])))
            if not lo <= t <= hi:
                errors.append(f"pulse seq {r['seq']} ({r['kind']}): edge at {t}, "
                              f"want in [{lo}, {hi}]")
                break
        print(f"worst |edge - logged rise| {worst / 1e6:.3f} ms")
    for e in errors:
        print("FAIL: " + e)
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
