#!/usr/bin/env python3
"""Converts OpenCV's fisheye test corners (FileStorage XML: <image_N> blocks of x y pairs, and of
x y z board points) into the project's observation CSV (docs/calibration.md, "Observation CSV").

  tools/opencv_fisheye_xml_to_csv.py IMAGE_XML OBJECT_XML --camera C --width W --height H \
      --source-pattern 'left/stereo_pair_%03d.jpg' -o OUT.csv

Frame = N of <image_N>; point_id = the index in the block (OpenCV's order, row-major). Numbers
are written with Python's repr (the shortest text that reads back bit for bit), so the CSV holds
exactly the doubles cv::FileStorage reads. Exit 2 with file and block named on malformed input
(nothing written), 1 when OUT cannot be written.
"""
import argparse
import re
import sys

BLOCK = re.compile(r"<image_(\d+)>(.*?)</image_\1>", re.S)


def fail(message):
    print(f"error: {message}", file=sys.stderr)
    sys.exit(2)


def read_blocks(path, width):
    """{N: [tuple of `width` floats, ...]} of the file's <image_N> blocks."""
    try:
        with open(path, encoding="ascii") as f:
            text = f.read()
    except (OSError, UnicodeDecodeError) as e:
        fail(f"{path}: cannot read: {e}")
    blocks = {}
    for m in BLOCK.finditer(text):
        try:
            values = [float(v) for v in m.group(2).split()]
        except ValueError as e:
            fail(f"{path}: image_{m.group(1)}: {e}")
        if not values or len(values) % width:
            fail(f"{path}: image_{m.group(1)}: {len(values)} numbers, not a multiple of {width}")
        blocks[int(m.group(1))] = [tuple(values[i:i + width]) for i in range(0, len(values), width)]
    if not blocks:
        fail(f"{path}: no <image_N> block")
    return blocks


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("image_xml")
    p.add_argument("object_xml")
    p.add_argument("--camera", type=int, required=True)
    p.add_argument("--width", type=int, required=True)
    p.add_argument("--height", type=int, required=True)
    p.add_argument("--source-pattern", required=True, help="printf pattern of the frame's image")
    p.add_argument("-o", "--output", required=True)
    a = p.parse_args()
    images = read_blocks(a.image_xml, 2)
    boards = read_blocks(a.object_xml, 3)
    if sorted(images) != sorted(boards):
        fail(f"{a.image_xml} and {a.object_xml} name different images")
    lines = ["# storetrack board observations (docs/calibration.md)",
             f"# converted by tools/opencv_fisheye_xml_to_csv.py from {a.image_xml} and {a.object_xml}",
             f"# image_size,{a.camera},{a.width},{a.height}"]
    lines += [f"# frame,{n},{a.source_pattern % n}" for n in sorted(images)]
    lines.append("camera,frame,point_id,board_x_m,board_y_m,board_z_m,image_x_px,image_y_px")
    for n in sorted(images):
        if len(images[n]) != len(boards[n]):
            fail(f"{a.image_xml}: image_{n}: {len(images[n])} image points, {len(boards[n])} board points in {a.object_xml}")
        for i, ((u, v), (x, y, z)) in enumerate(zip(images[n], boards[n])):
            lines.append(f"{a.camera},{n},{i},{x!r},{y!r},{z!r},{u!r},{v!r}")
    try:
        with open(a.output, "w", encoding="ascii") as f:
            f.write("\n".join(lines) + "\n")
    except OSError as e:
        print(f"error: {a.output}: cannot write: {e}", file=sys.stderr)
        sys.exit(1)
    print(f"wrote {a.output}: {len(images)} frames")


if __name__ == "__main__":
    main()
