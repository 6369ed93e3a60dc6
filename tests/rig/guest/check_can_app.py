#!/usr/bin/env python3
"""Checks of guest/can_app.sh: unit stats, host stats and the bus as candump -L saw it."""
import argparse
import json
import sys

FD_LENS = {0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64}
# docs/icd.md "CAN FD framing": LCC 28..26, FID 25..19, unit 18..11, camera 10..3, version 2..0
# (the message's schema version: MarkObservations 2, UnitHealth 1)
VERSION = {0x01: 2, 0x02: 1}


def fields(can_id):
    return ((can_id >> 26) & 7, (can_id >> 19) & 0x7F, (can_id >> 11) & 0xFF,
            (can_id >> 3) & 0xFF, can_id & 7)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--unit", required=True)
    ap.add_argument("--host", required=True)
    ap.add_argument("--candump", required=True)
    ap.add_argument("--unit-id", type=int, required=True)
    ap.add_argument("--camera-id", type=int, required=True)
    a = ap.parse_args()
    unit = json.load(open(a.unit))
    host = json.load(open(a.host))
    errors = []
    link = unit["links"][0]
    can = host["can"][0]
    print("unit link:", json.dumps(link))
    print("host can:", json.dumps(can))

    # bus: candump -L lines "(ts) vcan0 ID##Fdata" (FD) or "ID#data" (classic)
    ours = {"obs": 0, "health": 0}
    frames = bad_len = foreign = 0
    for line in open(a.candump):
        p = line.split()
        if len(p) < 3:
            continue
        frame = p[2]
        if "##" not in frame:
            continue  # classic frames: the injected one
        ident, rest = frame.split("##", 1)
        data = rest[1:]
        if len(ident) != 8:
            foreign += 1
            continue
        cid = int(ident, 16)
        lcc, fid, uid, cam, ver = fields(cid)
        if (uid, ver, lcc) != (a.unit_id, VERSION.get(fid), 2):
            foreign += 1
            continue
        frames += 1
        if len(data) // 2 not in FD_LENS:
            bad_len += 1
        if fid == 0x01 and cam == a.camera_id:
            ours["obs"] += 1
        elif fid == 0x02 and cam == 0:
            ours["health"] += 1
        else:
            foreign += 1
    print(f"candump: {frames} frames of unit {a.unit_id} ({ours['obs']} observation, "
          f"{ours['health']} health), {foreign} other FD frames, {bad_len} bad lengths")
    if ours["obs"] == 0:
        errors.append("candump saw no MarkObservations frames with the ICD id of unit/camera")
    if bad_len:
        errors.append(f"{bad_len} frames with a length that is not a CAN FD DLC length")
    if foreign != 0:
        errors.append(f"{foreign} FD frames on the bus that do not follow the ICD ids")

    sent = link["observations_sent"]
    decoded = can["decoded"]
    # A floor, not a rate: the unit renders every simulated frame itself, which under TCG on a
    # loaded machine (load 8) gave 17 observations in the 12 s run.
    if sent < 10:
        errors.append(f"unit sent only {sent} observations")
    # everything sent while the interface was up reached the host: decoded >= sent (+health)
    health_sent = link["health_sent"]
    # One message whose frames write() accepted in the instant vcan0 went down can be lost at
    # that transition (seen once in a loaded CI run: 77 of 78, with the host's one read error,
    # ENETDOWN; whether the kernel or the host's error path loses it is not established): one
    # is tolerated and reported; two or more are a failure.
    expected = sent + health_sent - can["reassembly"]["timeouts"]
    if decoded == expected - 1 and link["tx_errors"] > 0:
        print(f"NOTE: host decoded {decoded} of {expected}: one message lost as the interface went down")
        decoded += 1
    if decoded < expected:
        errors.append(f"host decoded {decoded} < unit sent {sent} obs + {health_sent} health")
    if can["classic_or_bad_frames"] < 1:
        errors.append("injected classic frame not counted by the host")
    bad = sum(v for k, v in can["decode_errors"].items() if k not in ("none", "kNone", "ok"))
    if can["reassembly"]["crc_errors"] + bad < 1:
        errors.append("injected malformed FD frame not counted by the host")
    down = link["tx_errors"] + link["dropped_exposures"]
    if down < 1:
        errors.append("unit did not report the interface-down period (tx_errors + dropped = 0)")
    if link["link_down"]:
        errors.append("unit still reports link_down after the interface came back")
    for e in errors:
        print("FAIL: " + e)
    return 1 if errors else 0


if __name__ == "__main__":
    sys.exit(main())
