#!/usr/bin/env python3
"""Writes libFuzzer seed inputs (valid messages in both framings) for the msg fuzz targets.

Usage: make_seeds.py OUT_DIR   -> OUT_DIR/udp/*, OUT_DIR/canfd/*
The layouts follow docs/icd.md; zlib.crc32 is the same CRC-32 (IEEE) as storetrack::msg::crc32.
"""
import os
import struct
import sys
import zlib


def marks_payload(n, unit=3, camera=1, seq=0x1234):
    # MarkObservations version 2: exposure_time_sigma_ns (u32) after clock_state.
    fixed = struct.pack(">BBIqqIBIHB", unit, camera, seq, 1_800_000_000_000_000_000,
                        5_000_000_000, 200_000, 2, 1_250, 0, n)
    words = b"".join(struct.pack(">Q", ((100 + 37 * i) << 45) | ((50 + 11 * i) << 26) |
                                 (40 << 18) | (200 << 10) | (16 << 4) | (i & 0xF))
                     for i in range(n))
    return fixed + words


def health_payload(unit=3):
    return struct.pack(">BBIqihhIIIIIIIIHHHH", unit, 2, 100, 1_800_000_000_000_000_000, -20,
                       4200, 5100, 1, 2, 3, 4, 5, 6, 7, 8, 0, 0, 900, 1)


VERSION = {1: 2, 2: 1}  # message id -> schema version (MarkObservations 2, UnitHealth 1)


def datagram(msg_id, unit, payload, seq=5):
    d = struct.pack(">HBBBBHI", 0x5354, 1, msg_id, VERSION[msg_id], unit, 12 + len(payload) + 4,
                    seq) + payload
    return d + struct.pack(">I", zlib.crc32(d))


def canfd_frames(msg_id, unit, camera, tseq, payload):
    stream = payload + struct.pack(">I", zlib.crc32(payload))
    count = (len(stream) + 60) // 61
    can_id = (2 << 26) | (msg_id << 19) | (unit << 11) | (camera << 3) | VERSION[msg_id]
    lens = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64]
    out = b""
    for i in range(count):
        chunk = stream[61 * i:61 * i + 61]
        length = next(l for l in lens if l >= 3 + len(chunk))
        data = struct.pack(">HB", tseq & 0xFFFF, i << 4 | (count - 1)) + chunk
        data += bytes(length - len(data))
        out += struct.pack(">IBH", can_id, length, 100) + data
    return out


def main():
    out = sys.argv[1]
    os.makedirs(os.path.join(out, "udp"), exist_ok=True)
    os.makedirs(os.path.join(out, "canfd"), exist_ok=True)

    def write(sub, name, data):
        with open(os.path.join(out, sub, name), "wb") as fh:
            fh.write(data)

    for n in (0, 2, 23, 64):
        write("udp", "marks%d" % n, b"\x00" + datagram(1, 3, marks_payload(n)))
        write("canfd", "raw_marks%d" % n, b"\x00" + canfd_frames(1, 3, 1, 0x1234, marks_payload(n)))
        write("canfd", "structured_marks%d" % n, b"\x01\x00" + marks_payload(n))
    write("udp", "health", b"\x00" + datagram(2, 3, health_payload()))
    tseq = (1_800_000_000_000_000_000 >> 20) & 0xFFFF
    write("canfd", "raw_health", b"\x00" + canfd_frames(2, 3, 0, tseq, health_payload()))
    write("canfd", "structured_health", b"\x01\x01" + health_payload())


if __name__ == "__main__":
    main()
